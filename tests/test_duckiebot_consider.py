"""The Duckiebot joint fit's considered nuisances (kinds/duckiebot/identify.py: considered_effect, add_considered,
add_corner_covariance; issue 23, "stds cover the errors"): the detector's corner error over its window's size is an
error shared by a whole log, which no cluster-robust std sees; it is carried into the stds, not fitted."""

from dataclasses import replace

import numpy as np
import pytest

from naocal.kinds.duckiebot.detect import MarkerSighting, refinement_window_px
from naocal.kinds.duckiebot.fit import CORNER_WINDOW, STATISTICAL, fit_drive
from naocal.kinds.duckiebot.identify import (CORNER_WINDOW_STD_PX2, Detections, add_corner_covariance,
                                             corner_window_shifts, rectified_sightings)
from naocal.kinds.duckiebot.intrinsics import LensCamera
from naocal.kinds.duckiebot.robot import camera_mount
from test_duckiebot_fit import Z_LIMIT, synthetic, truth_of

MARKER_M = 0.065
# the window-dependent part of the detector's corner error at the mock's blur and noise (px^2 over the window's
# half-width, outward +: benchmarks/bench_duckiebot_corners.py, fitted as b0 + c / w; identify.CORNER_WINDOW_STD_PX2)
MOCK_C_PX2 = -1.41


def detections_of(sightings, c_px2: float = 0.0) -> Detections:
    """The synthetic corners as the detector's output (a pinhole: raw pixels are rectified ones), each marker's
    corners moved outward along its diagonal by c_px2 / w, w the cornerSubPix window half-width the detector
    refines it in (detect.refinement_window_px): the size-dependent corner error, hidden."""
    frames = [[] for _ in range(int(sightings.frame.max()) + 1)]
    for f, m in sorted(set(zip(sightings.frame.tolist(), sightings.marker.tolist()))):
        rows = np.flatnonzero((sightings.frame == f) & (sightings.marker == m))
        quad = sightings.uv_px[rows[np.argsort(sightings.corner[rows])]]
        out = quad - quad.mean(axis=0)
        out /= np.linalg.norm(out, axis=1)[:, None]
        frames[f].append(MarkerSighting(m, quad + c_px2 * out / refinement_window_px(quad)))
    return Detections(frames, [[] for _ in frames])


def fitted(seed: int, c_px2: float):
    """(robot, drive, detections, pinhole camera, the joint fit) of synthetic log `seed` with a hidden corner error
    c_px2 / w."""
    robot, drive, sightings, K = synthetic(seed, noise_px=0.1)
    detections = detections_of(sightings, c_px2)
    camera = LensCamera("plumb_bob", K, np.zeros(5))
    fit = fit_drive(drive, rectified_sightings(detections, camera), K, MARKER_M, camera_mount())
    return robot, drive, detections, camera, fit


def test_the_considered_covariance_is_a_refits_response_to_the_corner_error():
    """S sigma^2 S^T added equals the outer product of an actual refit's move with every corner moved by sigma / w
    along its diagonal (its expected noise kept)."""
    _, drive, detections, camera, fit = fitted(1, 0.0)
    before, x0 = fit.covariance.copy(), fit.x.copy()
    add_corner_covariance(fit, drive, detections, camera, MARKER_M)
    added = fit.covariance - before
    corners = rectified_sightings(detections, camera)  # a pinhole: moved in raw pixels is moved rectified
    moved = replace(corners, uv_px=corners.uv_px + CORNER_WINDOW_STD_PX2 * corner_window_shifts(detections))
    refit = fit_drive(drive, moved, camera.K, MARKER_M, camera_mount(), start=dict(zip(fit.names, x0)))
    response = refit.x - x0
    assert np.abs(response).max() > 0
    # first order (one Gauss-Newton step) against the full refit: within 4 % per parameter (measured 3.6 %)
    np.testing.assert_allclose(added, np.outer(response, response), rtol=0.05,
                               atol=0.05 * np.abs(np.outer(response, response)).max())
    np.testing.assert_allclose(fit.considered[CORNER_WINDOW], np.abs(response), rtol=0.05, atol=1e-12)
    np.testing.assert_allclose(fit.x, x0)  # only the stds move
    parts = fit.std_parts()
    np.testing.assert_allclose(parts[STATISTICAL] ** 2 + parts[CORNER_WINDOW] ** 2, fit.std ** 2)


@pytest.mark.parametrize("seed", [1, 7])
def test_with_a_hidden_size_dependent_corner_error_the_considered_stds_cover_the_truth(seed):
    """The mock's corner error (MOCK_C_PX2 / w) hidden in synthetic corners: the cluster-robust stds leave the camera's
    height beyond Z_LIMIT stds; with the error considered every parameter is within them."""
    robot, drive, detections, camera, fit = fitted(seed, MOCK_C_PX2)
    truth = truth_of(robot)
    z_without = {n: (fit.value(n) - v) / fit.stdev(n) for n, v in truth.items()}
    assert abs(z_without["camera.z_m"]) > Z_LIMIT, z_without
    add_corner_covariance(fit, drive, detections, camera, MARKER_M)
    z = {n: (fit.value(n) - v) / fit.stdev(n) for n, v in truth.items()}
    assert max(abs(v) for v in z.values()) < Z_LIMIT, z
    assert fit.stdev("trim") < 0.0005  # the trim's std does not balloon


def test_a_refined_trim_drops_the_calibrations_std_parts_and_the_file_still_reads(tmp_path):
    """A refinement's trim std is the lane pass's own (no parts): the refined file must not keep the calibration's
    parts beside it (the reader refuses parts that do not make up the std)."""
    from types import SimpleNamespace

    from naocal.kinds.duckiebot.calibration import check_document, checked_document
    from naocal.kinds.duckiebot.fit import CAMERA, KINEMATIC, LENS, DriveFit, Sightings, pose_parameters
    from naocal.kinds.duckiebot.identify import DuckiebotCalibration
    from naocal.kinds.duckiebot.intrinsics import LensFit
    from naocal.kinds.duckiebot.refine import refined_document
    from naocal.kinds.duckiebot.render import hidden_robot

    robot = hidden_robot(3)
    kin = robot.kinematics
    none = Sightings(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))
    values = np.r_[kin.gain, kin.trim, kin.baseline_m, pose_parameters(robot.T_base_camera)]
    fit = DriveFit(list(KINEMATIC + CAMERA), values, np.full(9, 13e-4), np.full(9, 3e-4), np.ones(9, bool), 0,
                   np.zeros((0, 2)), none, none, 0.1, True, "", 1, 1.0, [], 0.0,
                   considered={LENS: np.full(9, 3e-4), CORNER_WINDOW: np.full(9, 4e-4)})
    lens = LensFit(LensCamera.from_intrinsics(robot.camera), 0.0, 0.0, 1)
    doc, read = checked_document(DuckiebotCalibration("rendered", kin, lens, {"plumb_bob": lens}, fit),
                                 tmp_path / "cal.json")
    assert read.parameters["trim"]["std_parts"] == pytest.approx({STATISTICAL: 12e-4, LENS: 3e-4,
                                                                  CORNER_WINDOW: 4e-4})
    refinement = SimpleNamespace(trim=kin.trim + 0.01, trim_std=2e-4, gain_refined=False, kinematics=kin)
    refined = check_document(refined_document(doc, refinement, "a lane pass"), tmp_path / "new.json")
    assert refined.std("trim") == 2e-4 and "std_parts" not in refined.parameters["trim"]
    assert refined.parameters["gain"]["std_parts"] == read.parameters["gain"]["std_parts"]  # not refined: kept
