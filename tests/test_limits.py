import math

import numpy as np
import pytest

from solver import limits
from solver.errors import DataError
from solver.joints import JOINTS


def test_head_pitch_limits_hit_the_documented_table_rows_on_both_sides():
    for yaw, lower, upper in limits.HEAD_PITCH_VS_YAW_TABLE:
        for sign in (1.0, -1.0):
            assert limits.head_pitch_limits(sign * yaw) == pytest.approx((lower, upper), abs=1e-12)


def test_head_pitch_limits_interpolate_linearly_between_rows():
    # Halfway between yaw 0.486 -> [-0.672, 0.422] and 0.756 -> [-0.548, 0.370].
    lower, upper = limits.head_pitch_limits(-(0.486 + 0.756) / 2)
    assert lower == pytest.approx((-0.672 - 0.548) / 2)
    assert upper == pytest.approx((0.422 + 0.370) / 2)


def test_head_pitch_limits_hold_the_last_row_beyond_the_table_and_refuse_nan():
    assert limits.head_pitch_limits(3.0) == pytest.approx((-0.449, 0.330))
    with pytest.raises(ValueError):
        limits.head_pitch_limits(math.nan)


def test_joint_limits_come_from_the_urdf_with_the_documented_right_knee():
    box = limits.joint_limits()
    assert set(JOINTS) <= set(box)
    assert box["HeadYaw"] == pytest.approx((-2.08567, 2.08567))
    assert box["LKneePitch"] == pytest.approx((-0.0923279, 2.11255))
    assert box["RKneePitch"] == pytest.approx((-0.103083, 2.120198))
    assert box["RHipRoll"] == pytest.approx((-0.79046, 0.379435))
    assert all(lower < upper for lower, upper in box.values())
    speeds = limits.max_speeds()
    assert speeds["LKneePitch"] == pytest.approx(6.40239)
    assert all(np.isfinite(speeds[j]) and speeds[j] > 0 for j in JOINTS)


def test_joint_limits_returns_a_copy():
    limits.joint_limits()["HeadYaw"] = (0.0, 0.0)
    assert limits.joint_limits()["HeadYaw"] == pytest.approx((-2.08567, 2.08567))


def test_a_broken_urdf_is_reported_with_its_path(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot><joint name="J" type="revolute"><limit lower="x" upper="1" velocity="1"/></joint></robot>')
    with pytest.raises(DataError, match="bad.urdf.*J"):
        limits.joint_limits(bad)
