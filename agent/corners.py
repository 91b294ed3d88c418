"""Finding a board's inner vertices near a predicted projection: the agent's detection of the sandals (OpenCV).

`detect_board_vertices` returns the vertices in naocal's vertex order (solver.nao_model.board_vertices_sole: index
= row * 6 + col, col along +x of the sole frame, row along +y; for another `BoardSpec`, row * (columns - 1) + col)
or a failure with its reason - never a guess:

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
Without a prediction the board is found by agent.board_detect.detect_board (any board size, colours, polarity,
channel); the sandal's order is then never resolved (it looks the same turned by 180 degrees): the result is
`ambiguous`, with the corners in `image_order_px` (agent.board_detect's image order) for inspection only.

The guided matcher works for any `BoardSpec` (`board=`, default the sandal's `SANDAL`) in the channel that
separates its colours (grey for black/white); a board of unknown polarity skips the square-pattern check.

benchmarks/bench_mock.py measures accuracy and speed on the mock's images. Pixel convention: (0, 0) is the centre
of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

import dataclasses
import functools
from math import nan

import cv2
import numpy as np

from naocal.agent.board_detect import (REASONS, SANDAL, BoardDetection, BoardSpec, channel_image, channels_to_try,
                                 corner_asymmetry, detect_board, failure, image_order, polarity, refine_clean)
from naocal.agent.board_detect import edge_width_px as _grid_edge_width_px
from naocal.agent.xcorners import inside as _inside

__all__ = ["REASONS", "SANDAL", "BoardDetection", "BoardSpec", "corner_asymmetry", "detect_board_vertices",
           "edge_width_px", "find_grid", "find_grid_near", "grid_xy", "order_like_prediction"]

SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
BEST_MATCH_MAX_SQUARES = 0.5  # the chosen labelling must fit the prediction this well (RMS, after the shift)
SEPARATION_SQUARES = 0.5  # and every other labelling must miss by more than twice as much plus this
MAX_ASYMMETRY = 0.06  # a clean X-corner looks the same turned by 180 deg about itself (see corner_asymmetry)
MIN_SEED_MATCHES = 6  # vertices a shift must explain before find_grid_near follows it to a placement
MAX_PLACEMENT_TRIES = 60  # shifts (the best first) find_grid_near follows


@functools.lru_cache(maxsize=16)
def _grid_xy(board: BoardSpec) -> np.ndarray:
    rows, columns = board.shape
    out = np.stack(np.meshgrid(np.arange(columns), np.arange(rows)), axis=-1).reshape(-1, 2)
    out.setflags(write=False)
    return out


def grid_xy(board: BoardSpec = SANDAL) -> np.ndarray:
    """(n, 2) vertex grid coordinates (col, row) in naocal/OpenCV row-major order."""
    return _grid_xy(board)


def _square_px(grid_px: np.ndarray, board: BoardSpec = SANDAL) -> float:
    """Median distance between neighbouring vertices of a (n, 2) grid in naocal/OpenCV row-major order."""
    g = grid_px.reshape(*board.shape, 2)
    steps = np.concatenate([np.diff(g, axis=0).reshape(-1, 2), np.diff(g, axis=1).reshape(-1, 2)])
    return float(np.median(np.linalg.norm(steps, axis=1)))


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


def _search_region(grey: np.ndarray, predicted: np.ndarray, search_margin_px: float, board: BoardSpec = SANDAL):
    """A crop around the predicted board with everything beyond the board's surroundings painted white.

    Returns (crop, (u0, v0)) or None when the region holds nothing of the image."""
    h, w = grey.shape
    centre = predicted.mean(axis=0)
    # The sandal's printed region spans about 8.2 x 6.2 squares, its vertices 5 x 3: grow the vertices' hull by
    # 2.2 from the centre (more for boards with fewer squares), plus the search margin for the prediction's error.
    growth = max(2.2, *((n + 1.2) / (n - 2) for n in (board.columns, board.rows) if n > 2))
    hull = cv2.convexHull(predicted.astype(np.float32)).reshape(-1, 2).astype(float)
    radial = hull - centre
    norm = np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    grown = centre + radial * growth + radial / norm * search_margin_px
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


def _saddle_points(grey: np.ndarray, sigma: float, n_strongest: int, min_relative: float = 0.4):
    """Candidate X-corners (k, 2): local maxima of -det(Hessian) of the smoothed image, at least `min_relative`
    of the median strength of the `n_strongest` (the board's vertex count; its X-corners are about four times
    stronger than the L- and T-shaped corners at its border, at the toe or on the body)."""
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
    reference = float(np.median(np.sort(strength)[::-1][:n_strongest]))
    keep = strength >= min_relative * reference
    return np.column_stack([u[keep], v[keep]]).astype(float)


def _parity_contrast(grey: np.ndarray, H_grid_px: np.ndarray, board: BoardSpec = SANDAL,
                     channel: str = "grey") -> float:
    """Mean value of the squares of the board's second colour minus those of its first (the colour of the corner
    square before vertex 0: black on the sandal), times the first colour's polarity in this channel (+1 when
    it is the brighter), sampled at the centres of the fully visible squares (all but the first column: on the
    sandal the toe covers it). Negative when the grid is off by one square; its magnitude when the polarity is
    unknown (then an offset grid cannot be told from the colours)."""
    cols, rows = np.meshgrid(np.arange(1, board.columns), np.arange(board.rows))
    centres = np.column_stack([cols.ravel() - 0.5, rows.ravel() - 0.5])  # square (i, j) centre in vertex grid coords
    first = (cols.ravel() + rows.ravel()) % 2 == 0  # square (0, 0)'s colour
    px = cv2.perspectiveTransform(centres[None].astype(np.float64), H_grid_px)[0]
    h, w = grey.shape
    u = np.clip(np.round(px[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(px[:, 1]).astype(int), 0, h - 1)
    values = cv2.blur(grey, (3, 3))[v, u].astype(float)
    difference = float(values[~first].mean() - values[first].mean())
    sign = -polarity(board, channel)
    return difference * sign if sign else abs(difference)


def _placement(predicted_px: np.ndarray, candidates: np.ndarray, start_px: np.ndarray, radius: float,
               board: BoardSpec = SANDAL):
    """Where a first match leads: the vertices matched within `radius` of `start_px` (the prediction under one
    shift) give an affine map from the predicted to the found positions; every vertex is matched again through
    it, and so on until the matches stop changing. The prediction's perspective stays in the map; what the
    affine part absorbs is the prediction's error in turn, scale and shear, which a shift alone leaves at the
    board's far end. Returns (matched count, homography from the vertex grid to the image, its (n, 2) grid,
    each vertex's candidate index or -1 (n,)) or None when the matches do not span the grid (fewer than
    MIN_SEED_MATCHES, or all on one line)."""
    xy = grid_xy(board)
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
        if matched.sum() < _min_seed_matches(board) or _collinear(xy[matched]):
            return None
        key = np.where(matched, index, -1).tobytes()
        if key in seen:
            break
        seen.add(key)
        A, *_ = np.linalg.lstsq(design[matched], candidates[index[matched]], rcond=None)
        mapped = design @ A
    H, _ = cv2.findHomography(xy[matched].astype(np.float64), candidates[index[matched]], 0)
    if H is None:
        return None
    return (int(matched.sum()), H, cv2.perspectiveTransform(xy[None].astype(np.float64), H)[0],
            np.where(matched, index, -1))


def _min_seed_matches(board: BoardSpec) -> int:
    return min(MIN_SEED_MATCHES, board.n_corners - 2)


def _collinear(xy: np.ndarray) -> bool:
    """Whether vertex grid coordinates (k, 2) all lie on one line (no affine map follows from them)."""
    d = xy[1:] - xy[0]
    return not np.any(d[:, 0] * d[0:1, 1] - d[:, 1] * d[0:1, 0]) if len(d) else True


def edge_width_px(grey: np.ndarray, grid_px: np.ndarray, board: BoardSpec = SANDAL) -> float:
    """10 %-90 % rise distance (px) of the board's edges between the grid's vertices (n, 2) in naocal/OpenCV
    row-major order (agent.board_detect.edge_width_px): about 1.5-2 px for a sharp image, more with defocus or
    motion blur (which widens only the edges across the motion)."""
    return _grid_edge_width_px(grey, np.asarray(grid_px, float).reshape(*board.shape, 2))


def find_grid_near(grey: np.ndarray, predicted_px: np.ndarray, search_margin_px: float,
                   max_edge_width_px: float = 3.0, board: BoardSpec = SANDAL, channel: str = "grey"):
    """Locate the board's n vertices near their predicted positions (naocal order), robust to a partly hidden
    board.

    Saddle points of the image are matched to the prediction under a common shift (a vote over the shifts
    within the search margin); the best shifts' matches are each followed to the placement of the grid they lead
    to (`_placement`: an affine correction of the prediction, so that a prediction turned by several degrees or
    scaled by a few per cent - a leg the estimate has not fitted yet - still matches at the board's far end).
    The placement explaining most corners (at least n - n // 6: 20 of the sandal's 24) wins, unless another
    placement a square or more away explains nearly as many with the right pattern (`ambiguous`). A homography
    from the vertex grid to the image is fitted, the square pattern is checked (a grid off by one square inverts
    it), and every vertex is refined with cornerSubPix in a window of 0.15 squares, small enough to keep out the
    toe in front of the first vertex column (7.5 mm away on the sandal) unless the toe's edge comes closer in
    perspective; then that vertex's window shrinks until its neighbourhood is a clean X-corner
    (`refine_clean`), or the board is reported `missing`. Edges wider than `max_edge_width_px` make it `blurred`
    (checked before refining). `grey` is the image's `channel` (for the colours' polarity in it).
    Returns ((n, 2) or None, reason or None, detail, edge width in px or nan).
    """
    n = board.n_corners
    xy = grid_xy(board)
    square = _square_px(predicted_px, board)
    candidates = _saddle_points(grey, sigma=max(1.0, 0.12 * square), n_strongest=n)
    if len(candidates) < n // 2:
        return None, "missing", f"only {len(candidates)} corner-like points near the prediction", nan
    radius = 0.2 * square
    shifts = (candidates[None, :, :] - predicted_px[:, None, :]).reshape(-1, 2)
    shifts = shifts[np.linalg.norm(shifts, axis=1) <= search_margin_px + 0.5 * square]
    if len(shifts) == 0:
        return None, "missing", "no corner-like point within the search margin", nan
    moved = predicted_px[None, :, None, :] + shifts[:, None, None, :]  # (m, n, 1, 2)
    distance = np.linalg.norm(moved - candidates[None, None], axis=-1)  # (m, n, candidates)
    pairing = np.where(distance.min(axis=-1) < radius, distance.argmin(axis=-1), -1)  # (m, n) candidate or -1
    counts = (pairing >= 0).sum(axis=1)
    order = np.lexsort((np.linalg.norm(shifts, axis=1), -counts))
    _, first = np.unique(pairing[order], axis=0, return_index=True)
    distinct = order[np.sort(first)]  # the best shift of each different pairing, best first
    # Follow these shifts' matches to the placements they lead to (the prediction's shape may be off by more
    # than `radius` at the board's far end: a few degrees of in-image rotation, a few per cent of scale).
    placements = []  # (matched count, homography, (n, 2) grid, distance of its mean from the prediction's, pairing)
    for k in distinct[:MAX_PLACEMENT_TRIES]:
        if counts[k] < _min_seed_matches(board):
            break
        seed = pairing[k] >= 0
        if any(np.array_equal(pairing[k][seed], p[4][seed]) for p in placements):
            continue  # these matches are part of a placement already followed
        placement = _placement(predicted_px, candidates, predicted_px + shifts[k], radius, board)
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
        return None, "missing", f"only {best_count} of {n} vertices found near the prediction", nan
    placements.sort(key=lambda p: (-p[0], p[3]))
    best_count, H = placements[0][:2]
    if best_count < n - max(1, n // 6):
        return None, "missing", f"only {best_count} of {n} vertices found near the prediction", nan
    contrast = _parity_contrast(grey, H, board, channel)
    # Another placement of the grid (a square or more away) that explains nearly as many corners with the right
    # pattern would make the choice a guess.
    for rival_count, H_rival, *_ in placements[1:]:
        if rival_count < best_count - 2:
            break
        if _parity_contrast(grey, H_rival, board, channel) > 0.5 * abs(contrast):
            return None, "ambiguous", (f"two placements of the grid explain {best_count} and {rival_count} "
                                       "corners"), nan
    if contrast <= 0:
        return None, "missing", "the board's squares do not match its colours (grid off by a square?)", nan
    for _ in range(2):  # re-match every vertex through the grid, then refit on all matches
        guess = cv2.perspectiveTransform(xy[None].astype(np.float64), H)[0]
        d = np.linalg.norm(guess[:, None] - candidates[None], axis=-1)
        close = d.min(axis=1) < 0.2 * square
        start = np.where(close[:, None], candidates[d.argmin(axis=1)], guess)
        H, _ = cv2.findHomography(xy.astype(np.float64), start, 0)
    if not np.all(_inside(start, grey.shape, _refine_window_px(square) + 1)):
        return None, "cut_off", "a vertex of the grid lies at or beyond the edge of the searched region", nan
    width = edge_width_px(grey, start, board)
    if width > max_edge_width_px:  # checked before refining: blur is what makes the refinement fail
        return None, "blurred", f"edges {width:.2f} px wide (limit {max_edge_width_px})", width
    refined, _, problem = refine_clean(grey, start, _refine_window_px(square), xy, MAX_ASYMMETRY)
    if refined is None:
        return None, "missing", problem, width
    return refined, None, f"{best_count} of {n} corners matched, pattern contrast {contrast:.0f}", width


def _refine_window_px(square_px: float) -> int:
    """Half size of the refinement window: 0.15 squares keeps the toe out (7.5 mm = 0.3 squares away)."""
    return int(np.clip(round(0.15 * square_px), 2, 8))


def find_grid(grey: np.ndarray, method: str = "sb", board: BoardSpec = SANDAL) -> np.ndarray | None:
    """The board's n inner vertices (n, 2) in OpenCV's order, or None. method: 'sb' (findChessboardCornersSB
    with CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE) or 'classic' (findChessboardCorners + cornerSubPix)."""
    pattern = board.shape[::-1]  # OpenCV's (corners per row, rows)
    if method == "sb":
        found, corners = cv2.findChessboardCornersSB(grey, pattern, flags=SB_FLAGS)
    elif method == "classic":
        found, corners = cv2.findChessboardCorners(grey, pattern, flags=CLASSIC_FLAGS)
        if found:
            square = _square_px(corners.reshape(-1, 2), board)
            half = int(np.clip(square * 0.3, 2, 10))
            corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1),
                                       (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
    else:
        raise ValueError(f"unknown method {method!r}: expected 'sb' or 'classic'")
    if not found or corners is None or len(corners) != board.n_corners:
        return None
    return corners.reshape(-1, 2).astype(float)


def order_like_prediction(grid_px: np.ndarray, predicted_px: np.ndarray, board: BoardSpec = SANDAL):
    """Reorder a detected (n, 2) grid (OpenCV row-major order, rows of columns - 1) to match the predicted
    vertices.

    Returns (ordered (n, 2) or None, detail). Each of the grid's four labellings is compared with the
    prediction after removing the mean shift; see the module docstring for the acceptance rule."""
    g = grid_px.reshape(*board.shape, 2)
    labellings = {"as found": g, "rows reversed": g[::-1], "columns reversed": g[:, ::-1],
                  "turned 180 deg": g[::-1, ::-1]}
    if board.rows == board.columns:  # a square board: its quarter turns too
        t = np.swapaxes(g, 0, 1)
        labellings.update({"transposed": t, "turned 90 deg": t[::-1], "turned 270 deg": t[:, ::-1],
                           "transposed and turned 180 deg": t[::-1, ::-1]})
    square = _square_px(predicted_px, board)
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
    board: BoardSpec = SANDAL,
    channel: str = "auto",
    border_margin_px: float = 6.0,
    search_margin_px: float = 40.0,
    max_edge_width_px: float = 3.0,
    method: str | None = None,
) -> BoardDetection:
    """The board's vertices in naocal's vertex order, or a failure with its reason.

    Parameters
    ----------
    image_bgr : (h, w, 3) uint8 BGR or (h, w) grey image.
    predicted_px : (n, 2) the model's projection of this board's vertices (naocal order), or None.
        With it the search is restricted to that board and the vertex order is resolved; without it any board
        in the image may be found and the sandal's result is `ambiguous` (see the module docstring).
    board : the board (default the sandal, `SANDAL`).
    channel : 'auto' (the channels that separate the board's colours, tried in turn), 'grey', 'cr' or 'cb'.
    border_margin_px : vertices closer than this to the image edge make the board `cut_off`.
    search_margin_px : how far (px) the true board may lie from the prediction.
    max_edge_width_px : edges wider than this (10 %-90 % rise, px) make the board `blurred`.
    method : with a prediction 'guided' (the default: `find_grid_near`), 'sb' or 'classic' (`find_grid`, then the
        labelling closest to the prediction). Without one 'free' (the default: agent.board_detect.detect_board),
        'sb' or 'classic'.
    """
    if predicted_px is None:
        method = method or "free"
        if method == "guided":
            raise ValueError("method 'guided' needs predicted_px")
        if method == "free":
            return detect_board(image_bgr, board, channel=channel, max_edge_width_px=max_edge_width_px)
    else:
        method = method or "guided"
        predicted_px = np.asarray(predicted_px, dtype=float)
        if predicted_px.shape != (board.n_corners, 2) or not np.all(np.isfinite(predicted_px)):
            raise ValueError(f"predicted_px must be a finite ({board.n_corners}, 2) array, got shape "
                             f"{predicted_px.shape}")
    if method not in ("guided", "sb", "classic"):
        raise ValueError(f"unknown method {method!r}: expected 'guided', 'free', 'sb' or 'classic'")
    first = None
    for name in channels_to_try(image_bgr, board, channel):
        found = _detect_in(channel_image(image_bgr, name), name, predicted_px, board, border_margin_px,
                           search_margin_px, max_edge_width_px, method)
        found = _with_channel(found, name)
        if found.ok:
            return found
        first = first or found
    return first


def _with_channel(found: BoardDetection, channel: str) -> BoardDetection:
    return dataclasses.replace(found, channel=channel)


def _detect_in(grey: np.ndarray, channel: str, predicted_px, board: BoardSpec, border_margin_px: float,
               search_margin_px: float, max_edge_width_px: float, method: str) -> BoardDetection:
    """detect_board_vertices in one channel (`grey`, the image's `channel`)."""
    if predicted_px is None:
        crop, offset = grey, np.zeros(2)
    else:
        region = _search_region(grey, predicted_px, search_margin_px, board)
        if region is None:
            return failure("cut_off", "the predicted board lies outside the image")
        crop, offset = region[0], np.asarray(region[1], dtype=float)
    predicted_out = predicted_px is not None and not np.all(_inside(predicted_px, grey.shape, border_margin_px))

    if method == "guided":
        grid, reason, detail, edge_width = find_grid_near(crop, predicted_px - offset, search_margin_px,
                                                          max_edge_width_px, board, channel)
    else:
        grid = find_grid(crop, method, board)
        reason, detail, edge_width = None, "", nan
        if grid is None:
            reason, detail = "missing", f"no complete {board} board found"
        else:
            edge_width = edge_width_px(crop, grid, board)
            if edge_width <= max_edge_width_px:
                grid, _, problem = refine_clean(crop, grid, _refine_window_px(_square_px(grid, board)),
                                                grid_xy(board), MAX_ASYMMETRY, refine_first=False)
                if grid is None:
                    reason, detail = "missing", problem + " (OpenCV's vertex order)"
    if grid is None:
        if predicted_out and reason == "missing":
            return failure("cut_off", f"{detail}, and the predicted board reaches out of the image",
                           edge_width_px=edge_width)
        if reason == "missing" and not np.isfinite(edge_width):
            width = _edge_width_without_corners(crop)
            if np.isfinite(width) and width > max_edge_width_px:
                return failure("blurred", f"{detail}; edges about {width:.1f} px wide", edge_width_px=width)
        return failure(reason, detail, edge_width_px=edge_width)

    grid = grid + offset
    if not np.all(_inside(grid, grey.shape, border_margin_px)):
        return failure("cut_off", f"a vertex lies within {border_margin_px} px of the image edge",
                       edge_width_px=edge_width)
    if edge_width > max_edge_width_px:
        return failure("blurred", f"edges {edge_width:.2f} px wide (limit {max_edge_width_px})",
                       edge_width_px=edge_width)
    if method == "guided":
        return BoardDetection(vertices_px=grid, detail=detail, edge_width_px=edge_width)
    in_image_order = image_order(grid.reshape(*board.shape, 2), board.shape).reshape(-1, 2)
    if predicted_px is None:
        return failure("ambiguous", f"no predicted projection: the vertex order of a {board} board is not resolved",
                       edge_width_px=edge_width, image_order_px=in_image_order)
    ordered, detail = order_like_prediction(grid, predicted_px, board)
    if ordered is None:
        return failure("ambiguous", "vertex order unclear: " + detail, edge_width_px=edge_width,
                       image_order_px=in_image_order)
    return BoardDetection(vertices_px=ordered, detail=detail, edge_width_px=edge_width)
