"""The camera's intrinsics from chessboard views, the lens model chosen by held-out reprojection error.

Lens models: `plumb_bob` (OpenCV's k1, k2, p1, p2, k3: what Duckietown's files hold), `rational` (k1..k6, p1, p2:
CALIB_RATIONAL_MODEL), `fisheye` (Kannala-Brandt k1..k4: cv2.fisheye). A low training reprojection error proves
nothing (the reference: 0.07-0.09 px while the camera is 5-12 px wrong over the whole image), so each model is
judged on views it was not fitted to: views are split into groups (e.g. one per board), each group is held out in
turn, the camera fitted to the others, and each held-out view's pose found by PnP with that camera; the model with
the smallest held-out RMS wins. `camera_difference_px` compares two cameras over the whole image.

First step: OpenCV's calibrateCamera / fisheye.calibrate, not naocal's own LM (solver/fit.py, solver/identify.py):
that path identifies a robot description's joint chains from a naocal dataset, and a free-standing board seen by a
camera on no chain is not expressible there until issue 22's core takes measurement kinds of any robot kind. The
joint fit of the next layer (camera pose, wheels, markers) belongs on that core.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from naocal.solver.errors import NaocalError

LENS_MODELS = ("plumb_bob", "rational", "fisheye")
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)


@dataclass(frozen=True)
class LensCamera:
    """A fitted camera: lens model, K (3, 3), distortion coefficients in OpenCV's order for the model."""

    model: str
    K: np.ndarray
    distortion: np.ndarray

    @classmethod
    def from_intrinsics(cls, camera) -> "LensCamera":
        """A naocal camera (solver.camera.CameraIntrinsics: OpenCV's pixel convention and plumb_bob)."""
        K = np.array([[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]])
        return cls("plumb_bob", K, np.asarray(camera.distortion, dtype=float))

    def project(self, object_points, rvec, tvec) -> np.ndarray:
        """(n, 2) pixels of board points (n, 3) at pose (rvec, tvec) (OpenCV's camera frame)."""
        obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
        if self.model == "fisheye":
            uv, _ = cv2.fisheye.projectPoints(obj, rvec, tvec, self.K, self.distortion)
        else:
            uv, _ = cv2.projectPoints(obj, rvec, tvec, self.K, self.distortion)
        return uv.reshape(-1, 2)

    def normalised(self, uv_px) -> np.ndarray:
        """(n, 2) undistorted normalised coordinates (x right, y down) of pixels."""
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
        if self.model == "fisheye":
            out = cv2.fisheye.undistortPoints(uv, self.K, self.distortion)
        else:
            out = cv2.undistortPoints(uv, self.K, self.distortion, None, None, criteria=_CRITERIA)
        return out.reshape(-1, 2)

    def pose(self, object_points, image_points):
        """(rvec, tvec) of a board view with this camera (PnP on undistorted points)."""
        ok, rvec, tvec = cv2.solvePnP(np.asarray(object_points, np.float64), self.normalised(image_points),
                                      np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise NaocalError("a board view's pose cannot be found")
        return rvec, tvec


@dataclass(frozen=True)
class LensFit:
    camera: LensCamera
    train_rms_px: float  # all views, fitted to all
    held_out_rms_px: float  # each group held out in turn
    n_views: int


def board_points(inner_corners: tuple[int, int], square_m: float) -> np.ndarray:
    """(rows * columns, 3) inner corners of a board in its plane, in image order (row-major, rows of columns)."""
    columns, rows = inner_corners
    r, c = np.mgrid[0:rows, 0:columns]
    return np.column_stack([c.ravel() * square_m, r.ravel() * square_m, np.zeros(r.size)])


def fit_camera(object_points, image_points, size, model: str, K_guess=None) -> tuple[LensCamera, float]:
    """(camera, training RMS px) of one lens model fitted to views (lists of (n, 3) and (n, 2)); `size` (w, h)."""
    if model not in LENS_MODELS:
        raise NaocalError(f"unknown lens model {model!r}: expected one of {', '.join(LENS_MODELS)}")
    if len(object_points) < 3:
        raise NaocalError(f"{len(object_points)} board views: at least 3 are needed to fit a camera")
    w, h = size
    K0 = np.array(K_guess if K_guess is not None else [[w / 2, 0, w / 2], [0, w / 2, h / 2], [0, 0, 1]], float)
    if model == "fisheye":
        obj = [np.asarray(o, np.float64).reshape(1, -1, 3) for o in object_points]  # (n, 1, 3): refused in 5.0
        img = [np.asarray(i, np.float64).reshape(1, -1, 2) for i in image_points]
        # OpenCV 5 keeps the fisheye flags in cv2 itself (4.x: cv2.fisheye.CALIB_*)
        flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS
        rms, K, D, _, _ = cv2.fisheye.calibrate(obj, img, (w, h), K0.copy(), np.zeros(4), flags=flags,
                                                criteria=_CRITERIA)
    else:
        obj = [np.asarray(o, np.float32) for o in object_points]
        img = [np.asarray(i, np.float32) for i in image_points]
        flags = cv2.CALIB_USE_INTRINSIC_GUESS | (cv2.CALIB_RATIONAL_MODEL if model == "rational" else 0)
        rms, K, D, _, _ = cv2.calibrateCamera(obj, img, (w, h), K0.copy(), None, flags=flags, criteria=_CRITERIA)
    return LensCamera(model, K, np.asarray(D, float).ravel()), float(rms)


def view_rms_px(camera: LensCamera, object_points, image_points) -> float:
    """RMS (over both coordinates) of one view's corners about their projection at the view's PnP pose."""
    rvec, tvec = camera.pose(object_points, image_points)
    residual = camera.project(object_points, rvec, tvec) - np.asarray(image_points, float)
    return float(np.sqrt(np.mean(residual ** 2)))


def fit_lens(object_points, image_points, size, model: str, groups, K_guess=None) -> LensFit:
    """One lens model: fitted to all views, and held out group by group (`groups`: a label per view, at least
    two different ones)."""
    groups = np.asarray(groups)
    labels = np.unique(groups)
    if len(labels) < 2:
        raise NaocalError("held-out errors need the views in at least two groups")
    camera, train = fit_camera(object_points, image_points, size, model, K_guess)
    squares = []
    for label in labels:
        train_idx, test_idx = np.flatnonzero(groups != label), np.flatnonzero(groups == label)
        try:
            held, _ = fit_camera([object_points[i] for i in train_idx], [image_points[i] for i in train_idx], size,
                                 model, K_guess)
            squares += [view_rms_px(held, object_points[i], image_points[i]) ** 2 for i in test_idx]
        except (cv2.error, NaocalError):  # too few views left, or the fit diverged: the model cannot be judged
            squares += [np.inf] * len(test_idx)
    return LensFit(camera, train, float(np.sqrt(np.mean(squares))), len(object_points))


def choose_lens(object_points, image_points, size, groups, models=LENS_MODELS, K_guess=None):
    """(best LensFit, {model: LensFit}): the lens model of the smallest held-out RMS (a tie goes to the model
    listed first: the simpler)."""
    fits = {}
    for model in models:
        try:
            fits[model] = fit_lens(object_points, image_points, size, model, groups, K_guess)
        except cv2.error:
            continue  # OpenCV refused this model on these views (e.g. fisheye's ill-conditioned check)
    if not fits:
        raise NaocalError("no lens model could be fitted to the board views")
    return min(fits.values(), key=lambda f: f.held_out_rms_px), fits


def camera_difference_px(a: LensCamera, b: LensCamera, size, step_px: float = 8.0) -> float:
    """RMS pixel distance over the whole image between where two cameras see the same rays: a grid of a's pixels,
    their rays by a, projected by b."""
    w, h = size
    u, v = np.meshgrid(np.arange(0.0, w, step_px), np.arange(0.0, h, step_px))
    uv = np.column_stack([u.ravel(), v.ravel()])
    rays = np.column_stack([a.normalised(uv), np.ones(len(uv))])
    back = b.project(rays, np.zeros(3), np.zeros(3))
    return float(np.sqrt(np.mean(np.sum((back - uv) ** 2, axis=1))))
