"""`LolaBackend`: a NAO V6 through LoLA, the way SPL teams run it (no NAOqi, no ALMotion).

LoLA (Aldebaran's Low Level Abstraction, NAOqi 2.8) serves ONE client on the Unix stream socket `/tmp/robocup`.
Every 12 ms it sends a msgpack map (896 bytes) with the keys Accelerometer, Angles, Battery, Current, FSR,
Gyroscope, Position, Sonar, Stiffness, Temperature, Touch, Status (arrays) and RobotConfig ([body id, body
version, head id, head version]); the client answers with a map holding Position[25] and Stiffness[25] (and
LEDs, which naocal leaves alone), in LoLA's 25-joint order `LOLA_JOINTS` (no RHipYawPitch: both HipYawPitch
joints are one motor). Sources: Aldebaran's LoLA page (NAOqi 2.8), B-Human's NaoProvider, HULKs' hula lola.rs.

What this driver does every cycle (`JointControl.step`, pure and tested without a socket):
- stamps the message with the monotonic clock on receipt (LoLA sends no time) and checks it (below);
- answers with one Position/Stiffness pair per message received;
- joints naocal does not calibrate (arms, hands) get stiffness 0 and their own measured angle as position;
  a calibrated joint at stiffness 0 too (so that stiffening it never jumps: B-Human does the same);
- interpolates toward the commanded targets itself, at the requested fraction of each joint's maximum speed
  (LoLA has no speed field): the joints of one command move together on a straight line in joint space, one
  12 ms step per message received, so a late message slows the motion and never makes it jump;
- raises stiffness by at most 1/`stiffen_s` per second and lowers it by at most 1/`ramp_s` per second;
- pauses motion (setpoints stay where they are) while a calibrated joint reports temperature Status >= 2
  (LoLA: 0 ok, 1 warm, 2 hot, 3 critical: LoLA itself cuts that joint's stiffness); command() and sleep()
  then raise NaocalError naming the joint, so the agent stops with that reason (`--resume` continues);
- checks the head's path against the HeadPitch-vs-HeadYaw table before a command is accepted, and again each
  cycle before sending (a head setpoint outside the table is never sent).

When control ends (`release_control`: the agent released the robot, or its bridge lease expired): the joints
hold where they are commanded now for `hold_s`, then their stiffness ramps to 0 over `ramp_s` (the robot lies on
its back; the legs settle onto the mat), then every joint is limp. `close()` (bridge stopped by SIGINT/SIGTERM)
ramps stiffness to 0 over `ramp_s` before it disconnects. If the bridge process dies, LoLA receives nothing
more: see docs/DEPLOY.md for what LoLA and HuLA do then.

Start-up refuses: no socket at the path, a refused connection, a connection on which nothing arrives within
`first_message_timeout_s` (LoLA serves one client: another one, the team's framework or HuLA, holds it), and a
first message that is not a LoLA sensor map (HuLA's /tmp/hula speaks HULKs' own binary frames, not msgpack).
Once running, `silence_timeout_s` without a trusted reading, or a closed connection, is a fault (RobotTimeout), and so
is one message that cannot be trusted (RobotFault; `parse_sensor_message` says what is checked): motion is
refused from then on, every message is still answered with the joints held for `hold_s` and then ramped limp
(`release_control`'s safe state), and no reading is served older than `silence_timeout_s`. Whatever the robot
reads, every position sent is inside its joint's limits (`pack_answer`, the one place positions are sent).
"""

from __future__ import annotations

import errno
import logging
import math
import os
import socket
import threading
import time
from dataclasses import dataclass

import msgpack
import numpy as np

from naocal.backends.base import Backend, JointTables, CameraImage, CameraIntrinsics, JointReading
from naocal.backends.errors import RobotFault, RobotTimeout
from naocal.solver import limits
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.joints import HEAD_JOINTS, JOINTS

log = logging.getLogger("naocal.lola")

DEFAULT_SOCKET = "/tmp/robocup"
CYCLE_S = 0.012  # LoLA runs at 83.3 Hz
LOLA_JOINTS = (
    "HeadYaw", "HeadPitch",
    "LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll", "LWristYaw",
    "LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch", "LAnkleRoll",
    "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll",
    "RShoulderPitch", "RShoulderRoll", "RElbowYaw", "RElbowRoll", "RWristYaw",
    "LHand", "RHand",
)
N_LOLA = len(LOLA_JOINTS)
LOLA_INDEX = {name: i for i, name in enumerate(LOLA_JOINTS)}
SHARED_MOTOR = ("LHipYawPitch", "RHipYawPitch")  # one motor, LoLA knows it as LHipYawPitch
# LoLA index of each of naocal's joints (RHipYawPitch reads and moves LoLA's LHipYawPitch).
MOTOR_OF = {name: LOLA_INDEX[SHARED_MOTOR[0] if name == SHARED_MOTOR[1] else name] for name in JOINTS}
CALIBRATED_MOTORS = tuple(sorted(set(MOTOR_OF.values())))  # the 13 motors naocal may stiffen and move
SENSOR_ARRAYS = {"Position": N_LOLA, "Stiffness": N_LOLA, "Temperature": N_LOLA, "Status": N_LOLA,
                 "Current": N_LOLA}
SENSOR_KEYS = ("Accelerometer", "Angles", "Battery", "Current", "FSR", "Gyroscope", "Position", "Sonar",
               "Stiffness", "Temperature", "Touch", "Status", "RobotConfig")
HOT_STATUS = 2  # LoLA temperature status: 0 ok, 1 warm, 2 hot (naocal pauses), 3 critical (LoLA cuts stiffness)
STATUS_VALUES = range(4)
LOLA_LIMITS = {name: limits.joint_limits()[name] for name in LOLA_JOINTS}  # rad (LHand, RHand: 0..1 open)
LOLA_LOWER = np.array([LOLA_LIMITS[name][0] for name in LOLA_JOINTS])
LOLA_UPPER = np.array([LOLA_LIMITS[name][1] for name in LOLA_JOINTS])
MAX_MESSAGE_BYTES = 1 << 16
DEFAULT_HOLD_S = 5.0
DEFAULT_RAMP_S = 5.0
DEFAULT_STIFFEN_S = 0.5


@dataclass(frozen=True)
class LolaFrame:
    """One LoLA sensor message, as received."""

    t_s: float  # monotonic clock when it was received
    position_rad: tuple  # 25, LoLA order
    stiffness: tuple
    temperature_c: tuple
    current_a: tuple
    status: tuple  # ints
    robot_config: tuple  # (body id, body version, head id, head version)


def _printable(text, limit: int = 64) -> str:
    """A RobotConfig string fit to print and to put in a file name: printable ASCII, at most `limit` chars."""
    return "".join(ch for ch in str(text) if 32 < ord(ch) < 127)[:limit] or "unknown"


class BadReading(ValueError):
    """A LoLA sensor map whose values cannot be trusted (not numbers, not finite, impossible)."""


def parse_sensor_message(message, t_s: float) -> LolaFrame:
    """A LolaFrame from one decoded LoLA message; ValueError naming the first bad key (BadReading when the map has
    LoLA's layout but a value cannot be trusted).

    Position is required; Stiffness, Temperature, Current and Status are read when present (NaN, or status 0,
    when absent: a peer may leave them out) and must then have 25 finite numbers (a string or a bool is not one,
    even where msgpack decodes it); every Position must lie within its joint's limits plus
    limits.READING_MARGIN_RAD, Stiffness within [0, 1], Status be 0, 1, 2 or 3; RobotConfig as below.
    """
    if not isinstance(message, dict):
        raise ValueError(f"a LoLA message is a map, got {type(message).__name__}")
    if "Position" not in message:
        raise ValueError("no Position array")
    arrays = {}
    for key, length in SENSOR_ARRAYS.items():
        values = message.get(key)
        if values is None:
            arrays[key] = (0.0 if key == "Status" else math.nan,) * length
            continue
        if not isinstance(values, (list, tuple)) or len(values) != length:
            raise ValueError(f"{key} must be an array of {length} numbers")
        # Position against the joints' limits; the others (temperature, current, ...) have no box here.
        why = limits.readings_problem(dict(zip(LOLA_JOINTS, values)), LOLA_LIMITS if key == "Position" else {})
        if why is not None:
            raise BadReading(f"{key}: {why}")
        arrays[key] = tuple(float(v) for v in values)
    if any(not (0.0 <= s <= 1.0) for s in arrays["Stiffness"] if not math.isnan(s)):
        raise BadReading("Stiffness outside [0, 1]")
    if any(s not in STATUS_VALUES for s in arrays["Status"]):
        raise BadReading(f"Status must be 0, 1, 2 or 3, got {sorted(set(arrays['Status']) - set(STATUS_VALUES))}")
    config = message.get("RobotConfig", ("unknown",) * 4)
    if not isinstance(config, (list, tuple)) or len(config) != 4:
        raise ValueError("RobotConfig must be [body id, body version, head id, head version]")
    return LolaFrame(t_s=float(t_s), position_rad=arrays["Position"], stiffness=arrays["Stiffness"],
                     temperature_c=arrays["Temperature"], current_a=arrays["Current"],
                     status=tuple(int(s) for s in arrays["Status"]),
                     robot_config=tuple(_printable(v) for v in config))


def _reported(value: float):
    """A sensor value for a report: None where the message did not carry it."""
    return value if math.isfinite(value) else None


def pack_answer(position_rad, stiffness) -> bytes:
    """The client's answer: {"Position": [25], "Stiffness": [25]} as msgpack with 32-bit floats (LoLA's floats).

    The one place positions go to the robot: each is clamped into its joint's limits whatever asked for it (a
    reading echoed, a bug), and a joint whose position or stiffness is not finite is sent limp (stiffness 0)."""
    position = np.asarray(position_rad, dtype=float)
    stiffness = np.asarray(stiffness, dtype=float)
    sane = np.isfinite(position) & np.isfinite(stiffness)
    position = np.clip(np.where(sane, position, LOLA_LOWER), LOLA_LOWER, LOLA_UPPER)
    stiffness = np.clip(np.where(sane, stiffness, 0.0), 0.0, 1.0)
    return msgpack.packb({"Position": position.tolist(), "Stiffness": stiffness.tolist()}, use_single_float=True)


class JointControl:
    """What naocal answers LoLA: setpoints and stiffnesses, advanced one 12 ms cycle per `step`. Not thread-safe.

    speeds_rad_per_s : {LoLA index: maximum speed} for the calibrated motors.
    Modes: 'limp' (nothing stiff), 'active' (a client controls), 'holding' (control released: positions held for
    hold_s), 'ramping' (stiffness falling to 0 at 1/ramp_s per second, positions held).
    """

    def __init__(self, speeds_rad_per_s: dict, *, hold_s: float = DEFAULT_HOLD_S, ramp_s: float = DEFAULT_RAMP_S,
                 stiffen_s: float = DEFAULT_STIFFEN_S, cycle_s: float = CYCLE_S):
        if not (hold_s >= 0 and ramp_s > 0 and stiffen_s > 0 and cycle_s > 0):
            raise ValueError("hold_s must be >= 0, ramp_s, stiffen_s and cycle_s > 0")
        self.speeds = np.zeros(N_LOLA)
        for i, speed in speeds_rad_per_s.items():
            self.speeds[i] = float(speed)
        self.calibrated = np.zeros(N_LOLA, dtype=bool)
        self.calibrated[list(CALIBRATED_MOTORS)] = True
        self.hold_s, self.ramp_s, self.stiffen_s, self.cycle_s = hold_s, ramp_s, stiffen_s, cycle_s
        self.mode = "limp"
        self.setpoint: np.ndarray | None = None  # rad, what is sent as Position
        self.stiffness = np.zeros(N_LOLA)  # what is sent as Stiffness
        self.stiffness_target = np.zeros(N_LOLA)
        self.seg_start = np.zeros(N_LOLA)
        self.seg_target = np.zeros(N_LOLA)
        self.seg_duration = np.zeros(N_LOLA)
        self.seg_elapsed = np.zeros(N_LOLA)
        self.moving = np.zeros(N_LOLA, dtype=bool)
        self.paused_reason: str | None = None
        self.cycles = 0
        self._released_cycle = 0
        self._warned: set = set()

    # ------------------------------------------------------------------------------------------ requests
    def set_stiffness(self, motors, stiffness: float) -> None:
        self.mode = "active"
        self.stiffness_target[list(motors)] = float(stiffness)

    def targets_of_head(self) -> dict:
        """{head joint: [current setpoint, target it moves to]} for the limit checks."""
        out = {}
        for name in HEAD_JOINTS:
            i = LOLA_INDEX[name]
            now = [] if self.setpoint is None else [float(self.setpoint[i])]
            out[name] = now + ([float(self.seg_target[i])] if self.moving[i] else [])
        return out

    def command(self, motor_targets: dict, speed_fraction: float) -> float:
        """Start moving {LoLA index: target rad} together at `speed_fraction`; returns the motion time (s).
        SafetyError if a joint is not stiff or the head would leave the HeadPitch table on the way."""
        if self.setpoint is None:
            raise NaocalError("no LoLA message yet: the joints' positions are unknown")
        limp = [LOLA_JOINTS[i] for i in motor_targets if self.stiffness_target[i] <= 0.0]
        if limp:
            raise SafetyError(f"{', '.join(limp)} at stiffness 0: set the stiffness before commanding")
        indices = list(motor_targets)
        start = self.setpoint[indices].copy()
        target = np.array([motor_targets[i] for i in indices])
        duration = float(np.max(np.abs(target - start) / (speed_fraction * self.speeds[indices])))
        self._check_head_path(dict(zip(indices, target)), duration)
        self.mode = "active"
        self.seg_start[indices] = start
        self.seg_target[indices] = target
        self.seg_duration[indices] = duration
        self.seg_elapsed[indices] = 0.0
        self.moving[indices] = True
        return duration

    def _check_head_path(self, new_targets: dict, duration: float, samples: int = 400) -> None:
        yaw_i, pitch_i = LOLA_INDEX["HeadYaw"], LOLA_INDEX["HeadPitch"]
        if yaw_i not in new_targets and pitch_i not in new_targets:
            return

        def track(i):  # (start, target, duration, elapsed) of the head joint's motion after this command
            if i in new_targets:
                return self.setpoint[i], new_targets[i], duration, 0.0
            if self.moving[i]:
                return self.seg_start[i], self.seg_target[i], self.seg_duration[i], self.seg_elapsed[i]
            return self.setpoint[i], self.setpoint[i], 0.0, 0.0

        tracks = [track(yaw_i), track(pitch_i)]
        horizon = max(max(d - e for _, _, d, e in tracks), 0.0)
        t = np.linspace(0.0, horizon, samples + 1)
        yaw, pitch = (s + (g - s) * (np.ones_like(t) if d <= 0 else np.minimum(1.0, (e + t) / d))
                      for s, g, d, e in tracks)
        table = limits.HEAD_PITCH_VS_YAW_TABLE  # vectorised here: this runs while LoLA waits for its answer
        lower = np.interp(np.abs(yaw), table[:, 0], table[:, 1])
        upper = np.interp(np.abs(yaw), table[:, 0], table[:, 2])
        outside = np.flatnonzero((pitch < lower - 1e-9) | (pitch > upper + 1e-9))
        if len(outside):
            problem = limits.head_pitch_problem(yaw[outside[0]], pitch[outside[0]], margin_rad=-1e-9)
            raise SafetyError(f"the head's way to its target leaves the table: {problem}")

    def release(self) -> None:
        """Control ended: stop where the joints are commanded now, hold, then ramp stiffness down."""
        self.moving[:] = False
        self.stiffness_target[:] = np.minimum(self.stiffness_target, self.stiffness)
        if np.any(self.stiffness > 0) or np.any(self.stiffness_target > 0):
            self.mode = "holding"
            self._released_cycle = self.cycles
        else:
            self.mode = "limp"

    def ramp_down(self) -> None:
        """Skip the hold: ramp stiffness down now (shutdown)."""
        self.release()
        if self.mode == "holding":
            self.mode = "ramping"
            self.stiffness_target[:] = 0.0

    # ------------------------------------------------------------------------------------------ one cycle
    def step(self, frame: LolaFrame | None) -> tuple[np.ndarray, np.ndarray]:
        """Advance one cycle given the newest sensor frame; returns (Position[25], Stiffness[25]) to send.
        `frame` None: this cycle's message could not be trusted; every setpoint stays where it is (limp joints
        included: they follow no measurement) and the temperature pause stays as it was."""
        self.cycles += 1
        if frame is None and self.setpoint is None:
            raise ValueError("the first cycle needs a frame")
        # Inside the limits even where the joint reads beyond them (limits.READING_MARGIN_RAD): stiffening a joint
        # at its stop then pulls it to the limit, never past it.
        measured = None if frame is None else np.clip(np.asarray(frame.position_rad, dtype=float), LOLA_LOWER,
                                                      LOLA_UPPER)
        if self.setpoint is None:
            self.setpoint = measured.copy()
        if frame is not None:
            self._check_temperature(frame)
        self._advance()
        return self._settle(measured)

    def _check_temperature(self, frame: LolaFrame) -> None:
        status = np.asarray(frame.status)

        # Temperature: pause all motion while a calibrated joint is hot.
        hot = [i for i in CALIBRATED_MOTORS if status[i] >= HOT_STATUS]
        for i in CALIBRATED_MOTORS:
            if status[i] >= 1 and (i, status[i]) not in self._warned:
                self._warned.add((i, status[i]))
                log.warning("%s temperature status %d (%.0f C)%s", LOLA_JOINTS[i], status[i],
                            frame.temperature_c[i], ": motion paused" if status[i] >= HOT_STATUS else "")
        self.paused_reason = None if not hot else ", ".join(
            f"{LOLA_JOINTS[i]} is hot (temperature status {status[i]}, {frame.temperature_c[i]:.0f} C)" for i in hot)

    def _advance(self) -> None:
        # Mode changes after a release.
        if self.mode == "holding" and (self.cycles - self._released_cycle) * self.cycle_s >= self.hold_s - 1e-9:
            self.mode = "ramping"
            self.stiffness_target[:] = 0.0

        # Motion: one cycle further along each joint's straight segment, unless paused or released.
        if self.mode == "active" and self.paused_reason is None and self.moving.any():
            previous = self.setpoint.copy()
            idx = np.flatnonzero(self.moving)
            self.seg_elapsed[idx] += self.cycle_s
            dur = self.seg_duration[idx]
            frac = np.where(dur > 0, np.minimum(self.seg_elapsed[idx] / np.where(dur > 0, dur, 1.0), 1.0), 1.0)
            self.setpoint[idx] = self.seg_start[idx] + (self.seg_target[idx] - self.seg_start[idx]) * frac
            self.moving[idx[frac >= 1.0]] = False
            yaw, pitch = self.setpoint[LOLA_INDEX["HeadYaw"]], self.setpoint[LOLA_INDEX["HeadPitch"]]
            if limits.head_pitch_problem(yaw, pitch, margin_rad=-1e-6) is not None:  # never expected: checked ahead
                log.error("head setpoint left the HeadPitch table: head stopped")
                for name in HEAD_JOINTS:
                    self.setpoint[LOLA_INDEX[name]] = previous[LOLA_INDEX[name]]
                    self.moving[LOLA_INDEX[name]] = False

    def _settle(self, measured: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        # Stiffness: up by at most cycle/stiffen_s, down by at most cycle/ramp_s per cycle; only calibrated motors.
        target = np.where(self.calibrated, np.clip(self.stiffness_target, 0.0, 1.0), 0.0)
        up, down = self.cycle_s / self.stiffen_s, self.cycle_s / self.ramp_s
        self.stiffness = np.clip(target, self.stiffness - down, self.stiffness + up)
        self.stiffness[self.stiffness < 1e-9] = 0.0
        if self.mode == "ramping" and not np.any(self.stiffness > 0):
            self.mode = "limp"

        # A joint without stiffness follows its measurement, so that stiffening it never jumps.
        limp = self.stiffness <= 0.0
        if measured is not None:
            self.setpoint[limp] = measured[limp]
        self.moving[limp] = False
        return self.setpoint.copy(), self.stiffness.copy()


class LolaBackend(JointTables, Backend):
    """A NAO V6 through LoLA's socket at `socket_path` (see the module docstring).

    cameras : objects with `name` ('bottom' or 'top'), capture() -> CameraImage | None, intrinsics(), close()
        (backends.v4l2_camera.V4L2Camera), each opened on its first capture; none for a robot served without a camera
        (capture then raises NaocalError naming the missing camera). `camera`: one camera, the same as (camera,).
    missing_cameras : {name: device} of cameras whose device was not there at start (named when asked for).
    intrinsics : the bottom camera's prior intrinsics if no camera is given.
    """

    name = "lola"

    def __init__(self, socket_path: str = DEFAULT_SOCKET, *, cameras=(), camera=None, missing_cameras=None,
                 intrinsics: CameraIntrinsics | None = None,
                 hold_s: float = DEFAULT_HOLD_S, ramp_s: float = DEFAULT_RAMP_S, stiffen_s: float = DEFAULT_STIFFEN_S,
                 first_message_timeout_s: float = 2.0, silence_timeout_s: float = 1.0):
        self.socket_path = os.fspath(socket_path)
        self.silence_timeout_s = float(silence_timeout_s)
        self._cameras = {getattr(c, "name", "bottom"): c for c in (*cameras, *([camera] if camera else []))}
        self._missing_cameras = dict(missing_cameras or {})  # {name: device} not found at start
        self._intrinsics = intrinsics
        self._limits = {j: limits.joint_limits()[j] for j in JOINTS}
        self._speeds = {j: limits.max_speeds()[j] for j in JOINTS}
        self.control = JointControl({MOTOR_OF[j]: self._speeds[j] for j in JOINTS if j != SHARED_MOTOR[1]},
                                    hold_s=hold_s, ramp_s=ramp_s, stiffen_s=stiffen_s)
        self._lock = threading.Lock()
        self._frame_arrived = threading.Condition(self._lock)
        self._frame: LolaFrame | None = None
        self._fault: NaocalError | None = None  # the fault (RobotTimeout, RobotFault) that ended motion
        self._closing = False
        self._closed = False
        self.messages_received = 0
        self._sock = self._connect()
        self._unpacker = msgpack.Unpacker(raw=False, max_buffer_size=MAX_MESSAGE_BYTES, strict_map_key=False)
        try:
            self._receive_first(float(first_message_timeout_s))
        except BaseException:
            self._sock.close()
            raise
        self._thread = threading.Thread(target=self._run, name="naocal-lola", daemon=True)
        self._thread.start()
        body_id, body_version, head_id, head_version = self._frame.robot_config
        log.info("connected to LoLA at %s: body %s (%s), head %s (%s)", self.socket_path, body_id, body_version,
                 head_id, head_version)

    # ------------------------------------------------------------------------------------------ socket
    def _connect(self) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(2.0)
        try:
            sock.connect(self.socket_path)
        except FileNotFoundError:
            sock.close()
            raise NaocalError(f"no LoLA socket at {self.socket_path}: is LoLA running (systemctl status lola)? "
                              "See docs/DEPLOY.md") from None
        except ConnectionRefusedError:
            sock.close()
            raise NaocalError(f"{self.socket_path}: connection refused: nothing listens there (LoLA stopped?), or "
                              "it accepts no further client") from None
        except OSError as err:
            sock.close()
            raise NaocalError(f"{self.socket_path}: cannot connect: {err.strerror or err}") from None
        return sock

    def _read_messages(self, timeout_s: float) -> list:
        """Messages that arrive within `timeout_s` (at least one, or [] on timeout), each stamped on receipt."""
        self._sock.settimeout(max(timeout_s, 1e-3))
        try:
            data = self._sock.recv(MAX_MESSAGE_BYTES)
        except socket.timeout:
            return []
        t_s = time.monotonic()
        if not data:
            raise ConnectionResetError("LoLA closed the connection")
        self._unpacker.feed(data)
        return [(message, t_s) for message in self._unpacker]

    def _receive_first(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        messages = []
        try:
            while not messages and time.monotonic() < deadline:
                messages = self._read_messages(deadline - time.monotonic())
        except OSError as err:
            raise NaocalError(f"{self.socket_path}: the connection closed at once ({err}): LoLA serves one client; "
                              "is another one (the team's framework, HuLA) connected?") from None
        except (msgpack.UnpackException, ValueError) as err:
            raise NaocalError(f"{self.socket_path} does not speak LoLA's msgpack ({type(err).__name__}); HuLA's "
                              "/tmp/hula uses HULKs' binary frames: connect to LoLA's /tmp/robocup") from None
        if not messages:
            raise NaocalError(
                f"connected to {self.socket_path}, but LoLA sent nothing within {timeout_s:g} s: LoLA serves one "
                "client and another one (the team's framework, or HuLA) probably holds it; stop it first "
                "(docs/DEPLOY.md)")
        message, t_s = messages[-1]
        try:
            frame = parse_sensor_message(message, t_s)
        except BadReading as err:
            raise RobotFault(f"{self.socket_path}: LoLA's first message cannot be trusted ({err}); nothing was "
                             "commanded: check the robot (docs/DEPLOY.md)") from None
        except ValueError as err:
            raise NaocalError(f"{self.socket_path} does not speak LoLA's sensor messages ({err}); HuLA's /tmp/hula "
                              "uses HULKs' binary frames: connect to LoLA's /tmp/robocup") from None
        self._answer(frame)

    def _answer(self, frame: LolaFrame | None) -> None:
        """Answer one message; `frame` None: it could not be trusted (the fault is set), answer it all the same so
        that LoLA goes on receiving the hold and the stiffness ramp."""
        with self._lock:
            if frame is not None:
                self._frame = frame
            self.messages_received += 1
            position, stiffness = self.control.step(frame)
            self._frame_arrived.notify_all()
        self._sock.settimeout(0.5)
        self._sock.sendall(pack_answer(position, stiffness))

    def _run(self) -> None:
        """Receive and answer until closed; a silent, closed or broken LoLA, or one reading that cannot be
        trusted, becomes a fault."""
        while not self._closed:
            try:
                messages = self._read_messages(0.1)
            except (OSError, msgpack.UnpackException, ValueError) as err:
                self._set_fault(f"LoLA connection lost: {err}")
                return
            if not messages:
                with self._lock:
                    self._check_fresh()
                continue
            for message, t_s in messages:
                try:
                    frame = parse_sensor_message(message, t_s)
                except ValueError as err:
                    frame = None
                    self._set_fault(f"LoLA sent a reading that cannot be trusted ({err})", RobotFault)
                try:
                    self._answer(frame)
                except OSError as err:
                    self._set_fault(f"cannot answer LoLA: {err}")
                    return

    def _set_fault(self, reason: str, error=RobotTimeout) -> None:
        with self._lock:
            self._set_fault_locked(reason, error)

    def _set_fault_locked(self, reason: str, error=RobotTimeout) -> None:
        """The safe state: motion refused from now on, the joints held for hold_s, then limp (control.release)."""
        if self._fault is None and not self._closed:
            self._fault = error(f"{reason}; motion is refused until the bridge is restarted (check the robot, "
                                "restart the bridge, then --resume)")
            log.error("%s", self._fault)
            self.control.release()
        self._frame_arrived.notify_all()

    def _check_fresh(self) -> None:
        """A fault once the newest trusted reading is older than silence_timeout_s: checked where readings are
        served too, so a stale one is never served, whatever the receiving thread is doing. Lock held."""
        age_s = time.monotonic() - self._frame.t_s
        if age_s > self.silence_timeout_s:
            self._set_fault_locked(f"LoLA sent no trusted reading for {age_s:.2f} s (more than "
                                   f"{self.silence_timeout_s:g} s)")

    def _raise_fault(self) -> None:
        """Raise the fault, if there is one (a fresh exception of its type). Lock held."""
        self._check_fresh()
        if self._fault is not None:
            raise type(self._fault)(str(self._fault))

    def _usable(self) -> None:
        """Raise unless motion may go on: closed, faulted or paused by a hot joint. Call with the lock held."""
        if self._closed or self._closing:
            raise NaocalError("the LoLA backend is closed")
        self._raise_fault()
        if self.control.paused_reason is not None:
            raise NaocalError(f"motion paused: {self.control.paused_reason}; let the robot cool, then --resume")

    # ------------------------------------------------------------------------------------------ Backend
    def robot_identity(self) -> dict:
        body_id, body_version, head_id, head_version = self._frame.robot_config
        return {"id": body_id, "model": f"NAO V{body_version.split('.')[0]} (LoLA)", "body_id": body_id,
                "head_id": head_id, "body_version": body_version, "head_version": head_version}

    def command(self, targets_rad: dict[str, float], speed_fraction: float) -> None:
        speed_fraction = limits.check_speed_fraction(speed_fraction)
        with self._lock:
            self._usable()
            targets = limits.check_targets(targets_rad, self._limits, head_angles=self.control.targets_of_head())
            if SHARED_MOTOR[0] in targets:  # one motor: as in NAOqi, LHipYawPitch's target wins
                targets.pop(SHARED_MOTOR[1], None)
            self.control.command({MOTOR_OF[name]: angle for name, angle in targets.items()}, speed_fraction)

    def set_stiffness(self, names, stiffness: float) -> None:
        names = [names] if isinstance(names, str) else list(names)
        unknown = [name for name in names if name not in MOTOR_OF]
        if unknown:
            raise SafetyError(f"unknown joint(s) {unknown}: naocal sets the stiffness of {', '.join(JOINTS)} only")
        stiffness = float(stiffness)
        if not 0.0 <= stiffness <= 1.0:
            raise SafetyError(f"stiffness must be in [0, 1], got {stiffness}")
        with self._lock:
            if self._closed or self._closing:
                self._usable()
            self._raise_fault()  # a hot joint may still be made limp: no _usable()
            self.control.set_stiffness({MOTOR_OF[name] for name in names}, stiffness)

    def release_control(self) -> None:
        with self._lock:
            if self.control.mode == "active":
                log.info("control released: holding for %g s, then stiffness to 0 over %g s", self.control.hold_s,
                         self.control.ramp_s)
            self.control.release()

    def read_joints(self) -> JointReading:
        with self._lock:
            self._raise_fault()
            frame = self._frame
        return JointReading(angles_rad={name: frame.position_rad[MOTOR_OF[name]] for name in JOINTS}, t_s=frame.t_s)

    def status(self) -> dict:
        """Also after a fault (it names it): the joints are then the last trusted reading, stamped with its own
        time t_s."""
        with self._lock:
            if not self._closed:
                self._check_fresh()
            frame, mode, paused = self._frame, self.control.mode, self.control.paused_reason
            fault = None if self._fault is None else str(self._fault)
            moving = bool(self.control.moving.any())
        body_id, body_version, head_id, head_version = frame.robot_config
        names = list(LOLA_JOINTS) + [SHARED_MOTOR[1]]
        joints = {}
        for name in names:
            i = LOLA_INDEX[SHARED_MOTOR[0]] if name == SHARED_MOTOR[1] else LOLA_INDEX[name]
            joints[name] = {"raw_rad": frame.position_rad[i], "stiffness": _reported(frame.stiffness[i]),
                            "temperature_c": _reported(frame.temperature_c[i]), "status": frame.status[i],
                            "current_a": _reported(frame.current_a[i])}
        return {"robot": {"body_id": body_id, "body_version": body_version, "head_id": head_id,
                          "head_version": head_version, "control": mode, "paused": paused, "fault": fault,
                          "moving": moving},
                "joints": joints, "t_s": frame.t_s}

    @property
    def cameras(self) -> tuple:
        """The cameras this driver serves: those given whose V4L2 device was present at start."""
        return tuple(self._cameras)

    def capture(self, camera: str = "bottom") -> CameraImage | None:
        if camera not in self._cameras:
            served = f"serves only the {' and '.join(self._cameras)} camera" if self._cameras else "has no camera"
            why = (f"its device {self._missing_cameras[camera]} was missing at start" if camera in
                   self._missing_cameras else "it was not asked for (--cameras, --no-camera)")
            raise NaocalError(f"this LoLA bridge {served}, not the {camera} camera: {why}")
        return self._cameras[camera].capture()

    def intrinsics(self) -> CameraIntrinsics:
        """The bottom camera's prior (the top one has the same lens); a served camera's own if no bottom one."""
        if self._cameras:
            return self._cameras.get("bottom", next(iter(self._cameras.values()))).intrinsics()
        if self._intrinsics is None:
            raise NaocalError("this LoLA bridge was started without a camera and without intrinsics")
        return self._intrinsics

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, duration_s: float) -> None:
        duration_s = float(duration_s)
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"sleep: duration_s must be finite and >= 0, got {duration_s}")
        deadline = time.monotonic() + duration_s
        while True:
            with self._lock:
                self._usable()
            remaining_s = deadline - time.monotonic()
            if remaining_s <= 0:
                return
            time.sleep(min(remaining_s, 0.05))

    def wait_cycles(self, n: int, timeout_s: float = 2.0) -> None:
        """Wait until `n` more LoLA messages have been answered (tests and tools); RobotTimeout past the deadline."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            goal = self.messages_received + int(n)
            while self.messages_received < goal:
                self._raise_fault()
                remaining_s = deadline - time.monotonic()
                if remaining_s <= 0:
                    raise RobotTimeout(f"LoLA delivered {goal - self.messages_received} message(s) too few within "
                                       f"{timeout_s:g} s")
                self._frame_arrived.wait(remaining_s)

    def close(self) -> None:
        """Ramp stiffness to 0 (positions held) over ramp_s, then disconnect from LoLA."""
        if self._closed:
            return
        with self._lock:
            self._closing = True
            self.control.ramp_down()
            stiff = self.control.mode != "limp"
        if stiff and self._fault is None:
            log.info("stopping: stiffness to 0 over %g s before disconnecting from LoLA", self.control.ramp_s)
            deadline = time.monotonic() + self.control.ramp_s + 1.0
            while time.monotonic() < deadline:
                with self._lock:
                    if self.control.mode == "limp" or self._fault is not None:
                        break
                time.sleep(0.02)
            else:
                log.warning("stiffness ramp did not finish within %.1f s", self.control.ramp_s + 1.0)
        with self._lock:
            self._closed = True
        self._thread.join(1.0)
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError as err:
            if err.errno not in (errno.ENOTCONN, errno.EBADF):
                log.debug("shutdown: %s", err)
        self._sock.close()
        for camera in self._cameras.values():
            camera.close()
