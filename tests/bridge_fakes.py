"""Test doubles for the bridge tests: a small deterministic Backend with a simulated clock, and server helpers."""

from __future__ import annotations

import collections
import contextlib
import os

import numpy as np

from naocal.backends.base import Backend, CameraImage, CameraIntrinsics, JointReading
from naocal.backends.bridge_server import BridgeServer
from naocal.solver import limits
from naocal.solver.errors import SafetyError
from naocal.solver.joints import JOINTS

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# `naocal` with only the bridge verb, for subprocess tests that must not depend on the other verbs.
CLI = "import sys, naocal.tools.cli as cli; cli.VERB_MODULES = ('naocal.tools.cmd_bridge',); sys.exit(cli.main(sys.argv[1:]))"

SENSOR_PERIOD_S = 0.01
SENSOR_LAG_S = 0.03
FRAME_PERIOD_S = 1.0 / 30.0
IMAGE_DELAY_S = 0.06


class FakeBackend(Backend):
    """Joints that move at their commanded speed on a simulated clock; counts every call that has an effect.

    Readings lag by SENSOR_LAG_S; images are exposed at 30 Hz and delivered IMAGE_DELAY_S later.
    """

    name = "fake"
    keeps_commands_on_close = True  # as NAOqi: a restarted server finds the robot as its client left it

    def __init__(self, seed: int = 0):
        self.seed = seed
        self._limits = {j: limits.joint_limits()[j] for j in JOINTS}
        self._speeds = {j: limits.max_speeds()[j] for j in JOINTS}
        self._t_s = 0.0
        self._angles = {j: float(np.clip(0.0, *self._limits[j])) for j in JOINTS}
        self._targets = dict(self._angles)
        self._speed_fraction = 0.0
        self._history = collections.deque([(0.0, dict(self._angles))], maxlen=64)
        self._base_image = np.random.default_rng(seed).integers(0, 256, (480, 640, 3), dtype=np.uint8)
        self.commands: list[tuple[dict, float]] = []  # every executed command, in order
        self.executed = collections.Counter()  # calls with an effect, by method name
        self.closed = False

    def robot_identity(self):
        return {"id": f"fake-{self.seed}", "model": "fake NAO", "body_id": f"body-{self.seed}", "head_id": "head-0"}

    def joint_names(self):
        return JOINTS

    def joint_limits(self):
        return dict(self._limits)

    def max_speeds(self):
        return dict(self._speeds)

    def command(self, targets_rad, speed_fraction):
        for name, angle in targets_rad.items():
            if name not in self._limits:
                raise SafetyError(f"unknown joint {name!r}")
            lower, upper = self._limits[name]
            if not (np.isfinite(angle) and lower <= angle <= upper):
                raise SafetyError(f"{name} target {angle} outside [{lower}, {upper}]")
        if not 0.0 < speed_fraction <= 1.0:
            raise SafetyError(f"speed_fraction {speed_fraction} outside (0, 1]")
        self.executed["command"] += 1
        self.commands.append((dict(targets_rad), float(speed_fraction)))
        self._targets.update(targets_rad)
        self._speed_fraction = float(speed_fraction)

    def read_joints(self):
        for t_s, angles in reversed(self._history):
            if t_s <= self._t_s - SENSOR_LAG_S + 1e-9:
                return JointReading(angles_rad=dict(angles), t_s=t_s)
        t_s, angles = self._history[0]
        return JointReading(angles_rad=dict(angles), t_s=t_s)

    def set_stiffness(self, names, stiffness):
        self.executed["set_stiffness"] += 1

    def capture(self):
        frame = int(np.floor((self._t_s - IMAGE_DELAY_S) / FRAME_PERIOD_S + 1e-9))
        if frame < 0:
            return None
        pixels = self._base_image.copy()
        pixels[0, :8, 0] = np.frombuffer(np.int64(frame).tobytes(), dtype=np.uint8)
        return CameraImage(pixels=pixels, t_exposure_s=frame * FRAME_PERIOD_S)

    def intrinsics(self):
        return CameraIntrinsics(640, 480, 600.0, 600.0, 319.5, 239.5)

    def now(self):
        return self._t_s

    def sleep(self, duration_s):
        self.executed["sleep"] += 1
        end_s = self._t_s + duration_s
        while self._t_s < end_s - 1e-12:
            step_s = min(SENSOR_PERIOD_S, end_s - self._t_s)
            for name, target in self._targets.items():
                max_step = self._speed_fraction * self._speeds[name] * step_s
                self._angles[name] += float(np.clip(target - self._angles[name], -max_step, max_step))
            self._t_s += step_s
            self._history.append((self._t_s, dict(self._angles)))

    def close(self):
        self.closed = True


@contextlib.contextmanager
def serving(backend, bind="tcp://127.0.0.1:0", **kwargs):
    """A BridgeServer for `backend` in a background thread; yields the server (its `.endpoint` is bound)."""
    kwargs.setdefault("driver", "fake")
    kwargs.setdefault("clock", "simulated")
    server = BridgeServer(backend, bind, **kwargs).start_thread()
    try:
        yield server
    finally:
        server.stop()


class RawClient:
    """A bare DEALER socket that speaks the protocol by hand, as a stranger on the network (or another program)
    would: any request id, any token, no Lazy Pirate."""

    def __init__(self, endpoint: str):
        import zmq

        self._zmq = zmq
        self.socket = zmq.Context.instance().socket(zmq.DEALER)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.connect(endpoint)

    def send(self, payload: bytes, timeout_s: float = 2.0):
        """Send one payload frame; the decoded reply, or None if none came in time."""
        from naocal.backends import protocol

        self.socket.send_multipart([b"", payload])
        if not self.socket.poll(timeout_s * 1000):
            return None
        return protocol.unpack(self.socket.recv_multipart()[-1], max_bytes=protocol.MAX_REPLY_BYTES)

    def request(self, request_id: str, cmd: str, args: dict | None = None, token: str | None = None, **kwargs):
        from naocal.backends import protocol

        message = protocol.make_request(request_id, cmd, args)
        if token is not None:
            message["token"] = token
        return self.send(protocol.pack(message), **kwargs)

    def close(self) -> None:
        self.socket.close(linger=0)


MOTION_ARGS = {  # one valid request of each motion command
    "command": {"targets_rad": {"HeadYaw": 0.3}, "speed_fraction": 0.2},
    "set_stiffness": {"names": ["HeadYaw"], "stiffness": 0.0},
    "sleep": {"duration_s": 5.0},
}
