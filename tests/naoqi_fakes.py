"""Fake NAOqi services (ALMotion, ALVideoDevice, ALMemory) for hosting in a real qi session on loopback.

The fake robot runs on wall-clock time: joints move towards their targets at speed_fraction x max speed, the
camera exposes a frame every 1/30 s, stamped on this machine's monotonic clock (or its system clock), and the
DCM clock is the monotonic clock shifted by an arbitrary epoch, as on a robot where the two differ.
"""

from __future__ import annotations

import contextlib
import threading
import time

import numpy as np
import qi

from naocal.solver import limits
from naocal.solver.joints import JOINTS

DCM_EPOCH_S = 12345.678  # DCM time minus monotonic time on the fake robot
FRAME_PERIOD_S = 1.0 / 30.0
_CLOSED_SESSIONS: list = []


class FakeRobot:
    """The state behind the fake services; every call the services receive is logged in `calls`."""

    def __init__(self, *, image_clock="monotonic", seed=0):
        self.image_clock = image_clock
        self.lock = threading.Lock()
        self.limits = limits.joint_limits()
        self.speeds = limits.max_speeds()
        self.angles = {name: float(np.clip(0.0, *self.limits[name])) for name in JOINTS}
        self.targets = dict(self.angles)
        self.speed_fraction = 0.0
        self.stiffness = {name: 0.0 for name in JOINTS}
        self.last_update_s = time.monotonic()
        self.calls: list[tuple] = []
        self.subscribers: set[str] = set()
        self.image_pattern = np.random.default_rng(seed).integers(0, 256, (480, 640, 3), dtype=np.uint8)
        self.block_get_angles_s = 0.0  # make getAngles hang, to test deadlines
        self.sensor_override: dict = {}  # {joint: what getAngles reports instead (any type: a hostile robot)}
        self.memory_override: dict = {}  # {ALMemory key: what getData reports instead (any type)}

    def update(self) -> None:
        now = time.monotonic()
        dt = now - self.last_update_s
        self.last_update_s = now
        for name, target in self.targets.items():
            step = self.speed_fraction * self.speeds[name] * dt
            self.angles[name] += float(np.clip(target - self.angles[name], -step, step))

    def image_stamp(self) -> float:
        """Exposure stamp of the newest frame, on the camera's clock."""
        frame_s = np.floor(time.monotonic() / FRAME_PERIOD_S) * FRAME_PERIOD_S
        if self.image_clock == "monotonic":
            return frame_s
        if self.image_clock == "realtime":
            return frame_s + (time.time() - time.monotonic())
        if self.image_clock == "dcm":
            return frame_s + DCM_EPOCH_S
        raise ValueError(self.image_clock)

    def motion_commands(self):
        return [call for call in self.calls if call[0] == "setAngles"]


class FakeMotion:
    def __init__(self, robot: FakeRobot):
        self.robot = robot

    @qi.bind(qi.List(qi.Dynamic), (qi.List(qi.String), qi.Bool))  # dynamic: a hostile robot may send any type
    def getAngles(self, names, useSensors):
        if self.robot.block_get_angles_s:
            time.sleep(self.robot.block_get_angles_s)
        with self.robot.lock:
            self.robot.update()
            return [self.robot.sensor_override.get(name, self.robot.angles[name]) for name in names]

    @qi.bind(qi.Void, (qi.List(qi.String), qi.List(qi.Float), qi.Float))
    def setAngles(self, names, angles, fractionMaxSpeed):
        with self.robot.lock:
            self.robot.update()
            self.robot.calls.append(("setAngles", list(names), list(angles), fractionMaxSpeed))
            for name, angle in zip(names, angles):
                lower, upper = self.robot.limits[name]
                self.robot.targets[name] = float(np.clip(angle, lower, upper))  # NAOqi clamps
            self.robot.speed_fraction = fractionMaxSpeed

    @qi.bind(qi.Void, (qi.List(qi.String), qi.List(qi.Float)))
    def setStiffnesses(self, names, stiffnesses):
        with self.robot.lock:
            self.robot.calls.append(("setStiffnesses", list(names), list(stiffnesses)))
            self.robot.stiffness.update(zip(names, stiffnesses))

    @qi.bind(qi.List(qi.List(qi.Float)), (qi.String,))
    def getLimits(self, name):
        lower, upper = self.robot.limits[name]
        return [[lower, upper, self.robot.speeds[name], 1.5]]


class FakeVideoDevice:
    def __init__(self, robot: FakeRobot):
        self.robot = robot

    @qi.bind(qi.String, (qi.String, qi.Int32, qi.Int32, qi.Int32, qi.Int32))
    def subscribeCamera(self, name, cameraIndex, resolution, colorSpace, fps):
        with self.robot.lock:
            self.robot.calls.append(("subscribeCamera", name, cameraIndex, resolution, colorSpace, fps))
            handle = f"{name}_{len(self.robot.subscribers)}"
            self.robot.subscribers.add(handle)
            return handle

    # The raw-buffer field 'r' makes the bytes arrive as a bytearray (qi 3.1.5 sends repr() of plain bytes).
    @qi.bind("(iiiiiirifffff)", (qi.String,))
    def getImageRemote(self, handle):
        stamp = self.robot.image_stamp()
        seconds = int(np.floor(stamp))
        microseconds = int(round((stamp - seconds) * 1e6))
        return (640, 480, 3, 13, seconds, microseconds, self.robot.image_pattern.tobytes(),
                1, 0.0, 0.0, 0.0, 0.0, 0.0)

    @qi.bind(qi.Bool, (qi.String,))
    def releaseImage(self, handle):
        return True

    @qi.bind(qi.Bool, (qi.String,))
    def unsubscribe(self, handle):
        with self.robot.lock:
            self.robot.calls.append(("unsubscribe", handle))
            self.robot.subscribers.discard(handle)
        return True


class TextImageVideoDevice(FakeVideoDevice):
    """getImageRemote without a buffer signature: qi 3.1.5 turns the bytes into their repr() text."""

    def getImageRemote(self, handle):
        return [640, 480, 3, 13, 0, 0, self.robot.image_pattern.tobytes()[:64]]


class FakeMemory:
    def __init__(self, robot: FakeRobot):
        self.robot = robot

    def getData(self, key):
        if key in self.robot.memory_override:
            return self.robot.memory_override[key]
        if key == "DCM/Time":
            return int((time.monotonic() + DCM_EPOCH_S) * 1000)
        return {
            "Device/DeviceList/ChestBoard/BodyId": "FAKEBODY0001",
            "RobotConfig/Head/FullHeadId": "FAKEHEAD0001",
            "RobotConfig/Body/BaseVersion": "V5",
        }[key]


@contextlib.contextmanager
def fake_naoqi(robot: FakeRobot | None = None, video_class=FakeVideoDevice):
    """Host the fake services in a qi session on loopback; yields (url, robot)."""
    robot = robot or FakeRobot()
    session = qi.Session()
    session.listenStandalone("tcp://127.0.0.1:0")
    session.registerService("ALMotion", FakeMotion(robot))
    session.registerService("ALVideoDevice", video_class(robot))
    session.registerService("ALMemory", FakeMemory(robot))
    try:
        yield session.endpoints()[0], robot
    finally:
        session.close()
        _CLOSED_SESSIONS.append(session)  # see backends.naoqi_driver._CLOSED_SESSIONS
