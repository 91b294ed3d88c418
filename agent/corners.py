"""Finding the 24 inner vertices of a sandal's 7 x 5 checkerboard in a camera image (OpenCV).

`detect_board_vertices` returns the vertices in naocal's vertex order (solver.nao_model.board_vertices_sole: index
= row * 6 + col, col along +x of the sole frame, row along +y) or a failure with its reason - never a guess:

- `missing`: no board near the predicted position, or a vertex partly hidden (something covers part of its
  neighbourhood, see `corner_asymmetry`), or a board whose black and white squares are off by one;
- `cut_off`: a vertex lies outside the image or within `border_margin_px` of its edge (its refinement window
  would be clipped), or the predicted board reaches out of the image and none was found;
- `blurred`: the board's edges are wider than `max_edge_width_px` (motion blur, focus): `edge_width_px`;
- `ambiguous`: the vertex order or the board's placement cannot be told.

On the sandal the foot covers most of the first column of squares (the toe ends 7.5 mm before the first vertex
column), so detectors that need the whole pattern (findChessboardCornersSB, findChessboardCorners) often fail on
real views. With a prediction the default method is therefore `find_grid_near`: X-corners (saddle points) are
matched to the predicted vertices under a shift, then through an affine correction of the prediction (its turn
and scale may be off by degrees and per cent) to the placement that explains most of them, the black/white
pattern is checked, and every vertex is refined with cornerSubPix in a window small enough to keep the toe out.
Everything but the predicted board and its surroundings is painted over first, so that the other sandal is not
found instead.

Vertex order: a 7 x 5 board looks the same turned by 180 degrees. With `find_grid_near` each vertex is matched to
its predicted position, so the order is the prediction's (a wrong turn would need a prediction off by half the
board). With 'sb' or 'classic' the detected grid is compared, after removing a common shift, with the prediction in
each of its four labellings (as found, rows reversed, columns reversed, both = 180 degrees): the best must fit
within half a square (RMS, in predicted square sizes) while every other misses by more than twice that plus half a
square (a 180 degree turn misses by about 4 squares RMS, reversed rows by about 2, less when foreshortened).
Without a prediction the order is never resolved: the result is `ambiguous`, with the detected grid in
`unordered_px` (OpenCV's own order, rows of 6) for inspection only.

benchmarks/bench_mock.py measures accuracy and speed on the mock's images. Pixel convention: (0, 0) is the centre
of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import nan

import cv2
import numpy as np

from solver.nao_model import BOARD_COLUMNS, BOARD_ROWS, N_VERTICES

PATTERN_SIZE = (BOARD_COLUMNS - 1, BOARD_ROWS - 1)  # inner vertices per row (along sole x), rows (along sole y)
REASONS = ("missing", "cut_off", "blurred", "ambiguous")
SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
BEST_MATCH_MAX_SQUARES = 0.5  # the chosen labelling must fit the prediction this well (RMS, after the shift)
SEPARATION_SQUARES = 0.5  # and every other labelling must miss by more than twice as much plus this
MAX_ASYMMETRY = 0.06  # a clean X-corner looks the same turned by 180 deg about itself (see corner_asymmetry)
MIN_SEED_MATCHES = 6  # vertices a shift must explain before find_grid_near follows it to a placement
MAX_PLACEMENT_TRIES = 60  # shifts (the best first) find_grid_near follows


@dataclass(frozen=True)
class BoardDetection:
    """The result of one detection. `vertices_px` (24, 2) in naocal vertex order when `ok`, else None."""

    vertices_px: np.ndarray | None
    reason: str | None = None  # one of REASONS when not ok
    detail: str = ""
    edge_width_px: float = float("nan")  # 10 %-90 % rise distance of the board's edges
    unordered_px: np.ndarray | None = None  # (24, 2) OpenCV's order, only when the order could not be resolved

    @property
    def ok(self) -> bool:
        return self.vertices_px is not None


def _failure(reason: str, detail: str, **extra) -> BoardDetection:
    return BoardDetection(vertices_px=None, reason=reason, detail=detail, **extra)


def _grey(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 2:
        return image
    raise ValueError(f"expected a (h, w, 3) BGR or (h, w) grey image, got shape {image.shape}")


def _square_px(grid_px: np.ndarray) -> float:
    """Median distance between neighbouring vertices of a (24, 2) grid in naocal/OpenCV row-major order."""
    g = grid_px.reshape(PATTERN_SIZE[1], PATTERN_SIZE[0], 2)
    steps = np.concatenate([np.diff(g, axis=0).reshape(-1, 2), np.diff(g, axis=1).reshape(-1, 2)])
    return float(np.median(np.linalg.norm(steps, axis=1)))


def _inside(points: np.ndarray, shape, margin: float) -> np.ndarray:
    h, w = shape[:2]
    return ((points[:, 0] >= margin) & (points[:, 0] <= w - 1 - margin)
            & (points[:, 1] >= margin) & (points[:, 1] <= h - 1 - margin))


def _edge_width_without_corners(grey: np.ndarray) -> float:
    """A rough edge width (px) of a region with no detected board: contrast over the steepest gradients."""
    g = grey.astype(np.float32)
    lo, hi = np.percentile(g, [2, 98])
    if hi - lo < 20:
        return float("nan")  # nothing with contrast here
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    steepest = np.percentile(np.hypot(gx, gy), 99.7)
    return float(0.8 * (hi - lo) / max(steepest, 1e-6))


def _search_region(grey: np.ndarray, predicted: np.ndarray, search_margin_px: float):
    """A crop around the predicted board with everything beyond the board's surroundings painted white.

    Returns (crop, (u0, v0)) or None when the region holds nothing of the image."""
    h, w = grey.shape
    centre = predicted.mean(axis=0)
    # The printed region spans about 8.2 x 6.2 squares, the vertices 5 x 3: grow the vertices' hull by 2.2 from
    # the centre, plus the search margin for the prediction's error.
    hull = cv2.convexHull(predicted.astype(np.float32)).reshape(-1, 2).astype(float)
    radial = hull - centre
    norm = np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    grown = centre + radial * 2.2 + radial / norm * search_margin_px
    u0, v0 = np.floor(grown.min(axis=0)).astype(int)
    u1, v1 = np.ceil(grown.max(axis=0)).astype(int)
    u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w - 1), min(v1, h - 1)
    if u1 - u0 < 16 or v1 - v0 < 16:
        return None
    crop = grey[v0:v1 + 1, u0:u1 + 1].copy()
    mask = np.zeros_like(crop)
    cv2.fillConvexPoly(mask, np.round(grown - [u0, v0]).astype(np.int32), 255)
    if not mask.any():  # the grown board's box reaches into the image, the board itself does not
        return None
    if np.any(mask == 0):
        crop[mask == 0] = np.uint8(np.percentile(crop[mask > 0], 95))
    return crop, (u0, v0)


def _saddle_points(grey: np.ndarray, sigma: float, min_relative: float = 0.4):
    """Candidate X-corners (k, 2): local maxima of -det(Hessian) of the smoothed image, at least `min_relative`
    of the median strength of the 24 strongest (the board's X-corners are about four times stronger than the
    L- and T-shaped corners at its border, at the toe or on the body)."""
    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), sigma)
    gxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    gyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    gxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    response = gxy * gxy - gxx * gyy  # positive at saddle points
    size = int(2 * round(sigma) + 1)
    peaks = (response == cv2.dilate(response, np.ones((size, size), np.uint8))) & (response > 0)
    v, u = np.nonzero(peaks)
    strength = response[v, u]
    if len(strength) == 0:
        return np.zeros((0, 2))
    reference = float(np.median(np.sort(strength)[::-1][:N_VERTICES]))
    keep = strength >= min_relative * reference
    return np.column_stack([u[keep], v[keep]]).astype(float)


GRID_XY = np.stack(np.meshgrid(np.arange(PATTERN_SIZE[0]), np.arange(PATTERN_SIZE[1])), axis=-1).reshape(-1, 2)
"""(24, 2) vertex grid coordinates (col, row) in naocal/OpenCV row-major order."""


def _parity_contrast(grey: np.ndarray, H_grid_px: np.ndarray) -> float:
    """Mean grey of the squares that should be white minus those that should be black, sampled at the centres
    of the fully visible squares (all but the column under the toe). Negative when the grid is off by one."""
    cols, rows = np.meshgrid(np.arange(1, BOARD_COLUMNS), np.arange(BOARD_ROWS))
    centres = np.column_stack([cols.ravel() - 0.5, rows.ravel() - 0.5])  # square (i, j) centre in vertex grid coords
    black = (cols.ravel() + rows.ravel()) % 2 == 0  # the corner squares are black
    px = cv2.perspectiveTransform(centres[None].astype(np.float64), H_grid_px)[0]
    h, w = grey.shape
    u = np.clip(np.round(px[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(px[:, 1]).astype(int), 0, h - 1)
    values = cv2.blur(grey, (3, 3))[v, u].astype(float)
    return float(values[~black].mean() - values[black].mean())


def _placement(predicted_px: np.ndarray, candidates: np.ndarray, start_px: np.ndarray, radius: float):
    """Where a first match leads: the vertices matched within `radius` of `start_px` (the prediction under one
    shift) give an affine map from the predicted to the found positions; every vertex is matched again through
    it, and so on until the matches stop changing. The prediction's perspective stays in the map; what the
    affine part absorbs is the prediction's error in turn, scale and shear, which a shift alone leaves at the
    board's far end. Returns (matched count, homography from the vertex grid to the image, its (24, 2) grid,
    each vertex's candidate index or -1 (24,)) or None when the matches do not span the grid (fewer than
    MIN_SEED_MATCHES, or all on one line)."""
    design = np.column_stack([predicted_px, np.ones(len(predicted_px))])
    mapped, seen = start_px, set()
    for _ in range(10):
        d = np.linalg.norm(mapped[:, None] - candidates[None], axis=-1)
        index = d.argmin(axis=1)
        matched = d[np.arange(len(index)), index] < radius
        taken, times = np.unique(index[matched], return_counts=True)
        for c in taken[times > 1]:  # a candidate explains one vertex at most: the nearest
            claim = np.flatnonzero(matched & (index == c))
            matched[claim[d[claim, c] > d[claim, c].min()]] = False
        if matched.sum() < MIN_SEED_MATCHES or _collinear(GRID_XY[matched]):
            return None
        key = np.where(matched, index, -1).tobytes()
        if key in seen:
            break
        seen.add(key)
        A, *_ = np.linalg.lstsq(design[matched], candidates[index[matched]], rcond=None)
        mapped = design @ A
    H, _ = cv2.findHomography(GRID_XY[matched].astype(np.float64), candidates[index[matched]], 0)
    if H is None:
        return None
    return (int(matched.sum()), H, cv2.perspectiveTransform(GRID_XY[None].astype(np.float64), H)[0],
            np.where(matched, index, -1))


def _collinear(grid_xy: np.ndarray) -> bool:
    """Whether vertex grid coordinates (k, 2) all lie on one line (no affine map follows from them)."""
    d = grid_xy[1:] - grid_xy[0]
    return not np.any(d[:, 0] * d[0:1, 1] - d[:, 1] * d[0:1, 0]) if len(d) else True


def edge_width_px(grey: np.ndarray, grid_px: np.ndarray) -> float:
    """10 %-90 % rise distance (px) of the board's edges between the grid's vertices (24, 2), averaged over the
    edges of each of the two families (OpenCV's estimateChessboardSharpness), the worse family: about 1.5-2 px
    for a sharp image, more with defocus or motion blur (which widens only the edges across the motion)."""
    corners = grid_px.reshape(-1, 1, 2).astype(np.float32)
    widths = [cv2.estimateChessboardSharpness(grey, PATTERN_SIZE, corners, 0.8, vertical)[0][0]
              for vertical in (False, True)]
    return float(max(widths))


def find_grid_near(grey: np.ndarray, predicted_px: np.ndarray, search_margin_px: float,
                   max_edge_width_px: float = 3.0):
    """Locate the 24 vertices near their predicted positions (naocal order), robust to a partly hidden board.

    Saddle points of the image are matched to the prediction under a common shift (a vote over the shifts
    within the search margin); the best shifts' matches are each followed to the placement of the grid they lead
    to (`_placement`: an affine correction of the prediction, so that a prediction turned by several degrees or
    scaled by a few per cent - a leg the estimate has not fitted yet - still matches at the board's far end).
    The placement explaining most corners (at least 20) wins, unless another placement a square or more away
    explains nearly as many with the right pattern (`ambiguous`). A homography from the vertex grid to the image
    is fitted, the black/white pattern is checked (a grid off by one square inverts it), and every vertex is refined
    with cornerSubPix in a window of 0.15 squares, small enough to keep out the toe in front of the first vertex
    column (7.5 mm away on the sandal) unless the toe's edge comes closer in perspective; then that vertex's
    window shrinks until its neighbourhood is a clean X-corner (`_refine_clean`), or the board is reported
    `missing`. Edges wider than `max_edge_width_px` make it `blurred` (checked before refining).
    Returns ((24, 2) or None, reason or None, detail, edge width in px or nan).
    """
    square = _square_px(predicted_px)
    candidates = _saddle_points(grey, sigma=max(1.0, 0.12 * square))
    if len(candidates) < N_VERTICES // 2:
        return None, "missing", f"only {len(candidates)} corner-like points near the prediction", nan
    radius = 0.2 * square
    shifts = (candidates[None, :, :] - predicted_px[:, None, :]).reshape(-1, 2)
    shifts = shifts[np.linalg.norm(shifts, axis=1) <= search_margin_px + 0.5 * square]
    if len(shifts) == 0:
        return None, "missing", "no corner-like point within the search margin", nan
    moved = predicted_px[None, :, None, :] + shifts[:, None, None, :]  # (m, 24, 1, 2)
    distance = np.linalg.norm(moved - candidates[None, None], axis=-1)  # (m, 24, candidates)
    pairing = np.where(distance.min(axis=-1) < radius, distance.argmin(axis=-1), -1)  # (m, 24) candidate or -1
    counts = (pairing >= 0).sum(axis=1)
    order = np.lexsort((np.linalg.norm(shifts, axis=1), -counts))
    _, first = np.unique(pairing[order], axis=0, return_index=True)
    distinct = order[np.sort(first)]  # the best shift of each different pairing, best first
    # Follow these shifts' matches to the placements they lead to (the prediction's shape may be off by more
    # than `radius` at the board's far end: a few degrees of in-image rotation, a few per cent of scale).
    placements = []  # (matched count, homography, (24, 2) grid, distance of its mean from the prediction's, pairing)
    for k in distinct[:MAX_PLACEMENT_TRIES]:
        if counts[k] < MIN_SEED_MATCHES:
            break
        seed = pairing[k] >= 0
        if any(np.array_equal(pairing[k][seed], p[4][seed]) for p in placements):
            continue  # these matches are part of a placement already followed
        placement = _placement(predicted_px, candidates, predicted_px + shifts[k], radius)
        if placement is None:
            continue
        count, H, grid, matches = placement
        offset = float(np.linalg.norm((grid - predicted_px).mean(axis=0)))
        if offset > search_margin_px + 0.5 * square:
            continue  # the board may lie only so far from the prediction
        misfit = grid - predicted_px - (grid - predicted_px).mean(axis=0)
        if np.sqrt(np.mean(np.sum(misfit ** 2, axis=1))) > BEST_MATCH_MAX_SQUARES * square:
            continue  # and its shape must be the prediction's, as for order_like_prediction
        same = [i for i, p in enumerate(placements) if np.max(np.linalg.norm(p[2] - grid, axis=1)) < 0.5 * square]
        if same:
            i = same[0]
            if (count, -offset) > (placements[i][0], -placements[i][3]):
                placements[i] = (count, H, grid, offset, matches)
            continue
        placements.append((count, H, grid, offset, matches))
    if not placements:
        best_count = int(counts[order[0]])
        return None, "missing", f"only {best_count} of {N_VERTICES} vertices found near the prediction", nan
    placements.sort(key=lambda p: (-p[0], p[3]))
    best_count, H = placements[0][:2]
    if best_count < N_VERTICES - 4:
        return None, "missing", f"only {best_count} of {N_VERTICES} vertices found near the prediction", nan
    contrast = _parity_contrast(grey, H)
    # Another placement of the grid (a square or more away) that explains nearly as many corners with the right
    # pattern would make the choice a guess.
    for rival_count, H_rival, *_ in placements[1:]:
        if rival_count < best_count - 2:
            break
        if _parity_contrast(grey, H_rival) > 0.5 * abs(contrast):
            return None, "ambiguous", (f"two placements of the grid explain {best_count} and {rival_count} "
                                       "corners"), nan
    if contrast <= 0:
        return None, "missing", "the black and white squares do not match the board (grid off by a square?)", nan
    for _ in range(2):  # re-match every vertex through the grid, then refit on all matches
        guess = cv2.perspectiveTransform(GRID_XY[None].astype(np.float64), H)[0]
        d = np.linalg.norm(guess[:, None] - candidates[None], axis=-1)
        close = d.min(axis=1) < 0.2 * square
        start = np.where(close[:, None], candidates[d.argmin(axis=1)], guess)
        H, _ = cv2.findHomography(GRID_XY.astype(np.float64), start, 0)
    if not np.all(_inside(start, grey.shape, _refine_window_px(square) + 1)):
        return None, "cut_off", "a vertex of the grid lies at or beyond the edge of the searched region", nan
    width = edge_width_px(grey, start)
    if width > max_edge_width_px:  # checked before refining: blur is what makes the refinement fail
        return None, "blurred", f"edges {width:.2f} px wide (limit {max_edge_width_px})", width
    refined, problem = _refine_clean(grey, start, _refine_window_px(square))
    if refined is None:
        return None, "missing", problem, width
    return refined, None, f"{best_count} of {N_VERTICES} corners matched, pattern contrast {contrast:.0f}", width


def _subpix(grey: np.ndarray, start: np.ndarray, half: int) -> np.ndarray:
    return cv2.cornerSubPix(grey, start.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1),
                            (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)).reshape(-1, 2).astype(float)


def _refine_clean(grey: np.ndarray, start: np.ndarray, half: int, refine_first: bool = True):
    """cornerSubPix of every vertex in a window of `half` px, shrunk (down to 2 px) for the vertices whose window
    holds something that is not their X-corner (an occluding edge near a vertex pulls it: `corner_asymmetry`);
    those restart from the homography of the clean ones. With refine_first=False the start positions (already
    refined by a detector) are only checked, and re-refined where unclean. Returns ((24, 2), '') or (None, why)."""
    if not np.all(_inside(np.asarray(start, dtype=float), grey.shape, half + 1)):
        return None, "a vertex lies at the edge of the searched region"
    refined = _subpix(grey, start, half) if refine_first else np.array(start, dtype=float)
    asymmetry = corner_asymmetry(grey, refined, half)
    bad = asymmetry > MAX_ASYMMETRY
    smaller = half
    while bad.any() and smaller > 2 and (~bad).sum() >= 8:
        smaller = max(2, int(smaller * 0.6))
        H, _ = cv2.findHomography(GRID_XY[~bad].astype(np.float64), refined[~bad], 0)
        guess = cv2.perspectiveTransform(GRID_XY[None].astype(np.float64), H)[0]
        retry = np.flatnonzero(bad)
        if not np.all(_inside(guess[retry], grey.shape, smaller + 1)):
            return None, "a vertex lies at the edge of the searched region"
        refined[retry] = _subpix(grey, guess[retry], smaller)
        asymmetry[retry] = corner_asymmetry(grey, refined[retry], smaller)
        bad = asymmetry > MAX_ASYMMETRY
    if bad.any():
        return None, (f"vertices {np.flatnonzero(bad).tolist()} are partly hidden: neighbourhood asymmetry up to "
                      f"{asymmetry.max():.2f} even in a {2 * smaller + 1} px window")
    drift = np.linalg.norm(refined - start, axis=1)
    if np.any(drift > 3.0 * half):
        return None, f"a vertex refinement wandered {drift.max():.1f} px"
    return refined, ""


def corner_asymmetry(grey: np.ndarray, corners_px: np.ndarray, radius_px: int) -> np.ndarray:
    """(n,) How far each corner's neighbourhood is from point symmetry: mean |I(c + d) - I(c - d)| over a disc
    of `radius_px`, over the patch's contrast. About 0.02 for a clean X-corner (straight edges through it, also
    under perspective); an occluding edge (the toe, the other leg) or damage near it raises it."""
    r = int(radius_px)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = (xx * xx + yy * yy) <= r * r
    grey = grey.astype(np.float32)
    out = np.empty(len(corners_px))
    for i, (u, v) in enumerate(corners_px):
        patch = cv2.getRectSubPix(grey, (2 * r + 1, 2 * r + 1), (float(u), float(v)))
        lo, hi = np.percentile(patch[disc], [5, 95])
        out[i] = np.abs(patch - patch[::-1, ::-1])[disc].mean() / max(hi - lo, 1.0)
    return out


def _refine_window_px(square_px: float) -> int:
    """Half size of the refinement window: 0.15 squares keeps the toe out (7.5 mm = 0.3 squares away)."""
    return int(np.clip(round(0.15 * square_px), 2, 8))


def find_grid(grey: np.ndarray, method: str = "sb") -> np.ndarray | None:
    """The 24 inner vertices (24, 2) in OpenCV's order, or None. method: 'sb' (findChessboardCornersSB with
    CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE) or 'classic' (findChessboardCorners + cornerSubPix)."""
    if method == "sb":
        found, corners = cv2.findChessboardCornersSB(grey, PATTERN_SIZE, flags=SB_FLAGS)
    elif method == "classic":
        found, corners = cv2.findChessboardCorners(grey, PATTERN_SIZE, flags=CLASSIC_FLAGS)
        if found:
            square = _square_px(corners.reshape(-1, 2))
            half = int(np.clip(square * 0.3, 2, 10))
            corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1),
                                       (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
    else:
        raise ValueError(f"unknown method {method!r}: expected 'sb' or 'classic'")
    if not found or corners is None or len(corners) != N_VERTICES:
        return None
    return corners.reshape(-1, 2).astype(float)


def order_like_prediction(grid_px: np.ndarray, predicted_px: np.ndarray):
    """Reorder a detected (24, 2) grid (OpenCV row-major order, rows of 6) to match the predicted vertices.

    Returns (ordered (24, 2) or None, detail). Each of the grid's four labellings is compared with the
    prediction after removing the mean shift; see the module docstring for the acceptance rule."""
    g = grid_px.reshape(PATTERN_SIZE[1], PATTERN_SIZE[0], 2)
    labellings = {"as found": g, "rows reversed": g[::-1], "columns reversed": g[:, ::-1],
                  "turned 180 deg": g[::-1, ::-1]}
    square = _square_px(predicted_px)
    misfit = {}
    for name, candidate in labellings.items():
        d = candidate.reshape(-1, 2) - predicted_px
        d = d - d.mean(axis=0)
        misfit[name] = float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) / square
    ranked = sorted(misfit, key=misfit.get)
    best, second = ranked[0], ranked[1]
    detail = ", ".join(f"{name}: {misfit[name]:.2f}" for name in ranked) + " squares RMS after the shift"
    if misfit[best] > BEST_MATCH_MAX_SQUARES or misfit[second] < 2 * misfit[best] + SEPARATION_SQUARES:
        return None, detail
    return labellings[best].reshape(-1, 2).copy(), detail


def detect_board_vertices(
    image_bgr: np.ndarray,
    predicted_px: np.ndarray | None = None,
    *,
    border_margin_px: float = 6.0,
    search_margin_px: float = 40.0,
    max_edge_width_px: float = 3.0,
    method: str | None = None,
) -> BoardDetection:
    """The 24 vertices of one board in naocal's vertex order, or a failure with its reason.

    Parameters
    ----------
    image_bgr : (h, w, 3) uint8 BGR or (h, w) grey image.
    predicted_px : (24, 2) the model's projection of this board's vertices (naocal order), or None.
        With it the search is restricted to that board and the vertex order is resolved; without it any board
        in the image may be found and the result is `ambiguous` (see the module docstring).
    border_margin_px : vertices closer than this to the image edge make the board `cut_off`.
    search_margin_px : how far (px) the true board may lie from the prediction.
    max_edge_width_px : edges wider than this (10 %-90 % rise, px) make the board `blurred`.
    method : 'guided' (the default with a prediction: `find_grid_near`), 'sb' or 'classic' (`find_grid`, then the
        labelling closest to the prediction). Without a prediction only 'sb' and 'classic' apply ('sb' default).
    """
    grey = _grey(image_bgr)
    if predicted_px is None:
        method = method or "sb"
        if method == "guided":
            raise ValueError("method 'guided' needs predicted_px")
        crop, offset = grey, np.zeros(2)
    else:
        method = method or "guided"
        predicted_px = np.asarray(predicted_px, dtype=float)
        if predicted_px.shape != (N_VERTICES, 2) or not np.all(np.isfinite(predicted_px)):
            raise ValueError(f"predicted_px must be a finite ({N_VERTICES}, 2) array, got shape {predicted_px.shape}")
        region = _search_region(grey, predicted_px, search_margin_px)
        if region is None:
            return _failure("cut_off", "the predicted board lies outside the image")
        crop, offset = region[0], np.asarray(region[1], dtype=float)
    predicted_out = predicted_px is not None and not np.all(_inside(predicted_px, grey.shape, border_margin_px))

    if method == "guided":
        grid, reason, detail, edge_width = find_grid_near(crop, predicted_px - offset, search_margin_px,
                                                          max_edge_width_px)
    else:
        grid = find_grid(crop, method)
        reason, detail, edge_width = None, "", nan
        if grid is None:
            reason, detail = "missing", "no complete 7 x 5 board found"
        else:
            edge_width = edge_width_px(crop, grid)
            if edge_width <= max_edge_width_px:
                grid, problem = _refine_clean(crop, grid, _refine_window_px(_square_px(grid)), refine_first=False)
                if grid is None:
                    reason, detail = "missing", problem + " (OpenCV's vertex order)"
    if grid is None:
        if predicted_out and reason == "missing":
            return _failure("cut_off", f"{detail}, and the predicted board reaches out of the image",
                            edge_width_px=edge_width)
        if reason == "missing" and not np.isfinite(edge_width):
            width = _edge_width_without_corners(crop)
            if np.isfinite(width) and width > max_edge_width_px:
                return _failure("blurred", f"{detail}; edges about {width:.1f} px wide", edge_width_px=width)
        return _failure(reason, detail, edge_width_px=edge_width)

    grid = grid + offset
    if not np.all(_inside(grid, grey.shape, border_margin_px)):
        return _failure("cut_off", f"a vertex lies within {border_margin_px} px of the image edge",
                        edge_width_px=edge_width)
    if edge_width > max_edge_width_px:
        return _failure("blurred", f"edges {edge_width:.2f} px wide (limit {max_edge_width_px})",
                        edge_width_px=edge_width)
    if method == "guided":
        return BoardDetection(vertices_px=grid, detail=detail, edge_width_px=edge_width)
    if predicted_px is None:
        return _failure("ambiguous", "no predicted projection: a 7 x 5 board looks the same turned by 180 deg",
                        edge_width_px=edge_width, unordered_px=grid)
    ordered, detail = order_like_prediction(grid, predicted_px)
    if ordered is None:
        return _failure("ambiguous", "vertex order unclear: " + detail, edge_width_px=edge_width,
                        unordered_px=grid)
    return BoardDetection(vertices_px=ordered, detail=detail, edge_width_px=edge_width)
