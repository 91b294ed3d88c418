"""The mock backend: contract, hidden truth, clock and timing, safety, determinism."""

import json
import math

import numpy as np
import pytest

from naocal.backends.mock import (
    DEFAULT_POSTURE, EFFECTS, FRAME_PERIOD_S, MockBackend, check_effects, draw_truth, parse_effect_sizes,
)
from naocal.backends.errors import RobotFault
from naocal.solver.errors import SafetyError
from naocal.solver.errors import NaocalError
from naocal.solver.joints import JOINTS, LEG_JOINTS
from naocal.solver.limits import head_pitch_limits
from tests.backend_contract import check_backend_contract
from tests.mock_stances import settle_and_capture


@pytest.fixture
def mock():
    backend = MockBackend(seed=5)
    yield backend
    backend.close()


def test_backend_contract():
    check_backend_contract(MockBackend(seed=1))


def test_truth_has_the_naocal_truth_format():
    truth = MockBackend(seed=3).truth_dict()
    assert set(truth) == {"schema", "alpha_rad", "camera_rotation_rad", "board_mount", "effects"}
    assert truth["schema"] == "naocal.truth/2"
    assert set(truth["alpha_rad"]) == set(JOINTS)
    assert set(truth["camera_rotation_rad"]) == {"bottom", "top"}  # keyed by camera name, as in offsets.json
    assert all(set(r) == {"roll", "pitch", "yaw"} for r in truth["camera_rotation_rad"].values())
    assert set(truth["board_mount"]) == {"L", "R"}
    for mount in truth["board_mount"].values():
        assert set(mount) == {"rot_z_rad", "trans_x_m", "trans_y_m"}
    assert truth["effects"] == {}
    assert MockBackend(seed=3).effect_values_dict() == {"schema": "naocal.truth_effects/1", "effects": {}}
    assert json.loads(json.dumps(truth)) == truth  # plain JSON types


def test_truth_holds_each_injected_effects_drawn_values():
    mock = MockBackend(seed=3, effects={"elasticity": 0.03, "time_lag": 0.04})
    values = mock.effect_values_dict()["effects"]
    assert set(values) == {"elasticity", "time_lag"}
    compliance = values["elasticity"]["compliance_rad_per_nm"]
    assert compliance == mock.truth.compliance_rad_per_nm
    assert all(0.015 <= c <= 0.045 for c in compliance.values())  # size x U(0.5, 1.5)
    assert values["time_lag"] == {"image_stamp_late_s": 0.04}
    assert json.loads(json.dumps(values)) == values


def test_truth_sizes_are_those_of_a_real_robot():
    for seed in range(20):
        truth = draw_truth(seed)
        leg_alpha_deg = np.degrees([abs(truth.alpha_rad[j]) for j in LEG_JOINTS])
        assert np.all((leg_alpha_deg >= 0.2) & (leg_alpha_deg <= 2.0))
        assert truth.alpha_rad["RHipYawPitch"] == truth.alpha_rad["LHipYawPitch"]  # one motor
        assert truth.alpha_rad["HeadYaw"] == truth.alpha_rad["HeadPitch"] == 0.0  # only with head_offsets
        for rotation in truth.camera_rotations().values():  # both cameras
            rot = {k: math.degrees(v) for k, v in rotation.items()}
            assert -8.5 <= rot["pitch"] <= -3.0
            assert 1.0 <= abs(rot["roll"]) <= 3.0 and 1.0 <= abs(rot["yaw"]) <= 3.0
        assert truth.top_camera_rotation_rad != truth.camera_rotation_rad
        for mount in truth.board_mount.values():
            assert 0.2 <= abs(math.degrees(mount.rot_z_rad)) <= 1.2
            assert 0.0005 <= abs(mount.trans_x_m) <= 0.003 and 0.0005 <= abs(mount.trans_y_m) <= 0.003


def test_effects_do_not_change_the_base_truth():
    base = draw_truth(11)
    with_effects = draw_truth(11, {"elasticity": 0.02, "backlash": 0.01, "head_offsets": 0.01})
    for joint in LEG_JOINTS:
        assert with_effects.alpha_rad[joint] == base.alpha_rad[joint]
    assert with_effects.camera_rotations() == base.camera_rotations()
    assert with_effects.board_mount == base.board_mount
    assert with_effects.alpha_rad["HeadYaw"] != 0.0


def test_a_seeds_effects_are_what_they_were_before_the_injection_moved_into_the_effect_modules():
    """Each effect's module draws from the stream the mock gave that effect before (commit 17e9f5d's values)."""
    t = draw_truth(3, {"elasticity": 0.02, "backlash": 0.01, "link_lengths": 0.003, "head_offsets": 0.01,
                       "intrinsics": 5.0, "distortion": 0.05, "time_lag": 0.03})
    assert t.compliance_rad_per_nm["LKneePitch"] == 0.018548907479973543
    assert t.backlash_rad["RAnkleRoll"] == 0.014704571583842741
    assert (t.thigh_delta_m["R"], t.tibia_delta_m["L"]) == (-0.0017892403698596647, -0.002752684707140297)
    assert t.alpha_rad["HeadPitch"] == 0.0055865647844509075
    k1 = t.camera.distortion[0]
    assert (t.camera.fx_px, t.camera.fy_px, k1, t.time_lag_s) == (595.0, 593.848749666668, 0.05, 0.03)


def test_effect_arguments_are_checked():
    assert parse_effect_sizes(["elasticity=0.02", "time_lag=0.03"]) == {"elasticity": 0.02, "time_lag": 0.03}
    for bad in (["elasticity"], ["elasticity=abc"], ["gravity=1"], ["backlash=nan"]):
        with pytest.raises(NaocalError):
            parse_effect_sizes(bad)
    with pytest.raises(NaocalError, match="unknown effect"):
        MockBackend(seed=0, effects={"wobble": 1.0})
    assert set(check_effects({name: 0.0 for name in EFFECTS})) == set(EFFECTS)


def test_same_seed_same_robot_and_images():
    images = []
    for _ in range(2):
        mock = MockBackend(seed=9)
        mock.command({"HeadYaw": 0.2, "LKneePitch": 0.8}, 0.5)
        mock.sleep(1.0)
        images.append((mock.truth_dict(), mock.capture().pixels, mock.read_joints()))
        mock.close()
    assert images[0][0] == images[1][0]
    assert np.array_equal(images[0][1], images[1][1])
    assert images[0][2] == images[1][2]
    assert MockBackend(seed=10).truth_dict() != images[0][0]


def test_still_joint_reads_the_command_and_stands_at_command_plus_alpha(mock):
    target = {"LKneePitch": 0.9, "RAnklePitch": -0.4, "HeadPitch": 0.2}
    mock.command(target, 0.5)
    mock.sleep(2.0)
    reading = mock.read_joints().angles_rad
    true = mock.true_angles()
    step = math.radians(0.1)
    for joint, value in target.items():
        assert abs(reading[joint] - value) <= step / 2 + 1e-12  # quantised to the encoder resolution
        assert abs(reading[joint] / step - round(reading[joint] / step)) < 1e-9
        assert true[joint] == pytest.approx(value + mock.truth.alpha_rad[joint], abs=1e-12)


def test_one_motor_drives_both_hip_yaw_pitch_joints(mock):
    mock.command({"RHipYawPitch": -0.2}, 0.5)
    mock.sleep(2.0)
    reading = mock.read_joints().angles_rad
    true = mock.true_angles()
    assert reading["LHipYawPitch"] == reading["RHipYawPitch"] == pytest.approx(-0.2, abs=1e-3)
    assert true["LHipYawPitch"] == true["RHipYawPitch"]
    mock.command({"LHipYawPitch": -0.1, "RHipYawPitch": -0.3}, 0.5)  # as in NAOqi, the left command wins
    mock.sleep(2.0)
    assert mock.read_joints().angles_rad["RHipYawPitch"] == pytest.approx(-0.1, abs=1e-3)


def test_motion_takes_time_at_the_commanded_fraction_of_the_speed_limit(mock):
    start = mock.servo_angles()
    t0 = mock.now()
    mock.command({"HeadYaw": 0.6, "LKneePitch": start["LKneePitch"] - 0.1}, 0.25)
    duration = 0.6 / (0.25 * mock.max_speeds()["HeadYaw"])  # the joint with the longest way sets the pace
    t_start = t0 + mock.command_delay_s
    halfway = mock.servo_angles(t_start + duration / 2)
    assert halfway["HeadYaw"] == pytest.approx(0.3, abs=1e-9)
    assert halfway["LKneePitch"] == pytest.approx(start["LKneePitch"] - 0.05, abs=1e-9)  # a straight line
    assert mock.servo_angles(t_start + duration - 1e-3)["HeadYaw"] < 0.6
    assert mock.servo_angles(t_start + duration)["HeadYaw"] == pytest.approx(0.6, abs=1e-12)


def test_joint_readings_lag_by_three_sensor_cycles(mock):
    mock.command({"HeadYaw": 0.5}, 0.2)
    mock.sleep(0.1234)
    reading = mock.read_joints()
    assert mock.now() - 0.04 < reading.t_s <= mock.now() - 0.03
    assert abs(reading.t_s / 0.01 - round(reading.t_s / 0.01)) < 1e-6  # sampled at 100 Hz
    servo_then = mock.servo_angles(reading.t_s)["HeadYaw"]
    assert reading.angles_rad["HeadYaw"] == pytest.approx(servo_then, abs=math.radians(0.05) + 1e-12)
    assert mock.servo_angles()["HeadYaw"] > servo_then + 0.01  # the robot has moved on since


def test_images_arrive_late_and_are_only_rendered_when_looked_at(mock):
    mock.sleep(0.5)
    image = mock.capture()
    age = mock.now() - image.t_exposure_s
    assert mock.camera_delay_s <= age < mock.camera_delay_s + FRAME_PERIOD_S + 1e-9
    assert mock.capture() is image  # no new frame yet: the same one
    for _ in range(300):  # an agent polling for a new enough frame reads only the timestamps
        mock.sleep(0.01)
        assert mock.capture().t_exposure_s <= mock.now() - mock.camera_delay_s + 1e-9
    assert mock.frames_rendered == 0
    newest = mock.capture()
    assert newest.pixels.shape == (480, 640, 3) and mock.frames_rendered == 1
    assert newest.pixels is newest.pixels and mock.frames_rendered == 1  # rendered once
    mock.true_vertex_pixels(image)  # the truth of an unread image renders it
    assert mock.frames_rendered == 2


def test_sleep_refuses_negative_or_non_finite_durations(mock):
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(NaocalError):
            mock.sleep(bad)


@pytest.mark.parametrize("targets, match", [
    ({"LKneePitch": 3.0}, "outside its limits"),
    ({"RKneePitch": 2.13}, "outside its limits"),
    ({"LHipRoll": float("inf")}, "not a finite angle"),
    ({"LeftToe": 0.1}, "unknown joint"),
    ({"HeadYaw": 1.5, "HeadPitch": 0.4}, "HeadPitch"),  # inside the box, outside the yaw-dependent table
    ({"LHipPitch": 0.4, "LKneePitch": 0.0}, "ground"),  # the leg pushed into the floor
    ({"LHipRoll": -0.3, "RHipRoll": 0.3}, "Sandal"),  # the sandals run into each other
])
def test_unsafe_commands_are_refused_and_logged(mock, targets, match):
    before = mock.servo_angles()
    with pytest.raises(SafetyError, match=match):
        mock.command(targets, 0.5)
    mock.sleep(2.0)
    assert mock.servo_angles() == before  # nothing moved
    record = mock.command_log[-1]
    assert record.targets_rad == targets and not record.accepted and match in record.reason


def test_a_motion_through_a_collision_is_refused_even_if_its_end_is_safe(mock):
    apart = {"LHipRoll": 0.05, "RHipRoll": -0.05, "LHipPitch": -0.2, "RHipPitch": -1.3, "LKneePitch": 0.0,
             "RKneePitch": 0.0, "LAnklePitch": 0.0, "RAnklePitch": 0.0}
    mock.command(apart, 1.0)
    mock.sleep(3.0)
    swapped = {"LHipPitch": -1.3, "RHipPitch": -0.2}  # the legs would pass through each other
    end = mock._true_static(np.array([{**mock.servo_angles(), **swapped}[j] for j in JOINTS]))
    assert mock.checker.is_safe(end)
    with pytest.raises(SafetyError, match="would come within"):
        mock.command(swapped, 1.0)


def test_speed_fraction_is_checked(mock):
    for bad in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(SafetyError, match="speed_fraction"):
            mock.command({"HeadYaw": 0.1}, bad)


def test_command_log_holds_every_command(mock):
    mock.command({"HeadYaw": 0.1}, 0.3)
    with pytest.raises(SafetyError):
        mock.command({"HeadYaw": 9.0}, 0.3)
    assert [(r.targets_rad, r.speed_fraction, r.accepted) for r in mock.command_log] == [
        ({"HeadYaw": 0.1}, 0.3, True), ({"HeadYaw": 9.0}, 0.3, False)]


def test_default_posture_is_within_limits_and_safe(mock):
    for joint, value in DEFAULT_POSTURE.items():
        lower, upper = mock.joint_limits()[joint]
        assert lower < value < upper
    lower, upper = head_pitch_limits(DEFAULT_POSTURE["HeadYaw"])
    assert lower < DEFAULT_POSTURE["HeadPitch"] < upper
    assert mock.checker.is_safe(mock._true_static(np.array([DEFAULT_POSTURE[j] for j in JOINTS])))


def test_unstiff_joints_ignore_commands(mock):
    mock.set_stiffness(["LKneePitch"], 0.0)
    before = mock.servo_angles()["LKneePitch"]
    mock.command({"LKneePitch": before + 0.3}, 0.5)
    mock.sleep(1.0)
    assert mock.servo_angles()["LKneePitch"] == before
    with pytest.raises(NaocalError):
        mock.set_stiffness(["LKneePitch"], 1.5)


def test_capturing_before_the_robot_is_still_shows_it_elsewhere(mock):
    still = settle_and_capture(mock, {"LHipPitch": -0.9, "LKneePitch": 1.0})
    at_rest = mock.true_vertex_pixels(still)["L"][0]
    mock.command({"LHipPitch": -0.5, "LKneePitch": 0.5}, 0.3)
    mock.sleep(0.3)  # the move takes about 0.4 s; the newest image left the camera 0.1 s ago
    during = mock.capture()
    shown = mock.true_vertex_pixels(during)["L"][0]
    t_end = mock.now() + 1.0
    mock.sleep(1.0)
    final = mock.vertex_pixels_at(t_end)["L"]
    assert mock.exposure_time(during) < mock.now() - mock.camera_delay_s + 1e-9
    assert np.min(np.linalg.norm(shown - at_rest, axis=1)) > 5.0  # neither where it was...
    assert np.min(np.linalg.norm(shown - final, axis=1)) > 5.0  # ...nor where it was sent


def test_closed_mock_refuses_work():
    mock = MockBackend(seed=0)
    mock.close()
    mock.close()
    with pytest.raises(NaocalError, match="closed"):
        mock.capture()


def test_the_top_camera_sees_a_planned_top_stance_where_its_truth_says():
    from naocal.agent.measure import opencv_detector
    from naocal.agent.planner import Planner

    planner = Planner()
    try:
        cand = planner.top_candidates("L", np.random.default_rng(3), 1)[0]
    finally:
        planner.close()
    q14 = cand.stances(planner.parked)[0]
    with MockBackend(seed=1, posture=dict(zip(JOINTS, q14))) as mock:
        mock.sleep(0.5)
        top, bottom = mock.capture("top"), mock.capture("bottom")
        assert (top.camera, bottom.camera) == ("top", "bottom")
        uv, visible = mock.true_vertex_pixels(top)["L"]
        assert visible.all()  # the planner's 50 px margin holds the board in view whatever the camera's rotation
        detection = opencv_detector(top, uv, "L", 40.0)
        assert detection.ok, detection.reason
        assert np.max(np.abs(np.asarray(detection.vertices_px) - uv)) < 0.5  # the truth's pixels are the top camera's
        bottom_uv = mock.true_vertex_pixels(bottom)["L"][0]
        assert np.min(np.linalg.norm(bottom_uv - uv, axis=1)) > 20.0  # a different camera, a different view
        with pytest.raises(NaocalError):
            mock.capture("middle")


@pytest.mark.parametrize("value", [math.nan, math.inf, 2.5, 1e30])
def test_the_mock_never_serves_a_reading_a_robot_could_not_give(value):
    """The same check as every driver (backends.base.checked_reading); `status` names the fault."""
    mock = MockBackend(0)
    servo_q = mock._servo_q
    knee = JOINTS.index("LKneePitch")
    mock._servo_q = lambda t: np.where(np.arange(len(JOINTS)) == knee, value, servo_q(t))  # a broken simulation
    with pytest.raises(RobotFault, match="LKneePitch reads"):
        mock.read_joints()
    assert "LKneePitch" in mock.status()["robot"]["fault"]
