"""The Duckiebot described and Duckietown's kinematics (kinds/duckiebot/robot.py, kinematics.py; issue 23)."""

import numpy as np
import pytest

from naocal.kinds.duckiebot.kinematics import (body_velocity, duty_to_pwm, forward_kinematics, integrate_pose,
                                        inverse_kinematics, wheel_speeds)
from naocal.kinds.duckiebot.robot import Kinematics, camera_mount, duckiebot
from naocal.solver.camera import project_points
from naocal.solver.errors import DataError, NaocalError
from naocal.solver.transforms import invert_transform, transform_points


def test_db21_and_db18_descriptions():
    db21, db18 = duckiebot("DB21"), duckiebot("DB18")
    assert (db21.radius_m, db21.baseline_m, db21.ticks_per_revolution) == (0.0318, 0.1, 135)
    assert db18.ticks_per_revolution is None
    cam = db21.camera
    assert (cam.width_px, cam.height_px) == (640, 480)
    # the real robots' ranges (5-95 %): the prior lies inside them
    assert 319 <= cam.fx_px <= 360 and 300 <= cam.cx_px <= 336 and 212 <= cam.cy_px <= 257
    assert -0.322 <= cam.distortion[0] <= -0.250 and 0.043 <= cam.distortion[1] <= 0.094
    kin = db21.nominal_kinematics()
    assert (kin.gain, kin.trim, kin.k, kin.limit, kin.v_max_mps, kin.omega_max_radps) == (1.0, 0.0, 27.0, 1.0, 1.0, 8.0)
    with pytest.raises(NaocalError, match="DB99"):
        duckiebot("DB99")


def test_camera_mount_looks_down_at_the_floor_ahead():
    robot = duckiebot()
    T = robot.T_base_camera
    np.testing.assert_allclose(T[:3, 3], (0.066, 0.0, 0.108))
    # the optical axis (camera x) points forward and 19 deg down
    axis = T[:3, 0]
    assert axis[0] > 0 and np.degrees(np.arcsin(-axis[2])) == pytest.approx(19.0)
    # a floor point on the optical axis projects to the principal point; a point to the left lands left of it
    distance = 0.108 / np.tan(np.radians(19.0))
    p_cam = transform_points(invert_transform(T), np.array([[0.066 + distance, 0.0, 0.0], [0.3, 0.05, 0.0]]))
    uv, depth = project_points(p_cam, robot.camera.intrinsics())
    np.testing.assert_allclose(uv[0], (316.0, 233.0), atol=1e-9)
    assert uv[1, 0] < 316.0 and np.all(depth > 0)
    np.testing.assert_allclose(camera_mount(yaw_rad=0.1)[:3, 3], (0.066, 0.0, 0.108))


def test_inverse_kinematics_is_duckietowns_formula():
    kin = Kinematics(gain=1.1, trim=-0.05, k=27.0, baseline_m=0.1, radius_m=0.0318)
    v, omega = 0.3, 1.2
    u_left, u_right = inverse_kinematics(v, omega, kin)
    w_r, w_l = (v + omega * 0.05) / 0.0318, (v - omega * 0.05) / 0.0318
    assert u_right == pytest.approx((1.1 - 0.05) * w_r / 27.0)
    assert u_left == pytest.approx((1.1 + 0.05) * w_l / 27.0)


def test_inverse_kinematics_respects_every_limit():
    kin = Kinematics(limit=0.5, v_max_mps=0.4, omega_max_radps=2.0)
    # v and omega clamped before the wheels: v = 5 acts as v_max
    np.testing.assert_allclose(inverse_kinematics(5.0, 0.0, kin), inverse_kinematics(0.4, 0.0, kin))
    np.testing.assert_allclose(inverse_kinematics(0.0, -50.0, Kinematics()), inverse_kinematics(0.0, -8.0,
                                                                                               Kinematics()))
    rng = np.random.default_rng(0)
    u_left, u_right = inverse_kinematics(rng.uniform(-3, 3, 1000), rng.uniform(-20, 20, 1000), kin)
    assert np.abs(u_left).max() <= 0.5 and np.abs(u_right).max() <= 0.5
    assert np.abs(u_left).max() == 0.5  # the limit is reached, not only respected


def test_forward_inverts_inverse_within_limits():
    kin = Kinematics(gain=0.9, trim=0.07)
    v, omega = np.array([0.2, -0.1, 0.0, 0.25]), np.array([0.0, 1.0, -3.0, 0.5])
    np.testing.assert_allclose(forward_kinematics(*inverse_kinematics(v, omega, kin), kin), (v, omega), atol=1e-12)


def test_forward_kinematics_of_a_robot_with_trim_curves():
    """The same duty on both wheels: a positive trim slows the right wheel's speed per duty (w_r = u k /
    (gain + trim)), so the robot turns right (clockwise, omega < 0), as Duckietown's sign convention says."""
    kin = Kinematics(trim=0.05)
    w_left, w_right = wheel_speeds(0.5, 0.5, kin)
    assert w_left == pytest.approx(0.5 * 27 / 0.95) and w_right == pytest.approx(0.5 * 27 / 1.05)
    v, omega = forward_kinematics(0.5, 0.5, kin)
    assert omega < 0 and v == pytest.approx(0.0318 * (w_left + w_right) / 2)
    assert body_velocity(1.0, 1.0, 0.0318, 0.1) == pytest.approx((0.0318, 0.0))


def test_drift_over_two_metres_matches_the_reference_rule():
    """docs/DUCKIEBOT.md: a speed mismatch eps = 2 trim / gain drifts y = eps L^2 / (2 b), 40 trim over 2 m."""
    trim = 0.002
    true = Kinematics(trim=trim)
    u = inverse_kinematics(0.3, 0.0, Kinematics())  # an uncalibrated robot asked to go straight
    v, omega = forward_kinematics(*u, true)
    pose = np.zeros(3)
    dt = 0.001
    while pose[0] < 2.0:
        pose = integrate_pose(pose, v, omega, dt)
    assert -pose[1] == pytest.approx(40 * trim, rel=0.02)


def test_integrate_pose_is_the_exact_arc():
    pose = integrate_pose(np.array([[0.0, 0.0, 0.0], [1.0, 2.0, np.pi / 2]]), 1.0, np.pi / 2, 1.0)
    r = 2 / np.pi
    np.testing.assert_allclose(pose[0], (r, r, np.pi / 2), atol=1e-12)
    np.testing.assert_allclose(pose[1], (1.0 - r, 2.0 + r, np.pi), atol=1e-12)
    # many small steps give the same pose as one
    many = np.zeros(3)
    for _ in range(100):
        many = integrate_pose(many, 1.0, np.pi / 2, 0.01)
    np.testing.assert_allclose(many, pose[0], atol=1e-12)
    np.testing.assert_allclose(integrate_pose([0, 0, 0.3], 2.0, 0.0, 0.5), (np.cos(0.3), np.sin(0.3), 0.3))


def test_duty_to_pwm_has_the_drivers_dead_zone_and_jump():
    np.testing.assert_array_equal(duty_to_pwm([0.0, 0.01, -0.01, 0.0101, 0.5, -1.0, 1.0, 3.0]),
                                  [0, 0, 0, 61, 157, 255, 255, 255])


@pytest.mark.parametrize("bad, message", [
    (dict(radius_m=0.0), "kinematics, field 'radius_m': must be positive, got 0.0"),
    (dict(k=-1.0), "kinematics, field 'k': must be positive, got -1.0"),
    (dict(limit=1.5), "kinematics, field 'limit': must be within (0, 1], got 1.5"),
    (dict(gain=0.1, trim=0.1), "kinematics, field 'trim': gain +- trim must not be 0"),
    (dict(trim=float("nan")), "kinematics, field 'trim': expected a finite number, got nan"),
    (dict(baseline_m=True), "kinematics, field 'baseline_m': expected a finite number, got True")])
def test_kinematics_refuses_impossible_parameters_naming_the_field(bad, message):
    """One home for the field checks (solver.fields): its messages, naming the field."""
    with pytest.raises(DataError) as refused:
        Kinematics(**bad)
    assert str(refused.value).startswith(message), str(refused.value)


@pytest.mark.parametrize("key, value, message", [("limit", "1.5", "field 'limit': must be within (0, 1], got 1.5"),
                                                 ("baseline", "-0.1", "field 'baseline': must be positive, got -0.1")])
def test_a_kinematics_file_value_kinematics_refuses_is_named_by_the_files_key(tmp_path, key, value, message):
    from naocal.kinds.duckiebot.calibration_files import kinematics_yaml, read_kinematics

    text = kinematics_yaml(duckiebot("DB21").nominal_kinematics(), "2026-01-01-00-00-00")
    path = tmp_path / "db21.yaml"
    path.write_text("".join(f"{key}: {value}\n" if line.startswith(f"{key}:") else line + "\n"
                            for line in text.splitlines()))
    with pytest.raises(DataError) as refused:
        read_kinematics(path)
    assert str(refused.value) == f"{path}, {message}"
