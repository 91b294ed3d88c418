"""The Duckiebot's joint fit (kinds/duckiebot/fit.py) and the log-to-calibration entry (kinds/duckiebot/identify.py),
issue 23: exact Jacobians, stds that cover the truth (synthetic corners, and logs of the independent OpenCV
renderer), the baseline refused when the data cannot determine it, Duckietown's files from the fit."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.calibration_files import apply_homography, read_calibration, write_calibration
from naocal.kinds.duckiebot.detect import detect_markers
from naocal.kinds.duckiebot.fit import (CAMERA, PWM_DRIVER, Drive, DriveEquations, PoseEquations, Sightings,
                                        _compose, _inverse, fit_drive, pose_parameters, secant_gain, sighting_runs,
                                        trajectory)
from naocal.kinds.duckiebot.kinematics import body_velocity, duty_to_pwm, integrate_pose
from naocal.kinds.duckiebot.identify import Detections, identify_log, rectified_sightings
from naocal.kinds.duckiebot.intrinsics import LensCamera
from naocal.kinds.duckiebot.render import (DriveStep, calibration_scene, hidden_robot, joint_program, paper_program,
                                    render_drive_log, simulate_drive)
from naocal.kinds.duckiebot.robot import camera_mount
from naocal.solver.camera import project, undistort_points
from naocal.solver.errors import NaocalError, SolveError
from naocal.solver.transforms import invert_transform, make_transform, rot_z, transform_points

LOG_K = 27.0  # the k the logs state (Duckietown's default): the fitted gain and trim are in its units
Z_LIMIT = 3.5


def truth_of(robot) -> dict:
    """The hidden robot's parameters as the fit sees them: gain and trim in the log's k (w = u k / (gain +- trim),
    so gain and trim scale with k together), the camera's pose."""
    kin = robot.kinematics
    truth = {"gain": kin.gain * LOG_K / kin.k, "trim": kin.trim * LOG_K / kin.k, "baseline_m": kin.baseline_m}
    truth.update(zip(CAMERA, pose_parameters(robot.T_base_camera)))
    return truth


def pwm_motor_poses(drive, kin, pwm_start):
    """The poses at the frames of a robot behind Duckietown's wheel driver (kinematics.duty_to_pwm, floored) whose
    motors start at PWM `pwm_start`: each wheel turns at (pwm - pwm_start) / 195 k / (gain -+ trim) (an independent
    small simulator: the driver's formula and exact arcs, not the fit's trajectory)."""
    pose, t, out = np.zeros(3), 0.0, []
    events = sorted([(t_, 0, i) for i, t_ in enumerate(drive.wheel_t_s)] + [(t_, 1, i) for i, t_ in
                                                                             enumerate(drive.frame_t_s)])
    w = np.zeros(2)
    for t_event, kind, i in events:
        v, omega = body_velocity(*w, kin.radius_m, kin.baseline_m)
        pose, t = integrate_pose(pose, v, omega, t_event - t), t_event
        if kind == 1:
            out.append(pose)
            continue
        duties = np.array([drive.left_duty[i], drive.right_duty[i]])
        pwm = duty_to_pwm(duties)
        w = np.sign(duties) * np.maximum(pwm - pwm_start, 0) * (pwm > 0) / 195.0 * kin.k / np.array(
            [kin.gain - kin.trim, kin.gain + kin.trim])
    return np.array(out)


def moved_by_hand(drive, frame_poses, at_row: int, moved):
    """(break time, frame poses) of the drive stopped before its wheel row `at_row` (the robot at rest there) and
    carried by hand by `moved` (x, y, theta in its own frame) before that row's command: every later pose moved
    rigidly with it (the commands drive the same relative motion from wherever it stands)."""
    t_break = float(drive.wheel_t_s[at_row])
    assert drive.left_duty[at_row - 1] == drive.right_duty[at_row - 1] == 0.0, "not at rest"
    rest = frame_poses[np.searchsorted(drive.frame_t_s, t_break) - 1]
    carried = _compose(_compose(rest, np.asarray(moved, dtype=float)), _inverse(rest))
    poses = np.array(frame_poses, dtype=float)
    after = drive.frame_t_s >= t_break
    poses[after] = [_compose(carried, p) for p in poses[after]]
    return t_break, poses


def synthetic(seed, noise_px=0.3, steps=None, effects=None, pwm_start=None, moved=None):
    """(robot, Drive, Sightings, K): the hidden robot `seed` with the hidden wheel `effects` (fit.EFFECTS' parameters)
    driven through `steps`, its marker corners projected by a pinhole with the true K (what rectification gives)
    plus Gaussian noise; markers within 0.6 m, in the image. `pwm_start`: the duties pass Duckietown's PWM driver
    to motors that start at this PWM (pwm_motor_poses). `moved`: (wheel row, (x, y, theta)): the run stopped before
    that row and the robot carried by hand (moved_by_hand); the Drive has the break (segment_t_s)."""
    robot, scene = hidden_robot(seed), calibration_scene()
    drive = simulate_drive(steps or joint_program(board_steps=0), robot.kinematics, effects=effects)
    frame_poses = drive.frame_poses if pwm_start is None else pwm_motor_poses(drive, robot.kinematics, pwm_start)
    breaks = ()
    if moved is not None:
        t_break, frame_poses = moved_by_hand(drive, frame_poses, *moved)
        breaks = (t_break,)
    cam = robot.camera
    K = np.array([[cam.fx_px, 0.0, cam.cx_px], [0.0, cam.fy_px, cam.cy_px], [0.0, 0.0, 1.0]])
    corners = scene.marker_corners()
    rng = np.random.default_rng(seed)
    rows = []
    for f, pose in enumerate(frame_poses):
        T = make_transform(rot_z(pose[2]), (pose[0], pose[1], 0.0)) @ robot.T_base_camera
        p_cam = transform_points(invert_transform(T), corners.reshape(-1, 3)).reshape(-1, 4, 3)
        for m in range(len(corners)):
            if np.any(p_cam[m, :, 0] < 0.05) or np.linalg.norm(p_cam[m], axis=1).max() > 0.6:
                continue
            uv = project(p_cam[m], K[0, 0], K[1, 1], K[0, 2], K[1, 2]).uv_px
            if np.all((uv > 5) & (uv < [634, 474])):
                rows += [(f, scene.marker_ids[m], c, *(uv[c] + rng.normal(0.0, noise_px, 2))) for c in range(4)]
    rows = np.array(rows)
    sightings = Sightings(rows[:, 0].astype(int), rows[:, 1].astype(int), rows[:, 2].astype(int), rows[:, 3:])
    return robot, Drive(drive.wheel_t_s, drive.left_duty, drive.right_duty, drive.frame_t_s, LOG_K, 0.0318, 0.1,
                        segment_t_s=breaks), sightings, K


def test_the_trajectory_jacobian_is_exact():
    robot, drive, _, _ = synthetic(2)
    x = np.array([1.1, 0.04, 0.102, 0.3, -0.2, 2.9])
    times = drive.frame_t_s[3:]
    _, J = trajectory(drive, *x[:3], x[3:], drive.frame_t_s[3], times)
    for j in range(6):
        step = np.zeros(6)
        step[j] = 1e-6
        plus, _ = trajectory(drive, *(x + step)[:3], (x + step)[3:], drive.frame_t_s[3], times)
        minus, _ = trajectory(drive, *(x - step)[:3], (x - step)[3:], drive.frame_t_s[3], times)
        np.testing.assert_allclose(J[:, :, j], (plus - minus) / 2e-6, atol=1e-6, rtol=1e-6)


def test_the_trajectory_jacobian_is_exact_with_the_driver_and_each_wheels_lag():
    """Through Duckietown's PWM driver, with the motors' start and a lag per wheel (lag_difference), every column
    against central differences."""
    _, drive, _, _ = synthetic(2)
    drive = Drive(drive.wheel_t_s, drive.left_duty, drive.right_duty, drive.frame_t_s, LOG_K, 0.0318, 0.1,
                  pwm_driver=True)
    effects = {"dead_zone": 0.01, "wheel_lag_s": 0.04, "wheel_lag_difference_s": 0.004}
    x = np.array([1.1, 0.04, 0.102, 0.3, -0.2, 2.9, *effects.values()])
    times = drive.frame_t_s[3:40]

    def poses(v, jacobian=False):
        out = trajectory(drive, *v[:3], v[3:6], drive.frame_t_s[3], times, dict(zip(effects, v[6:])))
        return out if jacobian else out[0]

    _, J = poses(x, True)
    for j in range(len(x)):
        step = np.zeros(len(x))
        step[j] = 1e-6
        np.testing.assert_allclose(J[:, :, j], (poses(x + step) - poses(x - step)) / 2e-6, atol=1e-5, rtol=1e-5,
                                   err_msg=str(j))


CARRIED = (49, (-0.03, 0.02, 0.08))  # stopped before wheel row 49 (7.9 s, at rest), carried 3 cm back, 2 left, 4.6 deg


@pytest.mark.parametrize("moved", [None, CARRIED])
def test_the_equations_jacobian_is_exact(moved):
    """Every column of the corners' Jacobian (kinematics, camera pose, anchor, markers) against central
    differences, at a point away from the truth; in segments, each segment's anchor too."""
    robot, drive, sightings, K = synthetic(1, moved=moved)
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    assert ("anchor1.theta_rad" in fit.names) == (moved is not None)
    x = fit.x + np.random.default_rng(0).normal(0.0, 1e-3, len(fit.x))
    eq = DriveEquations(drive, sightings, K, 0.065, fit.reference_marker, fit.names, x, np.ones(len(x), bool))
    _, J = eq.predict(x)
    numeric = np.zeros_like(J)
    for j in range(len(x)):
        step = np.zeros(len(x))
        step[j] = 1e-6
        numeric[:, :, j] = (eq.predict(x + step, jacobian=False)[0] - eq.predict(x - step, jacobian=False)[0]) / 2e-6
    assert len(x) > 15 and np.abs(J).max() > 1.0
    np.testing.assert_allclose(J, numeric, atol=2e-4 * np.abs(J).max(), rtol=1e-5)


def test_the_start_poses_jacobian_is_exact_for_each_segments_anchor():
    """drive_start's problem (PoseEquations) in segments: every column, both anchors', against central differences."""
    robot, drive, sightings, K = synthetic(1, moved=CARRIED)
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    frames = np.unique(fit.sightings.frame)
    seen = np.random.default_rng(0).normal(0.0, 0.01, (len(frames), 3))
    eq = PoseEquations(drive, frames, seen, fit.names, fit.x, np.ones(len(fit.x), bool))
    assert [fit.names[i] for i in eq.index][-3:] == ["anchor1.x_m", "anchor1.y_m", "anchor1.theta_rad"]
    x = fit.x[eq.index] + 1e-3
    _, J = eq.dense(x)
    for j in range(len(x)):
        step = np.zeros(len(x))
        step[j] = 1e-6
        np.testing.assert_allclose(J[:, j], (eq.dense(x + step)[0] - eq.dense(x - step)[0]) / 2e-6, atol=1e-6,
                                   rtol=1e-6, err_msg=fit.names[eq.index[j]])


@pytest.mark.parametrize("seed", [1, 2])
def test_a_drive_stopped_and_carried_by_hand_is_fitted_in_segments(seed):
    """A run stopped mid-drive, the robot carried elsewhere and the drive resumed: with the break in the log each
    segment has its own anchor and the shared wheels and camera come out within their stds; the same corners read
    as one drive are not explained (7-24 px RMS on seeds 1-3)."""
    robot, drive, sightings, K = synthetic(seed, moved=CARRIED)
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    assert fit.success and fit.rms_px < 0.4 and sorted(fit.anchors) == [0, 1]
    assert fit.anchors[1] >= drive.segment_t_s[0] > fit.anchors[0]
    for name, value in truth_of(robot).items():
        assert abs(fit.value(name) - value) < Z_LIMIT * fit.stdev(name), (name, fit.value(name), value)
    one_drive = fit_drive(replace(drive, segment_t_s=()), sightings, K, 0.065, camera_mount())
    assert one_drive.rms_px > 5.0


def test_a_segment_seen_in_one_frame_is_left_out_with_a_warning():
    robot, drive, sightings, K = synthetic(1, moved=CARRIED)
    after = np.unique(sightings.frame[drive.frame_t_s[sightings.frame] >= drive.segment_t_s[0]])
    rows = ~np.isin(sightings.frame, after[1:])  # the segment after the break: its first frame only
    fit = fit_drive(drive, sightings.subset(rows), K, 0.065, camera_mount())
    assert not any(n.startswith("anchor1.") for n in fit.names) and sorted(fit.anchors) == [0]
    assert any("segment 1" in w and "left out" in w for w in fit.warnings)
    assert abs(fit.value("trim") - truth_of(robot)["trim"]) < Z_LIMIT * fit.stdev("trim")


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_synthetic_corners_give_the_truth_within_the_stds(seed):
    robot, drive, sightings, K = synthetic(seed)
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    assert fit.success and not len(fit.outliers.frame)
    for name, value in truth_of(robot).items():
        z = (fit.value(name) - value) / fit.stdev(name)
        assert abs(z) < Z_LIMIT, (name, fit.value(name), value, fit.stdev(name))
    assert abs(fit.value("trim") - truth_of(robot)["trim"]) < 0.001


def test_a_pwm_driver_and_the_motors_start_are_modelled():
    """Duties through Duckietown's 8-bit driver to motors starting at PWM 65 (its floor: 60), drives at two duties:
    with the driver and the dead zone modelled, trim within 0.0005 and the stds cover; without, the trim is biased
    (the start scales the differential speed by u / (u - c)) beyond 0.001."""
    steps = joint_program(board_steps=0, drive_duties=(0.3, 0.45))
    robot, drive, sightings, K = synthetic(3, steps=steps, pwm_start=65.0)
    truth = truth_of(robot)
    # the driver named like an effect (identify --effects pwm_driver,dead_zone): the log does not say
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount(), effects=(PWM_DRIVER, "dead_zone"))
    assert fit.pwm_driver and not drive.pwm_driver
    assert abs(fit.value("trim") - truth["trim"]) < 0.0005
    assert abs(fit.value("dead_zone") - 5.0 / 195.0) < 3 * fit.stdev("dead_zone")
    for name in ("gain", "trim", "baseline_m"):
        assert abs(fit.value(name) - truth[name]) < Z_LIMIT * fit.stdev(name), name
    # the exported gain drives it 0.3 m/s: the secant with the start and the driver's mean half step folded in
    gain, std = secant_gain(drive, fit, 0.3)
    needed = truth["gain"] + 5.5 / 195.0 * LOG_K * 0.0318 / 0.3
    assert abs(gain - needed) < Z_LIMIT * std and abs(gain / needed - 1.0) < 0.01
    naive = fit_drive(drive, sightings, K, 0.065, camera_mount())
    assert abs(naive.value("trim") - truth["trim"]) > 0.001


def test_many_one_wheel_turns_before_the_drives_start_from_the_poses_seen():
    """Two sweeps of one-wheel half steps (8 left, 16 right, 8 left: the mission's lens views) after the first
    stretch, on a robot with a large trim (-0.10): dead reckoning at the nominal wheels drifted so far that markers
    in view projected behind the camera at the start values, and the first Jacobian left 9 directions 'undetermined'
    (the realistic mock, seed 3, with the lens views). Started from the wheels fitted to the poses seen
    (fit.drive_start), it fits, and the stds cover."""
    steps = joint_program(board_steps=0)
    first = next(i for i, s in enumerate(steps) if s.left_duty > 0 and s.right_duty > 0)
    left, right = DriveStep(0.05, 0.0, 0.25), DriveStep(0.05, 0.25, 0.0)
    sweep = [left] * 8 + [right] * 16 + [left] * 8
    robot, drive, sightings, K = synthetic(3, steps=steps[:first + 1] + 2 * sweep + steps[first + 1:])
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    assert fit.success
    for name, value in truth_of(robot).items():
        assert abs(fit.value(name) - value) < Z_LIMIT * fit.stdev(name), (name, fit.value(name), value)
    assert abs(fit.value("trim") - truth_of(robot)["trim"]) < 0.001


def test_the_paper_program_cannot_tell_the_baseline_from_trim():
    """Driving straight only while markers are in view, omega / v = -2 trim / (gain b): the baseline is
    undetermined, and without turns the camera's offset on the body is the anchor's; the core's policy stops the
    fit naming them; fixed by the user, the rest fits."""
    robot, drive, sightings, K = synthetic(1, steps=paper_program(board_steps=0))
    with pytest.raises(SolveError, match="baseline_m.*camera.x_m|camera.x_m.*baseline_m"):
        fit_drive(drive, sightings, K, 0.065, camera_mount())
    fixed = ("baseline_m", "camera.x_m", "camera.y_m")
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount(), fixed=fixed)
    assert fit.success and all(fit.stdev(name) == 0.0 for name in fixed)


def test_no_marker_seen_is_refused():
    robot, drive, sightings, K = synthetic(1)
    with pytest.raises(SolveError, match="no marker"):
        fit_drive(drive, sightings.subset(np.zeros(len(sightings.frame), bool)), K, 0.065, camera_mount())


def test_a_corner_no_model_explains_is_set_aside():
    robot, drive, sightings, K = synthetic(2)
    uv = sightings.uv_px.copy()
    uv[17] += (9.0, -6.0)
    fit = fit_drive(drive, Sightings(sightings.frame, sightings.marker, sightings.corner, uv), K, 0.065,
                    camera_mount(), robust=True)
    assert len(fit.outliers.frame) == 1 and np.allclose(fit.outliers.uv_px[0], uv[17])
    assert abs(fit.value("trim") - truth_of(robot)["trim"]) < 0.001


# ------------------------------------------------------------------------------------------------ rendered logs

@pytest.fixture(scope="module")
def rendered_marker_logs(tmp_path_factory):
    """Three hidden robots through the marker phase with turns (about 20 frames each, ~7 s CPU to render)."""
    return [render_drive_log(tmp_path_factory.mktemp(f"marker{seed}") / "LOG", seed=seed,
                             steps=joint_program(board_steps=0)) for seed in (1, 2, 3)]


# Rendered logs' camera pose: the corner bias the fit models is one constant, the detector's grows as markers
# shrink (docs/DUCKIEBOT.md), an error shared by every frame that frame clusters cannot see; measured worst
# 3.54 stds (camera.z_m, seed 2, an error of 0.16 mm), so the camera pose is held to 4, the kinematics to 3.5.
CAMERA_Z_LIMIT = 4.0


def test_rendered_logs_stds_cover_the_truth(rendered_marker_logs):
    """Detected corners of rendered images (rectified with the true camera, so that only the joint fit is judged):
    gain, trim and baseline within 3.5 stds of the truth, the camera's pose within 4, trim within 0.001."""
    for rendered in rendered_marker_logs:
        log, robot = rendered.log, rendered.robot
        detections = Detections([detect_markers(log.load_frame(i, cv2.IMREAD_GRAYSCALE))
                                 for i in range(len(log.frame_files))], [])
        camera = LensCamera.from_intrinsics(robot.camera)
        fit = fit_drive(Drive.of_log(log), rectified_sightings(detections, camera), camera.K, log.marker_size_m,
                        camera_mount())
        assert fit.success and fit.rms_px < 0.6
        for name, value in truth_of(robot).items():
            z = (fit.value(name) - value) / fit.stdev(name)
            assert abs(z) < (CAMERA_Z_LIMIT if name in CAMERA else Z_LIMIT), (name, fit.value(name), value,
                                                                              fit.stdev(name))
        assert abs(fit.value("trim") - truth_of(robot)["trim"]) < 0.001


def test_a_log_without_enough_board_views_is_refused_in_one_line(rendered_marker_logs):
    with pytest.raises(NaocalError, match=r"board views found, at least 6") as caught:
        identify_log(rendered_marker_logs[0].log.path)
    assert "\n" not in str(caught.value) and str(rendered_marker_logs[0].log.path) in str(caught.value)


@pytest.fixture(scope="module")
def full_log(tmp_path_factory):
    """The whole program (boards while turning, then the markers with turns): about 36 frames, ~12 s CPU."""
    return render_drive_log(tmp_path_factory.mktemp("full") / "LOG", seed=1, steps=joint_program(board_steps=4))


def test_identify_log_calibrates_and_exports_duckietowns_files(full_log, tmp_path):
    """identify_log from the log alone (intrinsics from the boards, then the joint fit); the three files written
    from it put floor points 0.15-0.6 m ahead, seen by the TRUE camera, within a few mm of where they lie."""
    cal = identify_log(full_log.log.path)
    robot = full_log.robot
    truth = truth_of(robot)
    assert cal.drive_fit.success  # the lens: plumb_bob or rational (seed 1: held-out 0.0359 px both)
    assert abs(cal.kinematics.trim - truth["trim"]) < 0.002
    assert abs(cal.kinematics.gain / truth["gain"] - 1.0) < 0.01
    findings = write_calibration(tmp_path, cal.duckietown(calibration_time="2026-11-27-12-00-00"))
    assert not [f for f in findings if f.level == "refuse"]
    files, _ = read_calibration(tmp_path, full_log.log.robot_id)
    x, y = np.meshgrid(np.linspace(0.15, 0.6, 10), np.linspace(-0.15, 0.15, 7))
    ground = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    p_cam = transform_points(invert_transform(robot.T_base_camera), ground)
    seen = robot.camera.project(p_cam)
    rectified = undistort_points(seen, {"fx_px": files.camera.K[0, 0], "fy_px": files.camera.K[1, 1],
                                        "cx_px": files.camera.K[0, 2], "cy_px": files.camera.K[1, 2],
                                        "distortion": list(files.camera.distortion)})
    error = np.linalg.norm(apply_homography(files.homography, rectified) - ground[:, :2], axis=1)
    assert np.sqrt(np.mean(error ** 2)) < 0.005
    document = cal.to_dict()
    assert document["parameters"]["trim"]["std"] > 0 and document["lens"]["model"] == cal.lens.camera.model


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_an_error_shared_along_a_markers_sighting_run_is_in_the_stds(seed):
    """A marker seen in consecutive frames from nearly the same place is detected with nearly the same error: here
    each corner of a marker's run of sightings (its consecutive frames) moved by one offset, little noise besides.
    Clustered by frame, the stds counted each of a run's frames as independent (seeds 1-3: largest |z| 1.4, 1.7,
    5.2; clustered by sighting run, fit.sighting_runs: 0.6, 1.3, 2.9)."""
    robot, drive, sightings, K = synthetic(seed, noise_px=0.02)
    rng = np.random.default_rng(100 + seed)
    shared, uv = {}, sightings.uv_px.copy()
    for i, (f, m, c) in enumerate(zip(sightings.frame, sightings.marker, sightings.corner)):
        earlier = sightings.frame[(sightings.marker == m) & (sightings.frame < f)]
        run = shared.get((m, c, int(earlier.max())) if len(earlier) and f - earlier.max() <= 1 else None)
        if run is None:
            run = rng.normal(0.0, 0.3, 2)
        shared[(m, c, int(f))] = run
        uv[i] += run
    fit = fit_drive(drive, Sightings(sightings.frame, sightings.marker, sightings.corner, uv), K, 0.065,
                    camera_mount())
    z = {name: (fit.value(name) - value) / fit.stdev(name) for name, value in truth_of(robot).items()}
    assert max(abs(v) for v in z.values()) < Z_LIMIT, z


def test_a_break_in_the_log_ends_a_markers_sighting_run():
    """The cluster-robust stds' clusters: marker 3 seen in frames 0-5 without a gap is one run, unless the log has a
    break between frames 2 and 3 (the robot carried: its sightings after are another run's); marker 4 alongside."""
    frame = np.array([0, 1, 2, 3, 4, 5, 0, 1, 4, 5])
    marker = np.array([3, 3, 3, 3, 3, 3, 4, 4, 4, 4])
    one = sighting_runs(frame, marker)
    assert len(set(one[:6])) == 1 and len(set(one[6:])) == 1 and one[0] != one[6]
    segment = (frame >= 3).astype(int)
    split = sighting_runs(frame, marker, segment)
    assert len(set(split[:3])) == 1 and len(set(split[3:6])) == 1 and split[0] != split[3]
    assert split[6] == split[7] and split[8] == split[9] and split[6] != split[8]
    assert len(set(split)) == 4


def test_a_drive_leaves_out_repeated_commands_and_moves_the_same():
    """A recorder republishing each command at 100 Hz: the rows that repeat the row before hold what already holds,
    so the drive keeps one row per change (and the first row after a break, which starts its segment from rest), and
    the trajectory is the same as the log's rows give."""
    from types import SimpleNamespace

    changes = [(0.0, 0.0, 0.0), (0.5, 0.3, 0.35), (1.7, -0.2, 0.2), (2.4, 0.3, 0.3), (3.5, 0.0, 0.0)]
    t = np.round(np.arange(0.0, 4.0, 0.01), 6)
    at = np.searchsorted([c[0] for c in changes], t, side="right") - 1
    left, right = np.array([changes[i][1] for i in at]), np.array([changes[i][2] for i in at])
    wheels = SimpleNamespace(k=27.0, radius_m=0.0318, baseline_m=0.1, limit=1.0)
    log = SimpleNamespace(wheel_t_s=t, left_duty=left, right_duty=right, frame_t_s=np.arange(0.2, 4.0, 0.3),
                          wheels=wheels, segment_t_s=np.array([2.0]))
    drive = Drive.of_log(log)
    np.testing.assert_array_equal(drive.wheel_t_s, [0.0, 0.5, 1.7, 2.0, 2.4, 3.5])
    every = replace(drive, wheel_t_s=t, left_duty=left, right_duty=right)
    times = np.arange(0.25, 1.95, 0.1)
    for a, b in zip(trajectory(drive, 0.9, 0.02, 0.1, (0.1, 0.2, 0.3), 0.2, times),
                    trajectory(every, 0.9, 0.02, 0.1, (0.1, 0.2, 0.3), 0.2, times)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    second = drive.segment(1)
    assert second.wheel_t_s[0] == 2.0 and (second.left_duty[0], second.right_duty[0]) == (-0.2, 0.2)
