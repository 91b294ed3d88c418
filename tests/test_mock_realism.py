"""The realistic mock (MockBackend(realism="realistic")): each feature does what docs/MOCK.md says."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from naocal.agent.corners import detect_board_vertices
from naocal.backends.mock import MockBackend, draw_truth
from naocal.backends.mock_faults import FaultyDetector, draw_faults
from naocal.backends.mock_realism import IDEAL, REALISTIC, as_realism
from naocal.backends.mock_render import bgr_to_yuyv, grey_to_yuyv, yuyv_to_bgr
from naocal.backends.mock_servo import SecondOrder, rest_offset
from naocal.solver.errors import NaocalError
from naocal.solver.joints import JOINT_INDEX, JOINTS, LEG_JOINTS, leg_joints
from tests.backend_contract import check_backend_contract
from tests.mock_stances import settle_and_capture, visible_stances

STEP = 2 * math.pi / 4096
SEED = 3


@pytest.fixture(scope="module")
def realistic():
    mock = MockBackend(seed=SEED, realism="realistic")
    yield mock
    mock.close()


def _still(mock, command, speed=0.5, wait_s=1.0):
    mock.command(command, speed)
    mock.sleep(wait_s)


def test_backend_contract():
    check_backend_contract(MockBackend(seed=1, realism="realistic"))


def test_realism_settings_are_checked():
    assert as_realism("ideal") is IDEAL and as_realism("realistic") is REALISTIC
    assert as_realism({"preset": "realistic", "servo_rest": "centre"}).servo_rest == "centre"
    for bad, match in ((("nonsense",), "expected one of"), (({"servo_rest": "middle"},), "servo_rest"),
                       (({"preset": "realistic", "sensor_period": 0.01},), "unknown field"),
                       (({"corner_fault_rate": 1.5},), "corner_fault_rate"),
                       (({"servo_damping": 1.0},), "servo_damping")):
        with pytest.raises(NaocalError, match=match):
            as_realism(*bad)
    with pytest.raises(NaocalError):
        MockBackend(seed=0, realism="very")


def test_readings_are_encoder_steps_sampled_every_12_ms_and_3_cycles_late(realistic):
    mock = realistic
    start = mock.servo_angles()["HeadYaw"]
    mock.command({"HeadYaw": start + 0.4}, 0.3)
    for _ in range(40):
        mock.sleep(0.0137)
        reading = mock.read_joints()
        assert mock.now() - 0.048 < reading.t_s <= mock.now() - 0.036 + 1e-9
        assert abs(reading.t_s / 0.012 - round(reading.t_s / 0.012)) < 1e-6  # LoLA's 12 ms cycle
        servo = mock.servo_angles(reading.t_s)
        for joint, angle in reading.angles_rad.items():
            assert abs(angle / STEP - round(angle / STEP)) < 1e-9, joint  # always a whole number of steps
            assert abs(angle - servo[joint]) <= STEP / 2 + 1e-12  # the step of the position at its sampling time
    mock.sleep(1.0)
    coarse = MockBackend(seed=SEED, realism={"preset": "realistic", "encoder_step_rad": math.radians(0.1)})
    angle = coarse.read_joints().angles_rad["LKneePitch"]
    assert abs(angle / math.radians(0.1) - round(angle / math.radians(0.1))) < 1e-9  # configurable step
    coarse.close()


@pytest.mark.parametrize("mode", ["command", "centre", "uniform"])
def test_a_still_joint_stands_inside_its_commanded_step_and_sags_with_the_load(mode):
    """Without stiffness: exactly at the command / the step centre / anywhere in the step. With a finite
    stiffness the gravity load pulls it towards the load's side, never out of the commanded step."""
    stiff = MockBackend(seed=SEED, realism={"preset": "realistic", "servo_rest": mode,
                                            "servo_stiffness_nm_per_rad": None})
    soft = MockBackend(seed=SEED, realism={"preset": "realistic", "servo_rest": mode,
                                           "servo_stiffness_nm_per_rad": 300.0})
    command = {"LKneePitch": 0.2503, "LHipPitch": -0.6011, "LAnklePitch": -0.1999, "HeadPitch": 0.3004}
    positions = {}
    for name, mock in (("stiff", stiff), ("soft", soft)):
        _still(mock, command)
        sensor = mock.servo_angles()  # sensor space: true angle minus the encoder offset
        q_true = mock.true_angles()
        for joint, c in command.items():
            assert q_true[joint] == pytest.approx(sensor[joint] + mock.truth.alpha_rad[joint], abs=1e-12)
            k = round(c / STEP)
            assert abs(sensor[joint] - k * STEP) < STEP / 2, (name, joint)  # inside the commanded cell
            reading = mock.read_joints().angles_rad[joint]
            assert reading == pytest.approx(k * STEP, abs=1e-12)  # so the servo reads its commanded step
        positions[name] = sensor
    tau = soft.body.gravity_torques(np.array([soft.reference_angles()[j] for j in JOINTS])
                                    + np.array([soft.truth.alpha_rad[j] for j in JOINTS]))
    for joint, c in command.items():
        if mode == "command":
            assert positions["stiff"][joint] == pytest.approx(c, abs=1e-12)
        elif mode == "centre":
            assert positions["stiff"][joint] == pytest.approx(round(c / STEP) * STEP, abs=1e-12)
        sag = positions["soft"][joint] - positions["stiff"][joint]
        expected = tau[JOINT_INDEX[joint]] / 300.0
        assert np.sign(sag) == np.sign(expected) and abs(sag) <= abs(expected) + 1e-9  # towards the load, limited
    stiff.close()
    soft.close()


def test_a_joint_sent_the_target_it_holds_stays_where_it_stands_in_its_cell():
    """Re-sending a joint its target (the agent sends all 14 joints for every head posture) does not move it: the
    error it has inside its step is shared by every image until its command changes (then it finds a new place)."""
    mock = MockBackend(seed=SEED, realism={"preset": "realistic", "servo_stiffness_nm_per_rad": None})
    legs = {"LKneePitch": 0.2503, "LHipPitch": -0.6011}
    _still(mock, dict(legs, HeadYaw=0.1, HeadPitch=0.40))
    first = mock.servo_angles()
    moved = []
    for k in range(6):  # the head moves, the legs are sent the same targets again
        _still(mock, dict(legs, HeadYaw=0.1 - 0.02 * (k + 1), HeadPitch=0.40))
        now = mock.servo_angles()
        assert now["LKneePitch"] == pytest.approx(first["LKneePitch"], abs=1e-12)
        assert now["LHipPitch"] == pytest.approx(first["LHipPitch"], abs=1e-12)
        moved.append(now["HeadYaw"] - (0.1 - 0.02 * (k + 1)))
    assert np.std(moved) > STEP / 20  # the re-commanded head finds a new place in its cell each time
    _still(mock, {"LKneePitch": 0.2503 + 5 * STEP})
    _still(mock, {"LKneePitch": 0.2503})  # away and back: a new place
    assert mock.servo_angles()["LKneePitch"] != pytest.approx(first["LKneePitch"], abs=1e-9)
    mock.close()


def test_the_load_mode_sags_by_torque_over_stiffness_and_more_under_more_load():
    mock = MockBackend(seed=SEED, realism={"preset": "realistic", "servo_rest": "load",
                                           "servo_stiffness_nm_per_rad": 200.0})
    sags, torques = [], []
    for knee in (0.1, 0.8, 1.5):
        _still(mock, {"LKneePitch": knee, "LHipPitch": -0.9})
        q = np.array([mock.reference_angles()[j] for j in JOINTS]) + np.array([mock.truth.alpha_rad[j]
                                                                                for j in JOINTS])
        tau = mock.body.gravity_torques(q)[JOINT_INDEX["LHipPitch"]]
        sag = mock.servo_angles()["LHipPitch"] - (-0.9)
        assert sag == pytest.approx(tau / 200.0, rel=1e-9, abs=1e-12)
        sags.append(sag)
        torques.append(tau)
    order = np.argsort(np.abs(torques))
    assert np.all(np.diff(np.abs(np.array(sags)[order])) > 0)  # a larger load, a larger steady error
    assert max(abs(s) for s in sags) > STEP  # off by more than a step: the reading shows it
    mock.close()


def test_rest_offset_modes():
    c, step = 0.1003, 0.001
    assert rest_offset(c, 0.0, "command", step, None) == pytest.approx(0.0)
    assert c + rest_offset(c, 0.0, "centre", step, None) == pytest.approx(0.100)
    assert c + rest_offset(c, 0.0, "uniform", step, None, u=-0.25) == pytest.approx(0.09975)
    assert c + rest_offset(c, 2.0, "centre", step, 1000.0) == pytest.approx(0.1005, abs=1e-7)  # to the edge
    assert rest_offset(c, 2.0, "load", step, 1000.0) == pytest.approx(0.002)


def test_second_order_closed_form_matches_integration_and_overshoots_a_little():
    dyn = SecondOrder(time_constant_s=0.025, damping=0.7)
    assert 0.03 < dyn.overshoot() < 0.06  # "a little overshoot": 4.6 %
    tau = np.linspace(0.0, 0.4, 4001)
    step = dyn.step_response(tau)
    assert step.max() == pytest.approx(1.0 + dyn.overshoot(), rel=1e-4)
    settled = dyn.settling_time_s(0.02)
    assert 0.08 < settled < 0.12  # settles to 2 % within about 0.1 s
    assert np.all(np.abs(step[tau >= settled] - 1.0) <= 0.02)
    assert np.any(np.abs(step[tau < 0.9 * settled] - 1.0) > 0.02)
    # A ramp that stops: the closed form (ramp lag and transients) against numerical integration of the ODE.
    w, z = dyn.omega, dyn.damping

    def reference(t):
        return 2.0 * min(max(t - 0.05, 0.0), 0.1)  # 2 rad/s from 0.05 s to 0.15 s

    def ode(t, x):
        return [x[1], w * w * (reference(t) - x[0]) - 2 * z * w * x[1]]

    times = np.linspace(0.0, 0.5, 501)
    numeric = solve_ivp(ode, (0.0, 0.5), [0.0, 0.0], t_eval=times, max_step=1e-4, rtol=1e-10, atol=1e-12).y[0]
    from naocal.backends.mock_servo import servo_positions

    changes = [([0.05, 0.15], [2.0, -2.0])]
    closed = [servo_positions(t, [reference(t)], [2.0 if 0.05 <= t < 0.15 else 0.0], changes, dyn, [], [])[0]
              for t in times]
    np.testing.assert_allclose(closed, numeric, atol=1e-6)
    # A step of the rest offset (0.01 rad at 0.2 s) overshoots and settles as a step response does.
    rest = [servo_positions(t, [0.0], [0.0], [([], [])], dyn, [0.2], [np.array([0.01])])[0] for t in times]
    np.testing.assert_allclose(rest, 0.01 * dyn.step_response(times - 0.2) * (times >= 0.2), atol=1e-12)


def test_the_mock_joint_settles_like_a_damped_servo_not_a_straight_line(realistic):
    mock = realistic
    _still(mock, {"LKneePitch": 0.4}, wait_s=1.0)
    t_command = mock.now()
    mock.command({"LKneePitch": 0.9}, 0.6)
    end = max(mock._track(j).end_time() for j in JOINTS)
    times = np.arange(t_command, end + 0.4, 0.001)
    knee = np.array([mock.servo_angles(t)["LKneePitch"] for t in times])
    reference = np.array([mock.reference_angles(t)["LKneePitch"] for t in times])
    moving = (times > t_command + 0.1) & (times < end - 0.01)
    lag = reference[moving] - knee[moving]
    assert np.all(lag > 0.01)  # it trails the interpolated command while moving...
    final = mock.servo_angles(end + 2.0)["LKneePitch"]
    assert abs(final - round(0.9 / STEP) * STEP) < STEP / 2  # ... comes to rest in the commanded step ...
    over = knee.max() - final
    assert math.radians(0.05) < over < math.radians(3.0)  # ... after a little overshoot ...
    within = times[np.abs(knee - final) > STEP / 2]
    assert within[-1] - end < 0.2  # ... and settles to half a step within 0.2 s of the command's end
    mock.sleep(1.0)


def test_large_offsets_are_drawn_within_their_ranges():
    pitches, hyp = [], []
    for seed in range(300):
        truth = draw_truth(seed, realism="realistic")
        ideal = draw_truth(seed)
        deg = {j: math.degrees(truth.alpha_rad[j]) for j in JOINTS}
        assert deg["LHipYawPitch"] == deg["RHipYawPitch"] and 0.5 <= abs(deg["LHipYawPitch"]) <= 12.0
        hyp.append(abs(deg["LHipYawPitch"]))
        for joint in LEG_JOINTS:
            if "HipYawPitch" not in joint:
                assert 0.2 <= abs(deg[joint]) <= 3.0
        rot = {k: math.degrees(v) for k, v in truth.camera_rotation_rad.items()}
        assert -6.0 <= rot["pitch"] <= 2.0 or 7.0 <= abs(rot["pitch"]) <= 14.0
        assert 1.0 <= abs(rot["roll"]) <= 3.0 and 1.0 <= abs(rot["yaw"]) <= 3.0
        pitches.append(rot["pitch"])
        assert truth.board_mount == ideal.board_mount  # the mounts stay those of the ideal mock's stream
        cam = truth.camera
        assert abs(cam.fx_px - 618.0) <= 1.5 and abs(cam.fy_px - 618.0) <= 1.5
        assert abs(cam.cx_px - 320.0) <= 2.0 and abs(cam.cy_px - 240.0) <= 2.0
    outliers = np.mean(np.abs(pitches) > 6.5)
    assert 0.05 < outliers < 0.16  # 10 % of heads (binomial: 300 draws)
    assert max(hyp) > 10.0 and np.mean(np.array(hyp) > 6.0) > 0.3
    assert MockBackend(seed=0, realism="realistic").intrinsics().fx_px == 618.0


def test_ideal_mock_is_unchanged_by_the_realism_option():
    a, b = draw_truth(4), draw_truth(4, realism="ideal")
    assert a == b
    assert a.camera.fx_px == 600.0 and a.camera.cx_px == 320.0


def test_each_mock_names_the_robot_it_plays(realistic):
    """The realistic mock, a NAO V6, called itself a V5; the ideal mock keeps its name (a resume compares it)."""
    assert realistic.robot_identity()["model"] == "NAO H25 V6 (naocal PyBullet mock)"
    ideal = MockBackend(seed=SEED)
    try:
        assert ideal.robot_identity()["model"] == "NAO H25 V5 (naocal PyBullet mock)"
    finally:
        ideal.close()


def test_stamps_relate_to_the_rows_as_b_humans_camera_timing_says(realistic):
    mock = realistic
    mock.sleep(0.5)
    image = mock.capture()
    t_mid = mock.exposure_time(image)
    first, last = mock.row_time(t_mid, [0, 479])
    # B-Human: first row at stamp - imageRecordingTime - imageRecordingDelay (0.045 s, -0.036 s lower camera)
    assert first == pytest.approx(image.t_exposure_s - 0.045 + 0.036, abs=0.045 / 480 + 1e-9)
    assert last - first == pytest.approx(0.045 * 479 / 480)


def test_rows_of_a_moving_board_are_displaced_by_their_exposure_times_and_a_still_board_is_not():
    rolling = MockBackend(seed=SEED, realism={"preset": "realistic", "glare_rate": 0.0})
    global_shutter = MockBackend(seed=SEED, realism={"preset": "realistic", "readout_s": 0.0, "glare_rate": 0.0})
    command, leg = visible_stances(rolling, 1, seed=11, margin_px=60.0)[0]
    still = [settle_and_capture(m, command) for m in (rolling, global_shutter)]
    for m in (rolling, global_shutter):
        m.sleep(0.4)
    still = [m.capture() for m in (rolling, global_shutter)]
    assert np.array_equal(still[0].pixels, still[1].pixels)  # a still robot: the rolling shutter changes nothing
    moved = dict(command)
    for joint in leg_joints(leg)[2:4]:
        moved[joint] = command[joint] + 0.08
    rolling.command(moved, 0.02)  # slowly: about 0.05 rad/s
    rolling.sleep(0.35 + rolling.camera_delay_s)
    image = rolling.capture()
    t_mid = rolling.exposure_time(image)
    uv, visible = rolling.true_vertex_pixels(image)[leg]
    for i in range(24):  # each vertex where the board was when its row was exposed
        t_row = float(rolling.row_time(t_mid, uv[i, 1]))
        np.testing.assert_allclose(uv[i], rolling.vertex_pixels_at(t_row)[leg][i], atol=0.01)
    at_mid = rolling.vertex_pixels_at(t_mid)[leg]
    assert np.max(np.linalg.norm(uv - at_mid, axis=1)) > 0.5  # rows far from the middle are visibly displaced
    found = detect_board_vertices(image.pixels, uv + 2.0)
    assert found.ok, found.detail
    assert np.sqrt(np.mean((found.vertices_px - uv) ** 2)) < 0.15  # the image shows it so
    assert np.sqrt(np.mean((found.vertices_px - at_mid) ** 2)) > 0.3
    rolling.close()
    global_shutter.close()


def test_yuyv_round_trip_halves_the_chroma_resolution():
    rng = np.random.default_rng(0)
    grey = np.repeat(rng.uniform(0, 255, (8, 16))[:, :, None], 3, axis=2)
    assert np.max(np.abs(yuyv_to_bgr(bgr_to_yuyv(grey)).astype(float) - grey)) <= 1.5  # luma at full resolution
    colours = rng.uniform(30, 225, (8, 8, 3))
    pairs = np.repeat(colours, 2, axis=1)  # colour constant over each pixel pair: kept
    assert np.max(np.abs(yuyv_to_bgr(bgr_to_yuyv(pairs)).astype(float) - pairs)) <= 2.0
    stripes = np.zeros((8, 16, 3))
    stripes[:, 0::2] = (0, 0, 200)  # red / blue alternating every pixel: chroma cannot follow
    stripes[:, 1::2] = (200, 0, 0)
    back = yuyv_to_bgr(bgr_to_yuyv(stripes)).astype(float)
    yuyv = bgr_to_yuyv(stripes)
    assert np.all(yuyv[:, 0::2, 1] == yuyv[0, 0, 1]) and np.all(yuyv[:, 1::2, 1] == yuyv[0, 1, 1])
    chroma = back - back.mean(axis=2, keepdims=True)
    assert np.max(np.abs(chroma[:, 0::2] - chroma[:, 1::2])) < 25  # both pixels of a pair share one chroma
    assert np.max(np.abs(stripes - back)) > 60  # so the stripes' colours are lost
    with pytest.raises(ValueError):
        bgr_to_yuyv(np.zeros((4, 5, 3)))
    scene = rng.uniform(0, 1, (8, 16)).astype(np.float32)  # the mock's grey scenes take a shortcut: the same
    assert np.array_equal(grey_to_yuyv(scene), bgr_to_yuyv(np.repeat(scene[:, :, None] * 255.0, 3, axis=2)))


def test_realistic_images_are_yuyv_noisy_and_slightly_defocused(realistic):
    mock = realistic
    mock.sleep(0.3)
    image = mock.capture().pixels.astype(float)
    flat = image[:40, :40]  # background
    noise = np.std(flat[..., 1])
    assert 1.5 < noise < 3.5  # Y noise of 2 levels of 219, seen through BT.601's 255 / 219
    assert np.std(flat[..., 0] - flat[..., 2]) > 0.5  # chroma noise separates the channels
    ideal = MockBackend(seed=SEED)
    ideal.sleep(0.3)
    assert np.array_equal(ideal.capture().pixels[..., 0], ideal.capture().pixels[..., 2])  # grey BGR
    ideal.close()


def test_defocus_widens_the_board_edges():
    widths = {}
    for sigma in (0.0, 1.2):
        mock = MockBackend(seed=SEED, realism={"preset": "realistic", "defocus_sigma_px": sigma, "glare_rate": 0.0,
                                               "luma_noise_std": 0.0, "chroma_noise_std": 0.0})
        command, leg = visible_stances(mock, 1, seed=2, margin_px=40.0)[0]
        image = settle_and_capture(mock, command)
        mock.sleep(0.4)
        image = mock.capture()
        uv, _ = mock.true_vertex_pixels(image)[leg]
        widths[sigma] = detect_board_vertices(image.pixels, uv).edge_width_px
        mock.close()
    assert widths[1.2] > widths[0.0] + 0.5


def test_corner_fault_model_fires_at_its_rate():
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.arange(6) * 30.0, np.arange(4) * 30.0), axis=-1).reshape(24, 2) + 100.0
    kinds, n = [], 0
    for _ in range(2000):
        moved, faults = draw_faults(rng, grid, 0.015)
        n += 24
        for f in faults:
            shift = moved[f.vertex] - grid[f.vertex]
            if f.kind == "square":  # exactly onto a grid neighbour: one square off
                assert min(np.linalg.norm(grid - moved[f.vertex], axis=1)) == pytest.approx(0.0)
                assert np.linalg.norm(shift) == pytest.approx(30.0)
            else:
                assert 3.0 <= np.linalg.norm(shift) <= 20.0
            kinds.append(f.kind)
        untouched = np.setdiff1d(np.arange(24), [f.vertex for f in faults])
        assert np.array_equal(moved[untouched], grid[untouched])
    rate = len(kinds) / n
    assert 0.012 < rate < 0.018  # 48000 vertices: 1.5 % +- 0.17 % (3 sigma)
    assert 0.4 < np.mean(np.array(kinds) == "square") < 0.6


def test_faulty_detector_wraps_a_detector_reproducibly():
    from naocal.agent.corners import BoardDetection
    from naocal.backends.base import CameraImage

    grid = np.arange(48, dtype=float).reshape(24, 2) * 7.0

    def perfect(image, predicted, leg, margin):
        return BoardDetection(vertices_px=grid.copy())

    def failing(image, predicted, leg, margin):
        return BoardDetection(vertices_px=None, reason="missing")

    wrapped = FaultyDetector(perfect, 0.5, seed=1)
    image = CameraImage(np.zeros((4, 4, 3), np.uint8), 12.345)
    first = wrapped(image, grid, "L", 40.0).vertices_px
    again = FaultyDetector(perfect, 0.5, seed=1)(image, grid, "L", 40.0).vertices_px
    assert np.array_equal(first, again) and not np.array_equal(first, grid)
    assert len(wrapped.faults) == int(np.sum(np.any(first != grid, axis=1)))
    assert not FaultyDetector(failing, 0.5, seed=1)(image, grid, "L", 40.0).ok
    assert np.array_equal(FaultyDetector(perfect, 0.0, seed=1)(image, grid, "L", 40.0).vertices_px, grid)


def test_glare_is_rendered_on_boards_at_its_rate():
    glare = MockBackend(seed=SEED, realism={"preset": "realistic", "glare_rate": 0.05})
    plain = MockBackend(seed=SEED, realism={"preset": "realistic", "glare_rate": 0.0})
    decided = [glare._glare_stream(k).uniform() < 0.05 for k in range(4000)]
    assert 0.04 < np.mean(decided) < 0.06  # 5 % of frames (4000 frames: +- 1 % at 3 sigma)
    command, leg = visible_stances(glare, 1, seed=4, margin_px=40.0)[0]
    for mock in (glare, plain):
        settle_and_capture(mock, command)
    k = next(k for k in range(glare._frame_index(glare.capture()) + 1, 10 ** 6) if decided[k])
    for mock in (glare, plain):
        mock.sleep(k * (1 / 30) + 0.004 + mock.camera_delay_s + 1e-3 - mock.now())
    images = [mock.capture() for mock in (glare, plain)]
    assert glare._frame_index(images[0]) == k
    difference = images[0].pixels.astype(float) - images[1].pixels.astype(float)
    board, (u, v), sigma, amplitude = glare._frame(k).glare
    assert 3.0 <= sigma <= 10.0 and 0.3 <= amplitude <= 0.8
    assert difference.min() >= 0.0 and difference.max() > 15  # a highlight (white squares saturate), nothing darker
    far = np.hypot(*np.meshgrid(np.arange(640) - u, np.arange(480) - v)) > 5 * sigma
    assert np.all(difference[far] == 0.0)  # only around its centre on the board
    glare.close()
    plain.close()
