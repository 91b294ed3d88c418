"""NAO joint limits: the URDF's box limits, the documented RKneePitch range, and the HeadPitch-vs-HeadYaw table.

Every backend that can move a real joint checks its targets against these before sending anything, with the one
implementation here: `check_targets` (known joint, finite, inside its box, HeadPitch inside the table for every
HeadYaw the head may have) and `check_speed_fraction`. The agent's own guard uses `limit_problem` and
`head_pitch_problem` with its margins. Every driver checks each joint reading with `readings_problem` before it
serves or echoes it (a number, finite, within the limits plus READING_MARGIN_RAD; backends.base.checked_reading).
The URDF is `solver/data/nao_v50.urdf` (the nominal model, see docs/ROBOT.md; Aldebaran's NAO V6 joint
documentation); it is parsed once.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from naocal.solver.errors import DataError, SafetyError
from naocal.solver.urdf import NOMINAL_URDF, nominal_urdf, parse_urdf

URDF_PATH = NOMINAL_URDF

# The URDF's RKneePitch range copies LKneePitch; the Aldebaran documentation gives the right knee its own range.
DOCUMENTED_LIMITS_RAD = {"RKneePitch": (-0.103083, 2.120198)}

# HeadPitch range as a function of HeadYaw (Aldebaran documentation; NAOqi clamps to it). Symmetric in yaw.
# Columns: |HeadYaw| (rad), HeadPitch lower (rad), HeadPitch upper (rad).
HEAD_PITCH_VS_YAW_TABLE = np.array(
    [
        [0.000, -0.672, 0.515],
        [0.486, -0.672, 0.422],
        [0.756, -0.548, 0.370],
        [0.903, -0.480, 0.330],
        [1.090, -0.430, 0.300],
        [1.527, -0.330, 0.200],
        [2.086, -0.449, 0.330],
    ]
)


def head_pitch_limits(head_yaw_rad: float) -> tuple[float, float]:
    """(lower, upper) HeadPitch in rad allowed at `head_yaw_rad`, linearly interpolated in the documented table.

    Beyond the table's last yaw (the HeadYaw limit) the last row holds; a non-finite yaw raises ValueError.
    """
    yaw = float(head_yaw_rad)
    if not np.isfinite(yaw):
        raise ValueError(f"head_yaw_rad must be finite, got {head_yaw_rad!r}")
    table = HEAD_PITCH_VS_YAW_TABLE
    abs_yaw = abs(yaw)
    lower = float(np.interp(abs_yaw, table[:, 0], table[:, 1]))
    upper = float(np.interp(abs_yaw, table[:, 0], table[:, 2]))
    return lower, upper


def _urdf_joint_table(urdf_path) -> dict[str, tuple[float, float, float]]:
    """{joint: (lower_rad, upper_rad, max_speed_rad_per_s)} for every revolute joint of the URDF."""
    urdf = nominal_urdf() if Path(urdf_path) == NOMINAL_URDF else parse_urdf(urdf_path)
    table = {}
    for joint in urdf.joints.values():
        if joint.kind != "revolute":
            continue
        values = (joint.lower, joint.upper, joint.velocity)
        if not all(np.isfinite(values)):
            raise DataError(urdf_path, "<limit> needs numeric lower, upper and velocity", field=joint.name)
        table[joint.name] = values
    return table


def joint_limits(urdf_path=URDF_PATH) -> dict[str, tuple[float, float]]:
    """(lower, upper) in rad for every revolute joint: the URDF's box limits, RKneePitch from the documentation.

    HeadPitch's box is its widest range; also apply `head_pitch_limits` for the actual HeadYaw.
    """
    limits = {name: (lo, hi) for name, (lo, hi, _) in _urdf_joint_table(str(urdf_path)).items()}
    limits.update(DOCUMENTED_LIMITS_RAD)
    return limits


def command_limits(robot=None) -> dict[str, tuple[float, float]]:
    """(lower, upper) in rad that the agent commands each joint within: `joint_limits` narrowed by the robot
    description's `command_limits_rad` (the NAO: HeadYaw +-0.7 rad). The planner, the measurement's head moves and
    the safety guard all take it from here."""
    from naocal.solver.robot import nao

    limits = dict(joint_limits())
    for joint, (lower, upper) in (robot or nao()).command_limits.items():
        box = limits.get(joint, (-math.inf, math.inf))
        limits[joint] = (max(box[0], lower), min(box[1], upper))
    return limits


def max_speeds(urdf_path=URDF_PATH) -> dict[str, float]:
    """Maximum joint speed in rad/s for every revolute joint (the URDF's `velocity`)."""
    return {name: speed for name, (_, _, speed) in _urdf_joint_table(str(urdf_path)).items()}


# A joint sensor reading this far beyond the joint's limits cannot be right. Wider than the largest encoder offset
# real robots carry (HipYawPitch up to 12 deg, docs/MOCK.md), so a joint at its stop still reads inside it;
# narrower than any reading that is plainly wrong (LKneePitch 2.5 rad against its 2.11 rad limit).
READING_MARGIN_RAD = 0.25


# ---------------------------------------------------------------------------------------------- checks
def _as_angle(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def limit_problem(joint: str, angle_rad, limits: Mapping, *, margin_rad: float = 0.0) -> str | None:
    """Why `angle_rad` is not a safe target for `joint` under `limits` ({joint: (lower, upper)} rad, shrunk by
    `margin_rad` on both sides), or None: unknown joint, not a finite number, outside the box."""
    if joint not in limits:
        return f"unknown joint {joint!r}: this robot commands only {', '.join(limits)}"
    angle = _as_angle(angle_rad)
    if not math.isfinite(angle):
        return f"{joint} target {angle_rad!r} is not a finite angle"
    lower, upper = (float(v) for v in limits[joint])
    lower, upper = lower + margin_rad, upper - margin_rad
    if not lower <= angle <= upper:
        return f"{joint} target {angle:.4f} rad outside its limits [{lower:.4f}, {upper:.4f}] rad"
    return None


def is_number(value) -> bool:
    """A real number, as a sensor or a file gives one: int or float (numpy's too), not a bool, not a string."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def reading_problem(joint: str, value, limits: Mapping, *, margin_rad: float = READING_MARGIN_RAD) -> str | None:
    """Why `value`, a sensor reading of `joint`, cannot be trusted, or None: not a number (a string or a bool is
    malformed, even if it would convert), not finite, or beyond the joint's limits by more than `margin_rad`.
    A joint `limits` does not know is not checked against a box."""
    if not is_number(value):
        return f"{joint} reads {value!r} ({type(value).__name__}), not a number"
    angle = float(value)
    if not math.isfinite(angle):
        return f"{joint} reads {angle}, not a finite number"
    if joint in limits:
        lower, upper = (float(v) for v in limits[joint])
        if not lower - margin_rad <= angle <= upper + margin_rad:
            return (f"{joint} reads {angle:.6g} rad, beyond its limits [{lower:.4f}, {upper:.4f}] rad by more than "
                    f"{margin_rad:g} rad: an impossible reading")
    return None


def readings_problem(readings: Mapping, limits: Mapping, *, margin_rad: float = READING_MARGIN_RAD) -> str | None:
    """The first of `readings` ({joint: value}) that cannot be trusted (`reading_problem`), or None. Every
    driver checks each reading with this before it serves or echoes it."""
    for joint, value in readings.items():
        why = reading_problem(joint, value, limits, margin_rad=margin_rad)
        if why is not None:
            return why
    return None


def head_pitch_problem(head_yaw_rad: float, head_pitch_rad: float, *, margin_rad: float = 0.0) -> str | None:
    """Why HeadPitch `head_pitch_rad` is not allowed at HeadYaw `head_yaw_rad` by the HeadPitch-vs-HeadYaw table
    (narrowed by `margin_rad`; a small negative margin is a tolerance), or None."""
    lower, upper = head_pitch_limits(head_yaw_rad)
    lower, upper = lower + margin_rad, upper - margin_rad
    if not lower <= float(head_pitch_rad) <= upper:  # also refuses NaN
        return (f"HeadPitch {float(head_pitch_rad):.4f} rad outside [{lower:.4f}, {upper:.4f}] rad allowed at "
                f"HeadYaw {float(head_yaw_rad):.4f} rad (HeadPitch-vs-HeadYaw table)")
    return None


def check_speed_fraction(speed_fraction) -> float:
    """`speed_fraction` as a float in (0, 1]; SafetyError otherwise (NaN included)."""
    speed = _as_angle(speed_fraction)
    if not 0.0 < speed <= 1.0:
        raise SafetyError(f"speed_fraction must be in (0, 1], got {speed_fraction!r}")
    return speed


def check_targets(targets_rad: Mapping, limits: Mapping, *,
                  head_angles: Mapping[str, Iterable[float]] | None = None) -> dict[str, float]:
    """The one limit check every driver applies to a command before sending anything.

    targets_rad : {joint: angle rad} to command.
    limits : {joint: (lower, upper)} rad the driver enforces (its joints; anything else is unknown).
    head_angles : for a head joint NOT in this command, every angle it may have while this command runs (where it
        reads now, and the target it may still be moving to). Required when the command names one head joint only.

    Returns {joint: float}; raises SafetyError naming the first problem (unknown joint, non-finite, outside the
    box, HeadPitch outside the HeadPitch-vs-HeadYaw table for some HeadYaw the head may have).
    """
    if not isinstance(targets_rad, Mapping):
        raise SafetyError("targets must be a {joint: angle} mapping")
    checked = {}
    for joint, angle in targets_rad.items():
        why = limit_problem(joint, angle, limits)
        if why is not None:
            raise SafetyError(why)
        checked[joint] = float(angle)
    if "HeadYaw" in checked or "HeadPitch" in checked:
        options = {name: [checked[name]] for name in ("HeadYaw", "HeadPitch") if name in checked}
        for name in ("HeadYaw", "HeadPitch"):
            if name not in options:
                options[name] = [float(a) for a in (head_angles or {}).get(name, ())]
                if not options[name]:
                    raise ValueError(f"check_targets: a command of one head joint needs head_angles[{name!r}]")
        for yaw in options["HeadYaw"]:
            for pitch in options["HeadPitch"]:
                why = head_pitch_problem(yaw, pitch)
                if why is not None:
                    raise SafetyError(why)
    return checked
