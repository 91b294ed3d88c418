"""Applying a calibration on the robot: the `apply` API of issue 8.

    compensated command = requested + c      (send this to the motors to reach `requested`)
    corrected reading   = measured  - c      (the true joint angle, given what the encoder says)

c is the stored offset (naocal.offsets/1 `joint_offsets_rad`; c = -alpha of the model q_true = theta + alpha).
Joints the file does not calibrate (arms, or a head without offsets) pass unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping

from naocal.solver.offsets import Offsets


def _offset_table(offsets) -> Mapping:
    """{joint: c} from an Offsets or a plain mapping of joint -> c (rad)."""
    if isinstance(offsets, Offsets):
        return offsets.joint_offsets_rad
    if isinstance(offsets, Mapping):
        return offsets
    raise TypeError(f"expected an Offsets or a {{joint: offset_rad}} mapping, got {type(offsets).__name__}")


def _apply(angles, offsets, joint, sign):
    table = _offset_table(offsets)
    if isinstance(angles, Mapping):
        if joint is not None:
            raise TypeError("give either a posture {joint: angle} or one angle with joint=..., not both")
        return {name: angle + sign * table.get(name, 0.0) for name, angle in angles.items()}
    if isinstance(angles, tuple) and len(angles) == 2 and isinstance(angles[0], str):
        joint, angles = angles
    if joint is None:
        raise TypeError("one angle needs its joint: f(angle, offsets, joint='LHipPitch') or f((joint, angle), ...)")
    return angles + sign * table.get(joint, 0.0)


def compensate_command(requested_rad, offsets, joint: str | None = None):
    """Command to send so that the joint reaches `requested_rad`: requested + c.

    requested_rad : a posture {joint: angle} (returns a new dict), one angle with `joint=` (returns a float; numpy
        arrays of angles work too), or a (joint, angle) pair. offsets : an Offsets or {joint: c}. Angles in rad.
    """
    return _apply(requested_rad, offsets, joint, +1.0)


def correct_reading(measured_rad, offsets, joint: str | None = None):
    """True joint angle from an encoder reading: measured - c. Same forms as `compensate_command`."""
    return _apply(measured_rad, offsets, joint, -1.0)


def parse_assignment(text: str):
    """'LHipPitch=-20.5' -> ('LHipPitch', -20.5); NaocalError for anything else."""
    import math

    from naocal.solver.errors import NaocalError
    from naocal.solver.joints import JOINTS

    joint, sep, value = text.partition("=")
    joint = joint.strip()
    if not sep or not joint:
        raise NaocalError(f"expected JOINT=ANGLE, got {text!r}")
    try:
        angle = float(value)
    except ValueError:
        raise NaocalError(f"{joint}: not a number: {value!r}") from None
    if not math.isfinite(angle):
        raise NaocalError(f"{joint}: non-finite angle {value!r}")
    known = set(JOINTS) | {"LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll", "LWristYaw", "LHand",
                           "RShoulderPitch", "RShoulderRoll", "RElbowYaw", "RElbowRoll", "RWristYaw", "RHand"}
    if joint not in known:
        raise NaocalError(f"unknown joint {joint!r}")
    return joint, angle
