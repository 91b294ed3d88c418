"""The Duckiebot over naocal's bridge (docs/PROTOCOL.md "Duckiebot commands"; docs/DEPLOY.md "Duckiebot (DB21)"):
the mission runs on a laptop, `naocal bridge serve --robot duckiebot` on the robot. One protocol, one server, one
security model with the NAO's: this module only adds the kind's two ends.

- `ServedDuckiebot`: the server's end. Wraps a driver with the mission's robot interface (now, command, advance,
  grab; kinds.duckiebot.ros_driver.RosDuckiebot on a DB21, kinds.duckiebot.mock.DuckiebotMock for tests and
  teaching) and answers its COMMANDS (registered with the protocol).
- `DuckiebotBridge`: the client's end, the mission's robot interface over the bridge (`naocal calibrate --robot
  duckiebot --backend bridge --endpoint URL`).

Safety on the server, whatever the client sends (the safe state = both duties 0):
- every duty is checked before the driver hears it (kinematics.duty_problem: finite, within [-limit, limit]),
  refused with a SafetyError, never clipped;
- any client may `stop` the wheels (both duties 0), lease or not: stopping only makes the robot safer; the
  controller is told at its next motion request (backends/bridge_server.py);
- a watchdog stops the wheels when they turn and no motion request (wheels, sleep, grab: the lease holder's only)
  has come for `watchdog_s` (a dead or hung client), and when control ends (release, the lease lapsing); the
  controller's next motion request is then refused once (RobotFault: its log would not be what happened; `stop`
  never is), a new controller's is not;
- the wheels stop when the server shuts down (close);
- every reading is checked before it is echoed: a time that is not finite, a frame not of the camera's size or not
  8-bit grey, encoder rows not in time order or not whole numbers: RobotFault, wheels stopped.
The client checks what it receives again before the mission uses it (a robot name that becomes a file name, a
frame that decodes to the camera's size, a clock that never goes back).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time

import cv2
import numpy as np

from naocal.backends.bridge import BridgeClient
from naocal.backends.bridge_server import ServedRobot, check_sleep
from naocal.backends.errors import BridgeError, RobotFault
from naocal.backends.protocol import (ProtocolError, finite_or_nan_float, is_motion_command, register_kind_commands,
                                     time_s)
from naocal.kinds.duckiebot.drive_log import MAX_TICKS, write_encoders
from naocal.kinds.duckiebot.kinematics import duty_problem
from naocal.kinds.duckiebot.robot import DEFAULT_LIMIT, MODELS, decoded_frame, duckiebot, robot_name_problem
from naocal.solver.errors import NaocalError, SafetyError

log = logging.getLogger("naocal.bridge.duckiebot")

DEFAULT_WATCHDOG_S = 1.0  # as the ROS driver's: the mission never leaves the wheels turning longer without a call
MAX_ENCODER_ROWS = 200_000  # per encoder_ticks reply (about 4 MB): 30 Hz for 1.8 h
IMAGE_FORMATS = {"png": ".png", "jpeg": ".jpg"}
PNG_COMPRESSION = 1  # fastest: a 640 x 480 grey frame in about 5 ms, lossless (the mission sees what the robot saw)

# The Duckiebot's commands (protocol revision 2; docs/PROTOCOL.md), beside the session commands every kind has.
# Duties are fractions of full power in [-1, 1]; passed through unclipped (NaN too) so that the server's one check
# (kinematics.duty_problem) refuses them with a SafetyError. `grab` steps a simulated robot's clock (the wheels in
# force move it): it needs the lease. `stop` (both duties 0 -> {t_s}) is the session's: any client may send it, lease or
# not, and it is never refused for a fault (the unwinding must not fail).
COMMANDS = register_kind_commands("duckiebot", {
    "facts": ({}, False),  # -> robot id and model, camera size, wheels (radius, baseline, encoders), duty limit
    "encoder_ticks": ({"from_s": time_s, "to_s": time_s}, False),  # -> {ticks_per_revolution, rows [[t, l, r]]}
    "wheels": ({"left_duty": finite_or_nan_float, "right_duty": finite_or_nan_float}, True),  # -> {t_s}
    "grab": ({}, True),  # -> {image (bin), format png|jpeg, t_exposure_s (mid-exposure), width_px, height_px}
})


def _finite_time(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value):
        raise RobotFault(f"{what} {value!r} is not a time")
    return float(value)


def _tick_rows(rows, what: str, t_from_s: float = -math.inf, t_to_s: float = math.inf) -> list:
    """Encoder rows (t_s, left_ticks, right_ticks) checked: finite times in increasing order within the window, whole
    numbers of ticks; RobotFault naming the first bad row."""
    out, previous = [], -math.inf
    for number, row in enumerate(rows, 1):
        try:
            t, left, right = row
        except (TypeError, ValueError):
            raise RobotFault(f"{what}: row {number} is not (t_s, left_ticks, right_ticks)") from None
        t = _finite_time(t, f"{what}: row {number}: t_s")
        if not (previous < t and t_from_s <= t <= t_to_s):
            raise RobotFault(f"{what}: row {number}: t_s {t!r} is not after the previous row ({previous!r}) within "
                             f"[{t_from_s!r}, {t_to_s!r}]")
        for side, ticks in (("left", left), ("right", right)):
            if isinstance(ticks, bool) or not isinstance(ticks, (int, np.integer)) or abs(int(ticks)) > MAX_TICKS:
                raise RobotFault(f"{what}: row {number}: {side}_ticks {ticks!r} is not a whole number of ticks")
        out.append([t, int(left), int(right)])
        previous = t
    return out


def check_watchdog(watchdog_s) -> float:
    """--watchdog-s: a number of seconds within [0.05, 10] (NaN refused), else NaocalError."""
    if isinstance(watchdog_s, bool) or not (isinstance(watchdog_s, (int, float)) and 0.05 <= watchdog_s <= 10.0):
        raise NaocalError(f"--watchdog-s must be within [0.05, 10] s, got {watchdog_s!r}")
    return float(watchdog_s)


class ServedDuckiebot(ServedRobot):
    """A Duckiebot driver as `naocal bridge serve --robot duckiebot` serves it (see the module's safety list).

    driver : the mission's robot interface (now, command(left, right) -> t, advance(s), grab() -> (t, grey image),
        close()); `encoder_ticks(t_from_s, t_to_s)` and `ticks_per_revolution` where it has wheel encoders.
    robot_id : the robot's name (its hostname, $VEHICLE_NAME; the mock's `mock<seed>`): becomes file names.
    """

    kind = "duckiebot"

    def __init__(self, driver, *, robot_id: str, model: str = "DB21", limit: float = DEFAULT_LIMIT,
                 watchdog_s: float = DEFAULT_WATCHDOG_S):
        problem = robot_name_problem(robot_id)
        if problem:
            raise NaocalError(problem)
        check_watchdog(watchdog_s)
        self.driver, self.robot_id, self.description = driver, robot_id, duckiebot(model)
        self.limit, self.watchdog_s = float(limit), float(watchdog_s)
        has_encoders = callable(getattr(driver, "encoder_ticks", None))
        self.ticks_per_revolution = int(driver.ticks_per_revolution) if has_encoders else None
        self._lock = threading.RLock()  # one driver call at a time: requests, the watchdog, the shutdown
        self._duties = (0.0, 0.0)  # as last sent to the driver
        self._last_motion = time.monotonic()
        self._fault = None  # why the server stopped the wheels on its own: refused to the next motion request
        self._closed = threading.Event()
        self._watchdog = threading.Thread(target=self._watch, name="naocal-duckiebot-watchdog", daemon=True)
        self._watchdog.start()

    # ------------------------------------------------------------------------------------------ ServedRobot
    def robot_identity(self) -> dict:
        return {"id": self.robot_id, "model": self.description.model}

    def dispatch(self, cmd: str, args: dict):
        with self._lock:
            if self._closed.is_set():
                raise RobotFault("the server is shutting down (the wheels are stopped)")
            try:
                return self._run(cmd, args)
            finally:
                if is_motion_command(cmd):  # the controller's requests only keep the wheels turning
                    self._last_motion = time.monotonic()

    def control_granted(self) -> None:
        with self._lock:
            self._fault = None  # the stop was the last controller's to hear of

    def release_control(self) -> None:
        with self._lock:
            if self._duties != (0.0, 0.0):
                self._fault = ("the server stopped the wheels: control ended (released, or the lease lapsed) while "
                               "they turned")
                log.warning("%s", self._fault)
            self._stop_quietly()

    def close(self) -> None:
        """Wheels stopped, watchdog ended, the driver closed. Safe to call twice."""
        with self._lock:
            if self._closed.is_set():
                return
            self._stop_quietly()
            self._closed.set()
        self._watchdog.join(1.0)
        self.driver.close()

    # ------------------------------------------------------------------------------------------ safety
    def _stop_quietly(self) -> None:
        """Both duties 0, from any thread (under the lock); never raises (the stop must not hide why we stopped)."""
        try:
            self.driver.command(0.0, 0.0)
            self._duties = (0.0, 0.0)
        except Exception:
            log.exception("could not stop the wheels")

    def _watch(self) -> None:
        while not self._closed.wait(min(0.05, self.watchdog_s / 4)):
            with self._lock:
                silent_s = time.monotonic() - self._last_motion
                if self._duties != (0.0, 0.0) and silent_s > self.watchdog_s and not self._closed.is_set():
                    self._fault = (f"the server stopped the wheels: no request from the controlling client for "
                                   f"{silent_s:.2f} s while they turned (watchdog {self.watchdog_s:g} s)")
                    log.warning("%s", self._fault)
                    self._stop_quietly()

    def _raise_fault(self) -> None:
        """A stop the client did not ask for is told to its next motion request, once."""
        fault, self._fault = self._fault, None
        if fault is not None:
            raise RobotFault(fault)

    def _refuse(self, problem: str):
        self._stop_quietly()
        raise RobotFault(f"{problem} (the wheels were stopped)")

    def _time(self, value, what: str) -> float:
        try:
            return _finite_time(value, what)
        except RobotFault as err:
            self._refuse(str(err))

    # ------------------------------------------------------------------------------------------ commands
    def _run(self, cmd: str, args: dict):
        driver = self.driver
        if cmd == "robot_identity":
            return self.robot_identity()
        if cmd == "facts":
            d = self.description
            return {"robot_id": self.robot_id, "model": d.model, "width_px": d.camera.width_px,
                    "height_px": d.camera.height_px, "radius_m": d.radius_m, "baseline_m": d.baseline_m,
                    "ticks_per_revolution": self.ticks_per_revolution, "duty_limit": self.limit,
                    "watchdog_s": self.watchdog_s}
        if cmd == "now":
            return self._time(driver.now(), "the robot's clock")
        if cmd == "stop":
            return {"t_s": self._wheels(0.0, 0.0)}
        if cmd == "wheels":
            return {"t_s": self._wheels(args["left_duty"], args["right_duty"])}
        if cmd == "sleep":
            duration_s = check_sleep(args["duration_s"])
            self._raise_fault()
            driver.advance(duration_s)
            return None
        if cmd == "grab":
            self._raise_fault()
            return self._grab()
        if cmd == "encoder_ticks":
            return self._encoder_ticks(args["from_s"], args["to_s"])
        raise ProtocolError(f"unknown command {cmd!r}", "UnknownCommand")  # COMMANDS and this disagree

    def _wheels(self, left: float, right: float) -> float:
        for name, duty in (("left", left), ("right", right)):
            problem = duty_problem(name, duty, self.limit)
            if problem:
                raise SafetyError(f"refused wheel command: {problem}")
        if (left, right) != (0.0, 0.0):
            self._raise_fault()
        t = self.driver.command(float(left), float(right))
        self._duties = (float(left), float(right))
        return self._time(t, "the wheels' command time")

    def _grab(self) -> dict:
        t, image = self.driver.grab()
        t = self._time(t, "the frame's time")
        camera = self.description.camera
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 \
                or image.shape != (camera.height_px, camera.width_px):
            shape = getattr(image, "shape", type(image).__name__)
            self._refuse(f"a frame of shape {shape} and type {getattr(image, 'dtype', '?')}, expected 8-bit grey "
                         f"{camera.width_px} x {camera.height_px}")
        ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
        if not ok:
            self._refuse(f"the frame of {t:.3f} s does not encode as PNG")
        return {"image": data.tobytes(), "format": "png", "t_exposure_s": t, "width_px": camera.width_px,
                "height_px": camera.height_px}

    def _encoder_ticks(self, t_from_s: float, t_to_s: float) -> dict:
        if self.ticks_per_revolution is None:
            return {"ticks_per_revolution": None, "rows": []}
        rows = self.driver.encoder_ticks(t_from_s, t_to_s)
        if len(rows) > MAX_ENCODER_ROWS:
            raise ProtocolError(f"encoder_ticks: {len(rows)} rows in [{t_from_s}, {t_to_s}] s, more than "
                                f"{MAX_ENCODER_ROWS} per reply: ask for a shorter window", "TooLarge")
        try:
            rows = _tick_rows(rows, "the wheel encoders", t_from_s, t_to_s)
        except RobotFault as err:
            self._refuse(str(err))
        return {"ticks_per_revolution": self.ticks_per_revolution, "rows": rows}


def open_served(args):
    """(ServedDuckiebot, clock, state_persists) for `naocal bridge serve --robot duckiebot --driver mock|ros`."""
    if getattr(args, "effect", None):
        raise NaocalError("--effect: the Duckiebot's mock draws its hidden effects per seed (docs/DUCKIEBOT.md)")
    watchdog_s = check_watchdog(DEFAULT_WATCHDOG_S if getattr(args, "watchdog_s", None) is None else args.watchdog_s)
    if args.driver == "mock":
        from naocal.kinds.duckiebot.mock import DuckiebotMock

        if args.seed < 0:
            raise NaocalError(f"--seed must not be negative, got {args.seed}")
        robot = DuckiebotMock(args.seed, args.mock or "realistic")
        try:
            return ServedDuckiebot(robot, robot_id=f"mock{args.seed}", watchdog_s=watchdog_s), "simulated", False
        except BaseException:
            robot.close()
            raise
    if args.driver != "ros":
        raise NaocalError(f"--driver {args.driver} drives a NAO; a Duckiebot is served with --driver ros (on the "
                          "robot) or --driver mock")
    if args.mock is not None:
        raise NaocalError("--mock is for --driver mock")
    vehicle = os.environ.get("VEHICLE_NAME")
    if not vehicle:
        raise NaocalError("--driver ros: $VEHICLE_NAME is not set (Duckietown's containers set it to the robot's name: "
                          "run inside dt-ros-commons on the robot; docs/DEPLOY.md)")
    from naocal.kinds.duckiebot.ros_driver import RosDuckiebot

    robot = RosDuckiebot(vehicle)
    try:
        return ServedDuckiebot(robot, robot_id=vehicle, watchdog_s=watchdog_s), "wall", True
    except BaseException:
        robot.close()
        raise


class DuckiebotBridge(BridgeClient):
    """A Duckiebot behind `naocal bridge serve --robot duckiebot`: the mission's robot interface (now, command,
    advance, grab, save_encoders, close; kinds.duckiebot.mission). Parameters: BridgeClient's (`lease_file`: the run
    directory's bridge.token, so that a resumed run takes its lease back at once).

    A run resumed over the bridge (calibrate --resume) takes the same path as on the robot (mission.run_mission with
    restart_phase): the wheels commanded stopped first (`stop` needs no lease), the logs replayed without a call to
    the robot, then the phase started again after a break in the log (Session.new_segment: a stop, a settle, a stop
    whose time must follow the log's). Its first motion request takes back the lease of the process it resumes
    (lease_file) and first hears what the server told that process while it was gone (BridgeClient.take_back_lease).
    A server that restarted under a run is fatal to it (BridgeClient._check_same_server): the server stops the wheels
    when it ends (ServedDuckiebot keeps no command on close)."""

    kind = "duckiebot"

    def __init__(self, endpoint: str, **kwargs):
        super().__init__(endpoint, **kwargs)
        self._facts = None
        self._last_t = -math.inf  # the newest robot time the server told: its clock never goes back

    def _robot_time(self, value, what: str) -> float:
        try:
            t = _finite_time(value, f"{self.endpoint}: {what}")
        except RobotFault as err:
            raise BridgeError(str(err)) from None
        if t < self._last_t:
            raise BridgeError(f"{self.endpoint}: {what} {t!r} s is before a time the robot gave already "
                              f"({self._last_t!r} s): another robot, or its clock went back")
        self._last_t = t
        return t

    def facts(self) -> dict:
        """The robot (asked once, checked): robot_id, model, width_px, height_px, radius_m, baseline_m,
        ticks_per_revolution (None: no encoders), duty_limit, watchdog_s."""
        if self._facts is None:
            facts = self._call("facts")
            problem = None
            if not isinstance(facts, dict):
                problem = "not a map"
            else:
                nominal = duckiebot("DB21").camera
                problem = robot_name_problem(facts.get("robot_id"))
                ticks, limit = facts.get("ticks_per_revolution"), facts.get("duty_limit")
                if problem is None and facts.get("model") not in MODELS:
                    problem = f"model {facts.get('model')!r} is not one of {', '.join(MODELS)}"
                elif problem is None and (facts.get("width_px"), facts.get("height_px")) != (nominal.width_px,
                                                                                             nominal.height_px):
                    problem = (f"a {facts.get('width_px')!r} x {facts.get('height_px')!r} camera; the mission takes "
                               f"{nominal.width_px} x {nominal.height_px} (Duckietown's camera node)")
                elif problem is None and ticks is not None and not (
                        type(ticks) is int and 1 <= ticks <= 100_000):
                    problem = f"ticks_per_revolution {ticks!r} is not a whole number in 1..100000"
                elif problem is None and not (type(limit) in (int, float) and 0 < limit <= 1):
                    problem = f"duty_limit {limit!r} is not within (0, 1]"
            if problem:
                raise BridgeError(f"{self.endpoint}: facts: {problem}")
            self._facts = facts
        return dict(self._facts)

    @property
    def robot_id(self) -> str:
        return self.facts()["robot_id"]

    def now(self) -> float:
        return self._robot_time(self._call("now"), "the robot's clock")

    def command(self, left: float, right: float) -> float:
        """The duties, held until the next command (the server checks them: SafetyError, nothing sent); returns the
        robot time they took effect. (0, 0) is `stop`, which the server never refuses."""
        if (left, right) == (0.0, 0.0):
            result = self._call("stop")  # needs no lease; with ours, the server knows it is the controller's own
        else:
            result = self._motion_call("wheels", {"left_duty": float(left), "right_duty": float(right)})
        return self._robot_time(result.get("t_s") if isinstance(result, dict) else None, "the command's time")

    def advance(self, duration_s: float) -> None:
        """Let `duration_s` of robot time pass, the duties in force."""
        self._sleep_robot(duration_s)

    def grab(self) -> tuple[float, np.ndarray]:
        """(mid-exposure robot time, grey image) of a new frame, checked: decodes, the camera's size."""
        facts = self.facts()
        result = self._motion_call("grab", {})
        if not isinstance(result, dict) or result.get("format") not in IMAGE_FORMATS \
                or not isinstance(result.get("image"), bytes):
            raise BridgeError(f"{self.endpoint}: grab: the reply holds no PNG or JPEG image")
        t = self._robot_time(result.get("t_exposure_s"), "the frame's time")
        image, problem = decoded_frame(result["image"], facts["width_px"], facts["height_px"])
        if problem:
            raise BridgeError(f"{self.endpoint}: grab: the frame of {t:.3f} s {problem}")
        return t, image

    def encoder_ticks(self, t_from_s: float, t_to_s: float) -> list:
        """The encoder rows (t_s, left_ticks, right_ticks) the robot counted within [t_from_s, t_to_s], checked."""
        result = self._call("encoder_ticks", {"from_s": float(t_from_s), "to_s": float(t_to_s)})
        if not isinstance(result, dict) or not isinstance(result.get("rows"), list):
            raise BridgeError(f"{self.endpoint}: encoder_ticks: the reply holds no rows")
        try:
            return _tick_rows(result["rows"], f"{self.endpoint}: encoder_ticks", t_from_s, t_to_s)
        except RobotFault as err:
            raise BridgeError(str(err)) from None

    def save_encoders(self, log_dir, t_from_s: float, t_to_s: float) -> int:
        """The robot's ticks within [t_from_s, t_to_s] into the drive log (drive_log.write_encoders); the rows
        written (0 for a robot without encoders)."""
        ticks = self.facts()["ticks_per_revolution"]
        if ticks is None:
            return 0
        return write_encoders(log_dir, self.encoder_ticks(t_from_s, t_to_s), ticks)

    def close(self) -> None:
        """The wheels stopped (best effort: the server's watchdog and lease stop them too), control released."""
        if not self._closed and self._token is not None:
            try:
                self._call("stop", timeout_s=min(self.timeout_s, 1.0), retries=0)
            except NaocalError as err:
                log.warning("%s: could not stop the wheels on closing (%s); the server's watchdog stops them",
                            self.endpoint, err)
        super().close()
