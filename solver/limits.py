"""NAO joint limits: the URDF's box limits, the documented RKneePitch range, and the HeadPitch-vs-HeadYaw table.

Every backend that can move a real joint checks its targets against these before sending anything. The URDF is
`solver/data/nao_v50.urdf` (the nominal model, see ../shared/reference/NAO.md); it is parsed once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from solver.errors import DataError
from solver.urdf import NOMINAL_URDF, nominal_urdf, parse_urdf

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


def max_speeds(urdf_path=URDF_PATH) -> dict[str, float]:
    """Maximum joint speed in rad/s for every revolute joint (the URDF's `velocity`)."""
    return {name: speed for name, (_, _, speed) in _urdf_joint_table(str(urdf_path)).items()}
