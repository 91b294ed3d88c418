import math

import numpy as np
import pytest

from naocal.solver import limits
from naocal.solver.errors import DataError
from naocal.solver.joints import JOINTS


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


# ---------------------------------------------------------------------------------------------- shared checks
from naocal.solver.errors import SafetyError  # noqa: E402


@pytest.mark.parametrize("targets, problem", [
    ({"LKneePitch": 2.5}, "LKneePitch target 2.5000 rad outside its limits"),
    ({"RKneePitch": -0.11}, "RKneePitch target -0.1100 rad outside"),  # the documented right knee, not the URDF's
    ({"LKneePitch": math.nan}, "not a finite angle"),
    ({"LKneePitch": "1"}, None),  # a numeric string is a number
    ({"LKneePitch": None}, "not a finite angle"),
    ({"LShoulderPitch": 0.0}, "unknown joint 'LShoulderPitch'"),
    ({"HeadYaw": 1.5, "HeadPitch": 0.4}, "HeadPitch 0.4000 rad outside"),  # in the box, outside the table
])
def test_check_targets_refuses_each_kind_of_unsafe_target(targets, problem):
    box = {j: limits.joint_limits()[j] for j in JOINTS}
    if problem is None:
        assert limits.check_targets(targets, box) == {"LKneePitch": 1.0}
        return
    with pytest.raises(SafetyError, match=problem):
        limits.check_targets(targets, box)


def test_a_single_head_joint_is_checked_against_every_angle_the_other_may_have():
    box = {j: limits.joint_limits()[j] for j in JOINTS}
    # HeadPitch reads 0 but is on its way to 0.45: yaw 1.5 is fine for the first, not for the second.
    with pytest.raises(SafetyError, match="HeadPitch 0.4500 rad outside .* HeadYaw 1.5000"):
        limits.check_targets({"HeadYaw": 1.5}, box, head_angles={"HeadPitch": [0.0, 0.45]})
    assert limits.check_targets({"HeadYaw": 1.5}, box, head_angles={"HeadPitch": [0.0, 0.1]}) == {"HeadYaw": 1.5}
    with pytest.raises(ValueError, match="head_angles"):
        limits.check_targets({"HeadYaw": 1.5}, box)  # the other head joint unknown: a programming error


def test_speed_fraction_and_margins():
    assert limits.check_speed_fraction(1) == 1.0
    for bad in (0.0, -0.1, 1.01, math.nan, "fast"):
        with pytest.raises(SafetyError, match="speed_fraction"):
            limits.check_speed_fraction(bad)
    box = {"HeadYaw": (-2.0, 2.0)}
    assert limits.limit_problem("HeadYaw", 1.95, box) is None
    assert "outside its limits [-1.9000, 1.9000]" in limits.limit_problem("HeadYaw", 1.95, box, margin_rad=0.1)
    assert limits.head_pitch_problem(0.0, 0.515) is None
    assert limits.head_pitch_problem(0.0, 0.515, margin_rad=0.01) is not None
    assert limits.head_pitch_problem(0.0, 0.515 + 5e-10, margin_rad=-1e-9) is None  # a tolerance


def test_a_reading_is_a_finite_number_within_the_limits_plus_the_reading_margin():
    box = {"LKneePitch": (-0.0923279, 2.11255)}
    assert limits.reading_problem("LKneePitch", np.float32(1.0), box) is None  # LoLA's floats, numpy's too
    assert limits.reading_problem("LKneePitch", 2.11255 + limits.READING_MARGIN_RAD - 1e-6, box) is None  # its stop
    for value, why in [(2.5, "impossible"), (1e30, "impossible"), (-0.4, "impossible"), (math.nan, "not a finite"),
                       (math.inf, "not a finite"), ("0.5", "not a number"), (True, "not a number"),
                       (np.bool_(False), "not a number"), (None, "not a number")]:
        assert why in limits.reading_problem("LKneePitch", value, box), value
    assert limits.readings_problem({"LKneePitch": 0.5, "HeadYaw": "x"}, box).startswith("HeadYaw reads 'x'")
