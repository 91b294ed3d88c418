"""Each injectable effect of the mock changes the data the way its physics says."""

import numpy as np
import pytest

from naocal.agent.corners import detect_board_vertices
from naocal.backends.mock import MockBackend
from naocal.body.nao_body import T_WORLD_TORSO
from naocal.solver.joints import JOINTS, LEGS, leg_joints
from naocal.solver.kinematics import gravity_torques, leg_fk
from tests.mock_stances import settle_and_capture, visible_stances

SEED = 21


def _leg_angles(angles: dict, leg: str) -> np.ndarray:
    return np.array([[angles[j] for j in leg_joints(leg)]])


def test_elasticity_deflects_each_leg_joint_by_compliance_times_gravity_torque():
    mock = MockBackend(seed=SEED, effects={"elasticity": 0.05})
    settle_and_capture(mock, {"LHipPitch": -0.8, "LKneePitch": 0.4, "RHipPitch": -1.0, "RKneePitch": 1.2})
    true, servo = mock.true_angles(), mock.servo_angles()
    reading = mock.read_joints().angles_rad
    for leg in LEGS:
        joints = leg_joints(leg)
        deflection = np.array([true[j] - servo[j] - mock.truth.alpha_rad[j] for j in joints])
        board_centre_sole = mock._T_sole_board[leg][:3, 3]  # the sandal's mass sits at the true board centre
        tau = gravity_torques(_leg_angles(true, leg), leg, sandal_com_sole_m=board_centre_sole)[0]
        compliance = np.array([mock.truth.compliance_rad_per_nm[j] for j in joints])
        np.testing.assert_allclose(deflection, compliance * tau, atol=1e-10)
        assert np.max(np.abs(deflection)) > np.radians(0.3)  # a visible effect: several pixels
        for joint in joints:
            assert reading[joint] == pytest.approx(servo[joint], abs=np.radians(0.05) + 1e-12)  # sensors can't see it
    # The torques are those of the simulated masses: PyBullet's inverse dynamics agrees with the model's.
    q = np.array([true[j] for j in JOINTS])
    for leg in LEGS:
        idx = [JOINTS.index(j) for j in leg_joints(leg)]
        tau_model = gravity_torques(_leg_angles(true, leg), leg, sandal_com_sole_m=mock._T_sole_board[leg][:3, 3])[0]
        np.testing.assert_allclose(mock.body.gravity_torques(q)[idx], tau_model, atol=1e-12)


def test_backlash_depends_on_the_approach_direction():
    mock = MockBackend(seed=SEED, effects={"backlash": 0.01})
    b = mock.truth.backlash_rad["LKneePitch"]
    assert 0.005 <= b <= 0.015
    settle_and_capture(mock, {"LKneePitch": 0.7})  # from 0.5: approached from below
    from_below, reading_below = mock.true_angles()["LKneePitch"], mock.read_joints().angles_rad["LKneePitch"]
    settle_and_capture(mock, {"LKneePitch": 0.9})
    settle_and_capture(mock, {"LKneePitch": 0.7})  # approached from above
    from_above, reading_above = mock.true_angles()["LKneePitch"], mock.read_joints().angles_rad["LKneePitch"]
    assert reading_below == reading_above
    assert from_below - from_above == pytest.approx(2 * b, abs=1e-12)
    assert from_below == pytest.approx(0.7 + mock.truth.alpha_rad["LKneePitch"] + b, abs=1e-12)
    # A repeated command (no change) keeps the direction.
    settle_and_capture(mock, {"LKneePitch": 0.7, "HeadYaw": 0.05})
    assert mock.true_angles()["LKneePitch"] == pytest.approx(from_above, abs=1e-12)


def test_link_lengths_change_the_simulated_and_rendered_body():
    mock = MockBackend(seed=SEED, effects={"link_lengths": 0.004})
    truth = mock.truth
    for leg in LEGS:
        assert 0.002 <= abs(truth.thigh_delta_m[leg]) <= 0.004 and 0.002 <= abs(truth.tibia_delta_m[leg]) <= 0.004
    command, leg = visible_stances(mock, 1, seed=3)[0]
    image = settle_and_capture(mock, command)
    q = mock._true_q(mock.exposure_time(image))
    # The PyBullet body is built with the longer/shorter links...
    mock.body.set_angles(q)
    q_leg = q[[JOINTS.index(j) for j in leg_joints(leg)]][None]
    T_sole = leg_fk(q_leg, leg, thigh_delta_m=truth.thigh_delta_m[leg], tibia_delta_m=truth.tibia_delta_m[leg])[0]
    expected = T_WORLD_TORSO @ T_sole @ mock._T_sole_board[leg]
    np.testing.assert_allclose(mock.body.link_pose_world(f"{leg}Sandal"), expected, atol=1e-6)
    nominal = T_WORLD_TORSO @ leg_fk(q_leg, leg)[0] @ mock._T_sole_board[leg]
    assert np.linalg.norm(expected[:3, 3] - nominal[:3, 3]) > 0.002
    # ...and the image shows the board where the true kinematics put it.
    pixels, visible = mock.true_vertex_pixels(image)[leg]
    assert visible.all()
    found = detect_board_vertices(image.pixels, pixels + 4.0)
    assert found.ok, found.detail
    assert np.sqrt(np.mean((found.vertices_px - pixels) ** 2)) < 0.1


def test_head_offsets_turn_the_camera_but_not_the_readings():
    plain = MockBackend(seed=SEED)
    offset = MockBackend(seed=SEED, effects={"head_offsets": 0.01})
    command = {"HeadYaw": 0.1, "HeadPitch": 0.35}
    pixels = []
    for mock in (plain, offset):
        settle_and_capture(mock, command)
        true, reading = mock.true_angles(), mock.read_joints().angles_rad
        for joint in command:
            assert reading[joint] == pytest.approx(command[joint], abs=np.radians(0.05) + 1e-12)
            assert true[joint] == pytest.approx(command[joint] + mock.truth.alpha_rad[joint], abs=1e-12)
        pixels.append(mock.vertex_pixels_at(mock.now())["L"])
    yaw, pitch = offset.truth.alpha_rad["HeadYaw"], offset.truth.alpha_rad["HeadPitch"]
    assert 0.005 <= abs(yaw) <= 0.01 and 0.005 <= abs(pitch) <= 0.01
    assert all(plain.truth.alpha_rad[j] == 0.0 for j in command)
    shift = np.linalg.norm(pixels[1] - pixels[0], axis=1)
    assert np.all(shift > 0.5 * 600 * 0.005)  # about f * offset


def test_intrinsics_scale_the_image_about_the_principal_point():
    plain = MockBackend(seed=SEED)
    focal = MockBackend(seed=SEED, effects={"intrinsics": 12.0})
    cam, nominal = focal.truth.camera, focal.intrinsics()
    assert abs(cam.fx_px - nominal.fx_px) == pytest.approx(12.0)
    assert 0.7 * 12 <= abs(cam.fy_px - nominal.fy_px) <= 1.3 * 12
    assert focal.intrinsics() == plain.intrinsics()  # the prior the agent gets is the nominal one
    uv0 = plain.vertex_pixels_at(plain.now())["L"]
    uv1 = focal.vertex_pixels_at(focal.now())["L"]
    centre = np.array([cam.cx_px, cam.cy_px])
    np.testing.assert_allclose((uv1 - centre) / (uv0 - centre),
                               np.broadcast_to([cam.fx_px / nominal.fx_px, cam.fy_px / nominal.fy_px], uv0.shape),
                               rtol=1e-9)


def test_distortion_moves_vertices_radially_and_is_rendered():
    k1 = -0.08
    plain = MockBackend(seed=SEED)
    distorted = MockBackend(seed=SEED, effects={"distortion": k1})
    command, leg = visible_stances(distorted, 1, seed=5, margin_px=10.0)[0]
    images = [settle_and_capture(mock, command) for mock in (plain, distorted)]
    uv0, _ = plain.true_vertex_pixels(images[0])[leg]
    uv1, visible = distorted.true_vertex_pixels(images[1])[leg]
    cam = distorted.truth.camera
    centre = np.array([cam.cx_px, cam.cy_px])
    normalised = (uv0 - centre) / [cam.fx_px, cam.fy_px]
    r2 = np.sum(normalised ** 2, axis=1, keepdims=True)
    np.testing.assert_allclose(uv1 - centre, (uv0 - centre) * (1 + k1 * r2), atol=1e-9)
    radial = np.sum((uv1 - uv0) * (uv0 - centre), axis=1) / np.linalg.norm(uv0 - centre, axis=1)
    assert np.all(radial < 0)  # barrel distortion pulls towards the centre, more at the border
    assert np.corrcoef(np.abs(radial), np.linalg.norm(uv0 - centre, axis=1) ** 3)[0, 1] > 0.99
    assert visible.all()
    found = detect_board_vertices(images[1].pixels, uv1 + 3.0)
    assert found.ok, found.detail
    assert np.sqrt(np.mean((found.vertices_px - uv1) ** 2)) < 0.1


def test_time_lag_stamps_images_later_than_their_exposure():
    lag = 0.04
    mock = MockBackend(seed=SEED, effects={"time_lag": lag})
    mock.command({"LHipPitch": -1.0, "LKneePitch": 0.8}, 0.3)
    mock.sleep(0.35)  # capture while the leg moves
    image = mock.capture()
    exposed = mock.exposure_time(image)
    assert image.t_exposure_s - exposed == pytest.approx(lag)
    shown, _ = mock.true_vertex_pixels(image)["L"]
    np.testing.assert_allclose(shown, mock.vertex_pixels_at(exposed)["L"], atol=1e-9)
    assert np.min(np.linalg.norm(mock.vertex_pixels_at(image.t_exposure_s)["L"] - shown, axis=1)) > 3.0
    # At rest the stamp does not matter.
    mock.sleep(2.0)
    still = mock.capture()
    np.testing.assert_allclose(mock.vertex_pixels_at(still.t_exposure_s)["L"],
                               mock.true_vertex_pixels(still)["L"][0], atol=1e-9)


def test_motion_blurs_the_boards():
    mock = MockBackend(seed=SEED, exposure_s=0.03)
    command, leg = visible_stances(mock, 1, seed=7)[0]
    sharp = settle_and_capture(mock, command)
    pixels, _ = mock.true_vertex_pixels(sharp)[leg]
    assert detect_board_vertices(sharp.pixels, pixels).ok
    moved = dict(command)
    for joint in leg_joints(leg)[2:5]:
        moved[joint] = command[joint] + 0.15
    t_start = mock.now() + mock.command_delay_s
    mock.command(moved, 0.2)  # takes about 0.12 s
    mock.sleep(mock.command_delay_s + 0.06 + mock.camera_delay_s)
    blurred = mock.capture()
    t_exposed = mock.exposure_time(blurred)
    assert t_start + 0.02 < t_exposed < t_start + 0.1  # exposed while the leg moves
    found = detect_board_vertices(blurred.pixels, mock.true_vertex_pixels(blurred)[leg][0])
    assert not found.ok and found.reason == "blurred", (found.reason, found.detail)
