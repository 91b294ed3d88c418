"""The camera's intrinsics with the lens model chosen by held-out reprojection error
(kinds/duckiebot/intrinsics.py, issue 23)."""

import cv2
import numpy as np
import pytest

from naocal.kinds.duckiebot.intrinsics import LensCamera, board_points, camera_difference_px, choose_lens, fit_camera
from naocal.kinds.duckiebot.render import hidden_robot
from naocal.solver.errors import NaocalError

SIZE = (640, 480)


def views(camera: LensCamera, n=18, noise_px=0.05, seed=0):
    """Board views spread over the image at several distances and tilts, projected by `camera`."""
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
        if not ((uv >= 5).all() and (uv[:, 0] <= SIZE[0] - 6).all() and (uv[:, 1] <= SIZE[1] - 6).all()):
            continue
        O.append(obj)
        I.append(uv + rng.normal(0, noise_px, uv.shape))
        groups.append(len(O) % 4)
    return O, I, groups


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


def test_refusals():
    O, I, _ = views(LensCamera.from_intrinsics(hidden_robot(1).camera), n=4)
    with pytest.raises(NaocalError, match="lens model"):
        fit_camera(O, I, SIZE, "orthographic")
    with pytest.raises(NaocalError, match="at least 3"):
        fit_camera(O[:2], I[:2], SIZE, "plumb_bob")
    with pytest.raises(NaocalError, match="two groups"):
        choose_lens(O, I, SIZE, [0, 0, 0, 0])
