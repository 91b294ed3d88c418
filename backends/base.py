"""The backend interface: everything the agent may ask of a robot, real or simulated.

Implementations: `backends.mock.MockBackend` (PyBullet, simulated clock), `backends.bridge.BridgeBackend`
(network client of `naocal bridge serve`, which in turn drives the mock or NAOqi), and the wrapper
`backends.compensated.CompensatedBackend`. All angles are in rad, all times in s on the robot's clock.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

from naocal.backends.errors import RobotFault
from naocal.solver import limits as joint_limits_module
from naocal.solver.camera import CameraIntrinsics  # noqa: F401  (the backends report the one intrinsics type)
from naocal.solver.joints import JOINTS


@dataclass(frozen=True)
class JointReading:
    """One sample of the joint sensors."""

    angles_rad: dict[str, float]
    t_s: float  # robot clock time at which the encoders were sampled


def checked_reading(angles_rad, t_s, limits) -> JointReading:
    """A JointReading from what a robot reported, checked as every driver checks a reading before serving it: each
    angle a number (not a string, not a bool), finite, within its joint's `limits` plus
    solver.limits.READING_MARGIN_RAD; the time a finite number. RobotFault naming the first problem otherwise."""
    why = joint_limits_module.readings_problem(angles_rad, limits)
    if why is None and not (joint_limits_module.is_number(t_s) and math.isfinite(t_s)):
        why = f"its time {t_s!r} is not a finite number"
    if why is not None:
        raise RobotFault(f"the robot sent a reading that cannot be trusted: {why}")
    return JointReading(angles_rad={str(name): float(v) for name, v in angles_rad.items()}, t_s=float(t_s))


@dataclass(frozen=True)
class CameraImage:
    """One image of a camera ('bottom' or 'top')."""

    pixels: np.ndarray  # (height, width, 3) uint8, BGR
    t_exposure_s: float  # robot clock time of the exposure (middle of the frame)
    camera: str = "bottom"


def nominal_intrinsics(width_px: int = 640, height_px: int = 480) -> CameraIntrinsics:
    """A NAO camera's intrinsics from the OV5640's nominal field of view, 56.3 x 43.7 deg
    (Aldebaran's NAO V6 video camera documentation; docs/MOCK.md), at this resolution: fx about 598 px at 640 x 480 (teams calibrate about 618)."""
    return CameraIntrinsics(width_px=width_px, height_px=height_px,
                            fx_px=(width_px / 2) / math.tan(math.radians(56.3) / 2),
                            fy_px=(height_px / 2) / math.tan(math.radians(43.7) / 2),
                            cx_px=width_px / 2, cy_px=height_px / 2)


class Backend(abc.ABC):
    """A NAO, as the calibration agent sees it.

    Commands are non-blocking: `command` sets targets and returns; the joints then move at
    `speed_fraction` of their maximum speed. Waiting is done with `sleep` on the backend's own clock
    (simulated for the mock, wall-clock for a robot), so every deadline the agent sets is in robot time.
    """

    name = "abstract"
    cameras = ("bottom", "top")  # the cameras capture() offers

    @abc.abstractmethod
    def robot_identity(self) -> dict:
        """{'id': str, 'model': str, 'body_id': str, 'head_id': str}."""

    @abc.abstractmethod
    def joint_names(self) -> tuple[str, ...]:
        """The joints this backend can command and read (at least solver.joints.JOINTS)."""

    @abc.abstractmethod
    def joint_limits(self) -> dict[str, tuple[float, float]]:
        """(lower, upper) in rad per joint, as the robot enforces them."""

    @abc.abstractmethod
    def max_speeds(self) -> dict[str, float]:
        """Maximum joint speed in rad/s per joint."""

    @abc.abstractmethod
    def command(self, targets_rad: dict[str, float], speed_fraction: float) -> None:
        """Start moving the named joints to their targets. Raises SafetyError for an unsafe target."""

    @abc.abstractmethod
    def read_joints(self) -> JointReading:
        """The newest sample of the joint sensors (it lags the true motion by a few sensor cycles)."""

    @abc.abstractmethod
    def set_stiffness(self, names, stiffness: float) -> None:
        """Set the stiffness (0..1) of the named joints."""

    @abc.abstractmethod
    def capture(self, camera: str = "bottom") -> CameraImage | None:
        """The newest image of `camera` ('bottom' or 'top') that has arrived, or None if none has yet.

        Images arrive some time after their exposure: an image returned now may show the robot as it was
        before the last command. Check `t_exposure_s`.
        """

    @abc.abstractmethod
    def intrinsics(self) -> CameraIntrinsics:
        """The bottom camera's nominal (prior) intrinsics."""

    @abc.abstractmethod
    def now(self) -> float:
        """Robot clock, s."""

    @abc.abstractmethod
    def sleep(self, duration_s: float) -> None:
        """Let `duration_s` of robot time pass."""

    def gravity_torso_mps2(self) -> np.ndarray:
        """Gravity in the torso frame (m/s^2). A robot lying on its back: (-9.81, 0, 0)."""
        return np.array([-9.81, 0.0, 0.0])

    # What the controller commanded stays in force when this driver is closed and a new one opened on the same robot
    # (NAOqi keeps the last targets and stiffness); False where closing makes the robot safe or a new driver starts
    # afresh (the LoLA driver ramps the joints limp and starts limp; the mock's world is gone). A bridge client whose
    # server restarted carries on only if True (BridgeClient._check_same_server).
    keeps_commands_on_close = False

    def release_control(self) -> None:
        """The client that controlled motion let go: it released the robot or went silent past its lease.

        A driver that holds joints stiff makes the robot safe here (the LoLA driver: hold, then a slow stiffness
        ramp; docs/DEPLOY.md). Default: nothing (the mock; NAOqi keeps its last targets).
        """

    def status(self) -> dict:
        """Everything the robot reports, for `naocal bridge status`: {"robot": {...}, "joints": {name: {"raw_rad",
        "stiffness", "temperature_c", "status"}}, "t_s"}; values a backend cannot read are None. A reading that
        cannot be trusted is reported as {"robot": {..., "fault": reason}, "joints": {}, "t_s": None}."""
        identity = {str(k): str(v) for k, v in self.robot_identity().items()}
        try:
            reading = self.read_joints()
        except RobotFault as err:
            return {"robot": {**identity, "fault": str(err)}, "joints": {}, "t_s": None}
        return {
            "robot": identity,
            "joints": {name: {"raw_rad": float(angle), "stiffness": None, "temperature_c": None, "status": None}
                       for name, angle in reading.angles_rad.items()},
            "t_s": float(reading.t_s),
        }

    def close(self) -> None:
        """Release the robot (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class JointTables:
    """For a NAO backend that serves solver.joints.JOINTS with limit and speed tables it fills at start (`_limits`,
    `_speeds`: the model's, or what the robot reports): Backend's three joint queries, answered with copies so that
    no caller can change what the safety checks use."""

    _limits: dict[str, tuple[float, float]]
    _speeds: dict[str, float]

    def joint_names(self) -> tuple[str, ...]:
        return JOINTS

    def joint_limits(self) -> dict[str, tuple[float, float]]:
        return dict(self._limits)

    def max_speeds(self) -> dict[str, float]:
        return dict(self._speeds)
