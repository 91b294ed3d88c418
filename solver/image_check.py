"""Whole images set aside before anything is fitted: an image whose corners no view of its flat board explains.

A detector can hand over a whole mis-detected board (a wrong lattice, a reflection, corners collapsed onto a line).
Single bad corners are the fit's to set aside (solver.fit trims them); a whole bad image drags every parameter
(a damaged image moved RKneePitch by 11 deg: benchmarks/fuzz_inputs.py) before the corner trimming can see it.
Any view of a flat board by a pinhole camera is a homography of the board's plane, so, image by image, with the
pixels undistorted by the data's own intrinsics:
- the corners must not be collapsed or collinear where the board's are not (the pixels span a plane);
- the homography must keep the board's handedness: the camera sees the printed face (+z of the board frame), so
  the board's x, y axes turn the other way in the image (v points down); a mirrored or folded map is no view;
- at least two thirds of its corners must lie within a few px of the best homography (least squares, or, when
  some corners do not fit, the least-median one, which ignores up to half of them): the threshold is
  HOMOGRAPHY_SCALES robust scales of all images' homography residuals, never below HOMOGRAPHY_MIN_PX.
A failing image is set aside whole and reported (image id, reason, homography RMS) by identify, diagnose,
verify and the agent: this module is the one place that decides it (called by solver.fit.set_aside_mis_detections,
the one rule for every mis-detection, which identify, diagnose, verify and the agent's verification share).
Images of fewer than 4 corners, or whose corners lie on one line of the board, cannot be checked and are kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from naocal.solver.errors import SolveError

# Threshold on a corner's distance from its image's homography: HOMOGRAPHY_SCALES x the robust (median) scale of all
# images' homography residuals, per coordinate, at least HOMOGRAPHY_MIN_PX. The floor is measured, not guessed: the
# largest distance of a corner from its image's homography in clean data is 0.89 px (synthetic, 0.25 px noise),
# 0.37 px (partial boards), 0.33 px (the six real MRL-SPL images, 320 x 240, lens distortion not modelled; image RMS
# at most 0.125 px); robust scales 0.04-0.23 px; a detector's mis-detections are a square (25-60 px) or 3-20 px off
# (the realistic mock's). docs/DIAGNOSTICS.md, "Mis-detections".
HOMOGRAPHY_SCALES = 5.0
HOMOGRAPHY_MIN_PX = 3.0
# An image keeps its place while at most this share of its corners are off its board (or were set aside by the
# fit's corner trimming, solver.fit): beyond it the image is set aside whole.
MAX_LOST_FRACTION = 1.0 / 3.0
# Corners whose undistorted pixels spread less than this across their principal direction lie on a line (or a
# point): no view of a board whose corners span a plane.
MIN_SPREAD_PX = 0.5
# A board's corners whose coordinates spread less than this (m) across their principal direction lie on one line
# of the board: the image cannot be checked (a partial board showing one row).
MIN_BOARD_SPREAD_M = 1e-3
# The board's corners lie on its plane z = 0 (the target description) within this (m); otherwise no homography.
MAX_OFF_PLANE_M = 1e-3
MIN_CORNERS = 4
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))


@dataclass
class SetAsideImage:
    image: int  # the dataset's image id
    reason: str  # why, in words (one phrase)
    rms_px: float  # RMS (both coordinates) of its corners about its board's best homography (nan: none fits)
    n_corners: int
    fit_rms_px: float = float("nan")  # RMS of all its corners at the fit that set it aside (nan: before any fit)

    def describe(self) -> str:
        rms = f"homography RMS {self.rms_px:.1f} px" if np.isfinite(self.rms_px) else "no homography"
        fit = f", fit RMS {self.fit_rms_px:.1f} px" if np.isfinite(self.fit_rms_px) else ""
        return f"image {self.image} ({self.reason}; {rms}{fit})"

    def as_dict(self) -> dict:
        finite = lambda x: float(x) if np.isfinite(x) else None  # noqa: E731
        return {"image": self.image, "reason": self.reason, "homography_rms_px": finite(self.rms_px),
                "fit_rms_px": finite(self.fit_rms_px), "n_corners": self.n_corners}


@dataclass
class ImageCheck:
    """What check_images found: the images kept, those set aside, and the threshold used."""

    kept: np.ndarray  # (K,) indices 0..M-1 of the images kept
    set_aside: list = field(default_factory=list)  # [SetAsideImage]
    scale_px: float = float("nan")  # robust scale of the homography residual components
    threshold_px: float = HOMOGRAPHY_MIN_PX
    rms_px: dict = field(default_factory=dict)  # image id -> homography RMS, for every image checked


def check_images(data) -> ImageCheck:
    """Check each image of `data` (solver.model.ModelData) against the view of a flat board; see the module.
    Vectorised over the images of each corner count (3456 corners: a few ms)."""
    from naocal.solver.camera import undistort_points

    M = data.n_images
    uv = np.empty_like(data.uv_px, dtype=float)
    for name in np.unique(data.camera):  # pixels as a pinhole camera would see them
        rows = data.camera[data.image_of_row] == name
        uv[rows] = undistort_points(data.uv_px[rows], data.cameras[name])
    board = _board_coordinates(data)
    order = np.argsort(data.image_of_row, kind="stable")
    counts = np.bincount(data.image_of_row, minlength=M)
    starts = np.concatenate([[0], np.cumsum(counts)])

    groups = []  # per corner count n: images (B,), rows (B, n), on a line (B,), distances (B, n), H (B, 3, 3)
    for n in np.unique(counts[counts >= MIN_CORNERS]):
        images = np.flatnonzero(counts == n)
        idx = order[starts[images][:, None] + np.arange(n)]
        checkable = np.all(np.isfinite(board[idx]), axis=(1, 2))  # off the board's plane: not checked
        checkable[checkable] = _spread(board[idx[checkable]])[:, 1] >= MIN_BOARD_SPREAD_M  # one line of the board
        images, idx = images[checkable], idx[checkable]
        if len(images):
            on_a_line = _spread(uv[idx])[:, 1] < MIN_SPREAD_PX  # (still fitted, for its RMS)
            H = fit_homographies(board[idx], uv[idx])
            distance = np.linalg.norm(apply_homographies(H, board[idx]) - uv[idx], axis=-1)
            groups.append((images, idx, on_a_line, distance, H))

    fitting = [d[~line].ravel() for _, _, line, d, _ in groups]
    fitting = np.concatenate(fitting) if fitting else np.zeros(0)
    # a corner's distance |r| under 2-D Gaussian noise of sigma per coordinate: median sqrt(2 ln 2) sigma
    scale = float(np.median(fitting)) / RAYLEIGH_MEDIAN if len(fitting) else float("nan")
    threshold = max(HOMOGRAPHY_SCALES * scale, HOMOGRAPHY_MIN_PX) if np.isfinite(scale) else HOMOGRAPHY_MIN_PX
    reasons, rms = {}, {}
    for images, idx, on_a_line, distance, H in groups:
        n = idx.shape[1]
        for k in np.flatnonzero(~on_a_line & ~np.all(distance <= threshold, axis=1)):  # the best homography of
            H[k], distance[k] = _robust_homography(board[idx[k]], uv[idx[k]], H[k], distance[k], threshold)
        image_rms = np.sqrt(np.mean(distance ** 2, axis=1) / 2.0)
        off = np.sum(~(distance <= threshold), axis=1)  # (a corner mapped to infinity is off)
        orientation = _orientation_problems(H, board[idx])
        for k, m in enumerate(images.tolist()):
            rms[m] = float(image_rms[k])
            if on_a_line[k]:
                reasons[m] = "its corners lie on a line or a point, its board's do not"
            elif off[k] > MAX_LOST_FRACTION * n:
                reasons[m] = (f"no flat board fits it: {off[k]} of {n} corners beyond {threshold:.1f} px of the best "
                              "homography")
            elif orientation[k]:
                reasons[m] = orientation[k]
    set_aside = [SetAsideImage(int(data.image_id[m]), reasons[m], rms.get(m, float("nan")), int(counts[m]))
                 for m in sorted(reasons)]
    kept = np.flatnonzero(~np.isin(np.arange(M), list(reasons)))
    return ImageCheck(kept, set_aside, scale, threshold, {int(data.image_id[m]): r for m, r in rms.items()})


def describe_set_aside(images, count: int = 8) -> str:
    """One line naming whole images set aside (solver.image_check.SetAsideImage), '' when there are none."""
    if not images:
        return ""
    listed = "; ".join(s.describe() for s in images[:count])
    return (f"images set aside whole as mis-detected boards: {len(images)}: {listed}"
            + (" ..." if len(images) > count else ""))


def without_images(data, image_ids, check: ImageCheck | None = None):
    """`data` less the images of the dataset ids `image_ids` (SolveError when none would be left)."""
    if not image_ids:
        return data
    keep = np.flatnonzero(~np.isin(data.image_id, list(image_ids)))
    if not len(keep):
        why = f" ({describe_set_aside(check.set_aside, count=2)})" if check and check.set_aside else ""
        raise SolveError(f"every one of the {data.n_images} images was set aside, nothing to fit{why}; nothing written")
    return data.subset(keep)


def lost_too_many(n_corners, n_lost) -> np.ndarray:
    """Per image: has it lost more than MAX_LOST_FRACTION of its corners (to the corner trimming)?"""
    return np.asarray(n_lost) > MAX_LOST_FRACTION * np.asarray(n_corners)


def _board_coordinates(data) -> np.ndarray:
    """(N, 2) each corner's position on its board's plane (the board frame's x, y), m; nan off the plane."""
    out = np.full((data.n_rows, 2), np.nan)
    target_of_row = data.target[data.image_of_row]
    for name in np.unique(target_of_row):
        rows = target_of_row == name
        T = data.robot.target(name).T_frame_board
        p_board = (data.p_mount[rows] - T[:3, 3]) @ T[:3, :3]
        on_plane = np.abs(p_board[:, 2]) <= MAX_OFF_PLANE_M
        out[np.flatnonzero(rows)[on_plane]] = p_board[on_plane, :2]
    return out


def _spread(points) -> np.ndarray:
    """(B, 2) the RMS spread of each set of points (B, n, 2) along its two principal directions, largest first."""
    centred = points - points.mean(axis=-2, keepdims=True)
    return np.linalg.svd(centred, compute_uv=False) / np.sqrt(points.shape[-2])


def _normaliser(points):
    """(..., 3, 3) similarity moving points (..., n, 2) to their centroid, mean distance sqrt(2) (Hartley)."""
    centre = points.mean(axis=-2)
    spread = np.mean(np.linalg.norm(points - centre[..., None, :], axis=-1), axis=-1)
    s = np.sqrt(2.0) / np.maximum(spread, 1e-300)
    T = np.zeros(points.shape[:-2] + (3, 3))
    T[..., 0, 0] = T[..., 1, 1] = s
    T[..., :2, 2] = -s[..., None] * centre
    T[..., 2, 2] = 1.0
    return T


def fit_homographies(src, dst) -> np.ndarray:
    """(B, 3, 3) least-squares homographies (normalised DLT) of src (B, n, 2) onto dst (B, n, 2), n >= 4."""
    Ts, Td = _normaliser(src), _normaliser(dst)
    a = apply_homographies(Ts, src)
    b = apply_homographies(Td, dst)
    B, n = src.shape[:2]
    A = np.zeros((B, 2 * n, 9))
    one = np.ones((B, n))
    zero = np.zeros((B, n, 3))
    xy1 = np.concatenate([a, one[..., None]], axis=-1)
    A[:, 0::2, 0:3] = xy1
    A[:, 0::2, 3:6] = zero
    A[:, 0::2, 6:9] = -b[..., 0:1] * xy1
    A[:, 1::2, 3:6] = xy1
    A[:, 1::2, 6:9] = -b[..., 1:2] * xy1
    # the right singular vector of A's smallest singular value, as the eigenvector of A^T A (9 x 9: batched eigh is
    # ~10x faster than the SVD of A; the normalisation keeps A^T A well conditioned)
    Hn = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)[1][:, :, 0].reshape(B, 3, 3)
    return np.linalg.inv(Td) @ Hn @ Ts


def apply_homographies(H, points) -> np.ndarray:
    """(..., n, 2) points (..., n, 2) mapped by H (..., 3, 3)."""
    p = points @ np.swapaxes(H[..., :, :2], -1, -2) + H[..., None, :, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[..., :2] / p[..., 2:3]


def _robust_homography(src, dst, H, distance, threshold):
    """The homography of the corners within `threshold` of the least-squares one, refitted; when that still leaves
    more than MAX_LOST_FRACTION off, the least-median-of-squares one refitted to its corners within `threshold`, if
    its median distance is smaller than least squares'."""
    near = distance <= threshold
    if near.sum() >= MIN_CORNERS:
        refit = fit_homographies(src[near][None], dst[near][None])[0]
        again = np.linalg.norm(apply_homographies(refit, src) - dst, axis=-1)
        if np.sum(~(again <= threshold)) <= MAX_LOST_FRACTION * len(src):
            return refit, again
    found, robust = least_median_homography(src, dst)
    near = robust <= threshold
    if near.sum() >= MIN_CORNERS:
        found = fit_homographies(src[near][None], dst[near][None])[0]
        robust = np.linalg.norm(apply_homographies(found, src) - dst, axis=-1)
    robust = np.where(np.isfinite(robust), robust, np.inf)
    if np.median(robust) >= np.median(np.where(np.isfinite(distance), distance, np.inf)):
        return H, distance
    return found, robust


def least_median_homography(src, dst, samples: int = 200, seed: int = 0):
    """(H (3, 3), distances (n,)): of `samples` homographies through 4 random corners (seeded: the same answer
    every run), the one whose median corner distance is least (Rousseeuw's LMedS, as OpenCV's findHomography with
    LMEDS): right while fewer than half the corners are off; 200 samples miss a clean one with p < 3e-6 then."""
    rng = np.random.default_rng(seed)
    n = len(src)
    picks = np.argsort(rng.random((samples, n)), axis=1)[:, :MIN_CORNERS]
    H = fit_homographies(src[picks], dst[picks])
    d = np.linalg.norm(apply_homographies(H, np.broadcast_to(src, (samples, n, 2))) - dst, axis=-1)
    d = np.where(np.isfinite(d), d, np.inf)
    best = int(np.argmin(np.median(d, axis=1)))
    return H[best], d[best]


def _orientation_problems(H, board) -> list:
    """Per image, why H (B, 3, 3) is no view of the printed face of its board points (B, n, 2), or None. The map
    (x, y) -> (u, v) has Jacobian determinant det(H) / w^3 (w the third homogeneous coordinate): w must keep one
    sign over the board (else the horizon crosses it: folded), and seen from the printed face (+z) with v pointing
    down the determinant is negative."""
    finite = np.all(np.isfinite(H), axis=(1, 2))
    Hf = np.where(finite[:, None, None], H, np.eye(3))
    w = np.einsum("bnk,bk->bn", board, Hf[:, 2, :2]) + Hf[:, 2, 2:3]
    folded = ~(np.all(w > 0, axis=1) | np.all(w < 0, axis=1))
    mirrored = np.linalg.det(Hf) * np.sign(w[:, 0]) >= 0
    return [None if ok and not f and not mi else
            "its corners fit no homography" if not ok else
            "its corners fold the board over (no view of a flat board)" if f else
            "its corners are mirrored (the board's handedness reversed: a wrong lattice order, or a reflection)"
            for ok, f, mi in zip(finite, folded, mirrored)]
