"""The camera's intrinsics with the lens model chosen by held-out reprojection error
(kinds/duckiebot/intrinsics.py, issue 23)."""

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.fit import Sightings
from naocal.kinds.duckiebot.intrinsics import (FLOOR_BIAS, FloorMarkers, LensCamera, LensEquations, board_points,
                                               camera_difference_px, choose_lens, fit_camera, opencv_start,
                                               parameter_names)
from naocal.kinds.duckiebot.render import hidden_robot
from naocal.kinds.duckiebot.robot import duckiebot
from naocal.solver.errors import NaocalError

SIZE = (640, 480)


def views(camera: LensCamera, n=18, noise_px=0.05, seed=0, v_max_px=SIZE[1] - 6):
    """Board views spread over the image (above v_max_px) at several distances and tilts, projected by `camera`."""
    rng = np.random.default_rng(seed)
    obj = board_points((7, 5), 0.031)
    centre = obj.mean(axis=0)
    O, I, groups = [], [], []
    while len(O) < n:
        rvec = rng.uniform(-0.5, 0.5, 3)
        R, _ = cv2.Rodrigues(rvec)
        depth = rng.uniform(0.2, 0.5)
        target = np.array([rng.uniform(-0.9, 0.9) * depth, rng.uniform(-0.7, 0.7) * depth, depth])
        tvec = target - R @ centre
        if (R @ obj.T + tvec[:, None])[2].min() < 0.1:
            continue
        uv = camera.project(obj, rvec, tvec)
        if not ((uv >= 5).all() and (uv[:, 0] <= SIZE[0] - 6).all() and (uv[:, 1] <= v_max_px).all()):
            continue
        O.append(obj)
        I.append(uv + rng.normal(0, noise_px, uv.shape))
        groups.append(len(O) % 4)
    return O, I, groups



def central_differences(equations, x) -> np.ndarray:
    """The Jacobian of `equations.dense` at x by central differences, a step of 1e-6 of each parameter's scale."""
    numeric = np.zeros((equations.dense(x)[0].size, len(x)))
    for j in range(len(x)):
        step = np.eye(len(x))[j] * 1e-6 * equations.scales[j]
        numeric[:, j] = (equations.dense(x + step)[0] - equations.dense(x - step)[0]) / (2 * step[j])
    return numeric

def test_camera_difference_is_zero_for_one_camera_and_measures_a_shift():
    truth = LensCamera.from_intrinsics(hidden_robot(1).camera)
    assert camera_difference_px(truth, truth, SIZE) < 1e-3
    shifted = LensCamera("plumb_bob", truth.K + [[0, 0, 2.0], [0, 0, 0], [0, 0, 0]], truth.distortion)
    assert camera_difference_px(truth, shifted, SIZE) == pytest.approx(2.0, abs=1e-3)


def test_a_plumb_bob_lens_is_chosen_and_recovered():
    truth = LensCamera.from_intrinsics(hidden_robot(4).camera)
    O, I, groups = views(truth)
    best, fits = choose_lens(O, I, SIZE, groups)
    assert best.camera.model in ("plumb_bob", "rational") and set(fits) == {"plumb_bob", "rational", "fisheye"}
    assert fits["fisheye"].held_out_rms_px > 2 * best.held_out_rms_px
    assert best.train_rms_px < 0.1  # OpenCV's RMS is per point: sqrt(2) x 0.05 px of noise per coordinate
    assert camera_difference_px(truth, best.camera, SIZE) < 0.5  # the bound over the whole image


def test_a_fisheye_lens_is_chosen_for_fisheye_data():
    truth = LensCamera("fisheye", np.array([[300.0, 0, 322], [0, 301.0, 236], [0, 0, 1]]),
                   np.array([0.08, -0.05, 0.02, -0.005]))
    O, I, groups = views(truth, seed=1)
    best, fits = choose_lens(O, I, SIZE, groups)
    assert best.camera.model == "fisheye"
    assert fits["plumb_bob"].held_out_rms_px > 1.5 * best.held_out_rms_px
    assert camera_difference_px(truth, best.camera, SIZE) < 0.5


@pytest.mark.parametrize("rational_whole_image_std_px, chosen", [(1.3e5, "plumb_bob"), (1.5, "rational")])
def test_a_model_the_views_leave_undetermined_over_the_image_is_not_chosen(monkeypatch, rational_whole_image_std_px,
                                                                          chosen):
    """Held-out views judge a model only where the boards were; rational held out 3 % better on every view but
    undetermined elsewhere (the realistic mock's seed 8: whole-image std 1.3e5 px, 144 px off the truth) is not
    chosen; determined as well as the others, its better held-out error chooses it."""
    from naocal.kinds.duckiebot import intrinsics

    views_ms = np.linspace(0.001, 0.002, 24)
    made = {"plumb_bob": (views_ms, 0.97), "rational": (views_ms * 0.94, rational_whole_image_std_px),
            "fisheye": (views_ms * 1.7, 1.46)}

    def fit_lens(O, I, size, model, groups, K_guess=None, floor=None):
        ms, whole = made[model]
        camera = LensCamera(model, np.eye(3), np.zeros(len(intrinsics.LENS_PARAMETERS[model])))
        return intrinsics.LensFit(camera, 0.03, float(np.sqrt(ms.mean())), len(ms), whole_image_std_px=whole,
                                  held_out_view_ms_px2=ms)

    monkeypatch.setattr(intrinsics, "fit_lens", fit_lens)
    best, fits = choose_lens([], [], SIZE, [0, 1])
    assert best.camera.model == chosen and set(fits) == set(made)


def test_refusals():
    O, I, _ = views(LensCamera.from_intrinsics(hidden_robot(1).camera), n=4)
    with pytest.raises(NaocalError, match="lens model"):
        fit_camera(O, I, SIZE, "orthographic")
    with pytest.raises(NaocalError, match="at least 3"):
        fit_camera(O[:2], I[:2], SIZE, "plumb_bob")
    with pytest.raises(NaocalError, match="two groups"):
        choose_lens(O, I, SIZE, [0, 0, 0, 0])


@pytest.mark.parametrize("model, distortion", [("plumb_bob", [-0.28, 0.06, 0.001, -0.002, 0.0]),
                                               ("rational", [-0.28, 0.06, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005]),
                                               ("fisheye", [0.08, -0.05, 0.02, -0.005])])
def test_the_lens_equations_jacobian_is_exact(model, distortion):
    camera = LensCamera(model, np.array([[330.0, 0, 318], [0, 328.0, 231], [0, 0, 1]]), np.array(distortion))
    O, I, _ = views(camera, n=4, noise_px=0.1, seed=2)
    start, rvecs, tvecs = opencv_start(O, I, SIZE, model, camera.K)
    equations = LensEquations(model, O, I, start, rvecs, tvecs)
    x = equations.start + np.random.default_rng(3).normal(0, 1e-3, len(equations.start)) * equations.scales
    r, J = equations.dense(x)
    assert J.shape == (r.size, len(parameter_names(model)) + 6 * len(O))
    numeric = central_differences(equations, x)
    assert np.max(np.abs(J - numeric) * equations.scales) < 1e-5 * np.max(np.abs(J) * equations.scales)
    normal = equations(x)  # the normal equations are those of the dense Jacobian, in scaled units
    Js = J * equations.scales
    assert np.allclose(normal.A, Js.T @ Js, rtol=1e-9, atol=1e-9 * np.abs(normal.A).max())
    assert np.allclose(normal.g, Js.T @ r, rtol=1e-9, atol=1e-9 * np.abs(normal.g).max())


def test_views_in_the_upper_part_only_still_give_the_whole_image_and_stds_that_cover_it():
    """The set-up's boards are seen only in the image's upper 40 % (docs/DUCKIEBOT.md): plumb_bob without k3 keeps
    the lower corners right (with k3 fitted, as before, 0.9 px off here), and the stds cover the errors."""
    truth = LensCamera.from_intrinsics(hidden_robot(1).camera)
    O, I, groups = views(truth, n=20, noise_px=0.04, seed=4, v_max_px=0.4 * SIZE[1])
    best, fits = choose_lens(O, I, SIZE, groups)
    assert best.camera.model == "plumb_bob"
    error = camera_difference_px(truth, best.camera, SIZE)
    assert error < 0.5
    assert error < 3 * best.whole_image_std_px
    z = (best.camera.parameters - truth.parameters[:len(best.names)]) / best.std
    assert np.all(np.abs(z) < 3), dict(zip(best.names, z))


# ------------------------------------------------------------------------------------------------ the floor markers

def mission_like(camera: LensCamera, T_base_camera, *, bias_px=-0.2, noise_px=0.04, seed=5, turn_step_rad=0.1,
                 marker_frames=40, yaw_sd_rad=0.3):
    """What the mission sees, synthetic: boards upright on a 0.6 m semicircle (centres 0.13 m up) seen while the
    robot turns in place at the origin (the image's upper part only), and floor markers (6.5 cm, 15 cm apart along
    -x, all alike) seen while it stands facing along them at several places, their corners moved along each
    marker's image diagonal by `bias_px` (the detector's inward bias: negative)."""
    rng = np.random.default_rng(seed)
    to_cv = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])

    def to_camera(points_world, pose):  # world (n, 3) -> OpenCV camera frame, robot at planar pose
        c, s = np.cos(pose[2]), np.sin(pose[2])
        R_wb = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        base = (points_world - [pose[0], pose[1], 0.0]) @ R_wb
        return (base - T_base_camera[:3, 3]) @ T_base_camera[:3, :3] @ to_cv.T

    obj = board_points((7, 5), 0.031)
    O, I = [], []
    for theta in np.arange(-1.3, 1.3, turn_step_rad):
        for a in (-0.9, 0.0, 0.9):
            # the board's frame: x along its rows (left to right seen from the front), y down, on its panel
            right = np.array([np.sin(a), -np.cos(a), 0.0])
            down = np.array([0.0, 0.0, -1.0])
            top_left = 0.6 * np.array([np.cos(a), np.sin(a), 0.0]) + [0, 0, 0.13] - 0.093 * right - 0.062 * down
            world = top_left + obj[:, :1] * right + obj[:, 1:2] * down
            cam = to_camera(world, (0.0, 0.0, theta))
            if cam[:, 2].min() < 0.1:
                continue
            uv = camera.project(cam, np.zeros(3), np.zeros(3))
            if (uv >= 5).all() and (uv <= [SIZE[0] - 6, SIZE[1] - 6]).all():
                O.append(obj)
                I.append(uv + rng.normal(0, noise_px, uv.shape))
    half = 0.0325
    offsets = np.array([[half, half], [half, -half], [-half, -half], [-half, half]])
    frame, marker, corner, uv_all = [], [], [], []
    for f, x in enumerate(np.linspace(-0.05, -0.9, marker_frames)):
        pose = (x, rng.normal(0, 0.01), np.pi + rng.normal(0, yaw_sd_rad))
        for m in range(8):
            world = np.column_stack([-0.3 - 0.15 * m + offsets[:, 0], offsets[:, 1], np.zeros(4)])
            cam = to_camera(np.vstack([world, [[-0.3 - 0.15 * m, 0.0, 0.0]]]), pose)
            if cam[:, 2].min() < 0.05:
                continue
            uv = camera.project(cam, np.zeros(3), np.zeros(3))
            corners, centre = uv[:4], uv[4]
            if not ((corners >= 5).all() and (corners <= [SIZE[0] - 6, SIZE[1] - 6]).all()):
                continue
            d = corners - centre
            corners = corners + bias_px * d / np.linalg.norm(d, axis=1)[:, None] + rng.normal(0, noise_px, (4, 2))
            frame += [f] * 4
            marker += [m] * 4
            corner += [0, 1, 2, 3]
            uv_all.append(corners)
    sightings = Sightings(np.array(frame), np.array(marker), np.array(corner), np.concatenate(uv_all),
                          np.full(len(frame), max(noise_px, 0.01)))
    groups = np.arange(len(O)) * 3 // len(O)
    return O, I, groups, sightings


@pytest.fixture(scope="module")
def floor_case():
    robot = hidden_robot(1)
    truth = LensCamera.from_intrinsics(robot.camera)
    O, I, groups, sightings = mission_like(truth, robot.T_base_camera)
    floor = FloorMarkers(sightings, 0.065, duckiebot("DB21").T_base_camera).usable()
    return truth, robot, O, I, groups, floor


def test_the_floor_markers_usable_are_large_seen_twice_and_on_one_floor():
    s = Sightings(np.repeat([0, 0, 1, 1, 4, 2, 3], 4), np.repeat([5, 6, 5, 7, 5, 8, 8], 4), np.tile(np.arange(4), 7),
                  np.tile([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]], (7, 1)), np.full(28, 0.15))
    small = s.uv_px.copy()
    small[4:8] *= 0.5  # frame 0's marker 6: a 20 px side
    usable = FloorMarkers(Sightings(s.frame, s.marker, s.corner, small, s.noise_px), 0.065, np.eye(4)).usable()
    # marker 6 too small, marker 7 seen once, markers 8 (frames 2, 3) tied to nothing of marker 5's floor: a
    # smaller group
    kept = set(zip(usable.sightings.frame.tolist(), usable.sightings.marker.tolist()))
    assert sorted(kept) == [(0, 5), (1, 5), (4, 5)]


def test_the_lens_equations_jacobian_with_floor_markers_is_exact(floor_case):
    truth, _, O, I, _, floor = floor_case
    start, rvecs, tvecs = opencv_start(O[:5], I[:5], SIZE, "plumb_bob", truth.K)
    equations = LensEquations("plumb_bob", O[:5], I[:5], start, rvecs, tvecs, floor)
    x = equations.start + np.random.default_rng(3).normal(0, 1e-2, len(equations.start)) * equations.scales
    x[equations.names.index(FLOOR_BIAS)] = -0.3
    r, J = equations.dense(x)
    numeric = central_differences(equations, x)
    assert np.max(np.abs(J - numeric) * equations.scales) < 1e-5 * np.max(np.abs(J) * equations.scales)
    normal = equations(x)
    Js = J * equations.scales
    assert np.allclose(normal.A, Js.T @ Js, rtol=1e-9, atol=1e-9 * np.abs(normal.A).max())
    assert np.allclose(normal.g, Js.T @ r, rtol=1e-9, atol=1e-9 * np.abs(normal.g).max())
    assert normal.image_scores.shape[0] == 5 + len(np.unique(floor.sightings.frame))  # a cluster per view, frame


def test_floor_markers_fix_the_lower_half_the_boards_leave_open(floor_case):
    """Boards seen from one spot fall in the image's upper part; the floor markers (with the detector's inward bias
    fitted) bring the whole image within a fraction of the boards-only error, and the stds cover it."""
    truth, robot, O, I, groups, floor = floor_case
    assert max(v[:, 1].max() for v in I) < 0.45 * SIZE[1] and floor.sightings.uv_px[:, 1].min() > 0.45 * SIZE[1]
    boards, _ = choose_lens(O, I, SIZE, groups, models=("plumb_bob",))
    both, _ = choose_lens(O, I, SIZE, groups, models=("plumb_bob",), floor=floor)
    error_boards = camera_difference_px(truth, boards.camera, SIZE)
    error = camera_difference_px(truth, both.camera, SIZE)
    assert error < 0.5 * error_boards and error < 0.1, (error, error_boards)
    assert error < 3 * both.whole_image_std_px
    z = (both.camera.parameters - truth.parameters[:len(both.names)]) / both.std
    assert np.all(np.abs(z) < 3), dict(zip(both.names, z))


def test_a_mis_detected_floor_marker_is_set_aside(floor_case):
    """One floor sighting mis-detected (two corners pushed apart along its diagonal, 4.2 px each; realistic mock
    seed 8: two sightings 5.4 and 15 times their expected noise left the lens 1.9 px off over the whole image, 0.17
    without them) is set aside by the outlier rule of every kind: the lens is the one fitted without it (1.96 px
    from it if kept)."""
    truth, _, O, I, _, floor = floor_case
    s = floor.sightings
    rows = np.flatnonzero((s.frame == s.frame[0]) & (s.marker == s.marker[0]))
    without = FloorMarkers(s.subset(np.setdiff1d(np.arange(len(s.frame)), rows)), floor.size_m,
                           floor.T_base_camera_start).usable()
    clean, _ = fit_camera(O, I, SIZE, "plumb_bob", truth.K, floor=without)
    uv = s.uv_px.copy()
    uv[rows[[0, 2]]] += [[-3.0, -3.0], [3.0, 3.0]]
    bad = FloorMarkers(Sightings(s.frame, s.marker, s.corner, uv, s.noise_px), floor.size_m,
                       floor.T_base_camera_start)
    camera, _ = fit_camera(O, I, SIZE, "plumb_bob", truth.K, floor=bad)
    assert camera_difference_px(clean, camera, SIZE) < 0.01, camera_difference_px(clean, camera, SIZE)
