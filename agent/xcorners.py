"""X-corners and the lattices they form: the part of finding a checkerboard that needs no board size.

Candidates (`saddle_candidates`) are local maxima of the scale-normalised saddle response -sigma^4 det(Hessian) at
scales from 1 px up (coarse ones on pyramid levels): an ideal X-corner looks the same at every scale below its
square, in either polarity, so no square size is assumed. Kept are those point symmetric about their refined
position and as strong for their contrast as an X-corner is (an L-corner at a board's border is neither). At a
saddle the Hessian's quadratic form vanishes along the two edges through it: each candidate's edge directions.

Lattices (`find_lattices`): a candidate's nearest neighbours along its edges make a first square; if the squares
around it alternate, the lattice grows: the homography of the lattice plus its local misfit (lens distortion)
predicts the next corners, which must be candidates whose edges run along the lattice's lines. A lattice whose
squares do not alternate in both directions (`alternation`) is dropped: stripes, texture and noise make X-like
points, not checkerboards. agent.board_detect matches lattices to a board.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

SCALE_RATIO = 1.6  # between the Gaussian sigmas of the saddle response (from 1 px)
MIN_LEVEL_SIGMA_PX = 1.3  # a sigma is computed on the smallest pyramid level where it is still this wide
MAX_CANDIDATES = 1000
MAX_SEEDS = 400
EDGE_ANGLE_DEG = 20.0  # a neighbour lies along an edge, and a grown corner's edges along the lattice, this closely
MATCH_RADIUS = 0.3  # a predicted corner matches a candidate this close (in local squares)
MAX_CANDIDATE_ASYMMETRY = 0.25  # candidates more asymmetric than this are no X-corners (an L-corner scores 0.5)
MIN_RELATIVE_STRENGTH = 0.02  # saddle strength over contrast^2: about 0.08 for X-corners, 0.02 for L-corners
MIN_CONTRAST = 6.0  # grey levels (p95 - p5) around an X-corner candidate, and between a board's two colours
MIN_SQUARE_CNR = 2.5  # the two colours differ by this many times the spread within a square (real boards: 6-40)


@dataclass
class Candidates:
    """Saddle points of one channel: positions (k, 2), scale-normalised strengths (k,), edge directions (k, 2, 2)
    (unit vectors along the two edges through each point), the sigma each was found at (k,)."""

    points: np.ndarray
    strength: np.ndarray
    edges: np.ndarray
    sigma: np.ndarray
    tree: cKDTree = field(init=False, repr=False)

    def __post_init__(self):
        self.tree = cKDTree(self.points if len(self.points) else np.zeros((0, 2)))


def _edge_directions(gxx, gxy, gyy) -> np.ndarray:
    """(k, 2, 2) the two directions along which the quadratic form of [[gxx, gxy], [gxy, gyy]] vanishes (a
    saddle's edges): with eigenvalues l1 > 0 > l2 and eigenvectors v1, v2, sqrt(-l2) v1 +- sqrt(l1) v2."""
    H = np.stack([np.stack([gxx, gxy], -1), np.stack([gxy, gyy], -1)], -2)
    w, v = np.linalg.eigh(H)  # ascending: w[:, 0] < 0 < w[:, 1]
    a = np.sqrt(np.maximum(-w[:, 0], 0))[:, None] * v[:, :, 1]
    b = np.sqrt(np.maximum(w[:, 1], 0))[:, None] * v[:, :, 0]
    edges = np.stack([a + b, a - b], axis=1)
    return edges / np.maximum(np.linalg.norm(edges, axis=-1, keepdims=True), 1e-12)


def _scales(shape) -> list[tuple[float, int]]:
    """(sigma in full-resolution px, pyramid level) pairs: SCALE_RATIO steps from 1 px up to a 24th of the image's
    smaller side, each computed on the pyramid level where it is at least MIN_LEVEL_SIGMA_PX (cheaper, same
    response)."""
    out, sigma = [], 1.0
    while sigma <= max(min(shape[:2]) / 24.0, 4.2):
        level = 0
        while sigma / 2 ** (level + 1) >= MIN_LEVEL_SIGMA_PX:
            level += 1
        out.append((sigma, level))
        sigma *= SCALE_RATIO
    return out


def _parabolic_peak(response: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Sub-pixel offsets (du, dv) of peaks at integer (u, v) (not on the border) from parabolas through their
    neighbours, within half a pixel."""
    c = response[v, u]
    offsets = []
    for before, after in ((response[v, u - 1], response[v, u + 1]), (response[v - 1, u], response[v + 1, u])):
        curvature = before - 2 * c + after
        with np.errstate(divide="ignore", invalid="ignore"):
            offset = np.where(curvature < 0, 0.5 * (before - after) / curvature, 0.0)
        offsets.append(np.clip(offset, -0.5, 0.5))
    return offsets


def saddle_candidates(channel: np.ndarray, min_relative: float = 0.02) -> Candidates:
    """X-corner candidates: local maxima of sigma^4 * -det(Hessian) over the image at each scale (one per place:
    the strongest scale), at least `min_relative` of the strongest's strength, refined to sub-pixel and kept
    when they look like X-corners (see below); at most MAX_CANDIDATES, the strongest first."""
    img = channel.astype(np.float32)
    pyramid = [img]
    found = []
    for sigma, level in _scales(img.shape):
        while len(pyramid) <= level:
            pyramid.append(cv2.pyrDown(pyramid[-1]))
        s_level = sigma / 2 ** level
        g = cv2.GaussianBlur(pyramid[level], (0, 0), s_level)
        gxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3) / 4.0
        gyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3) / 4.0
        gxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3) / 4.0
        response = (gxy * gxy - gxx * gyy) * s_level ** 4
        size = 2 * int(np.ceil(1.5 * s_level)) + 1
        peaks = (response == cv2.dilate(response, np.ones((size, size), np.uint8))) & (response > 0)
        border = int(np.ceil(2 * s_level)) + 1
        peaks[:border], peaks[-border:], peaks[:, :border], peaks[:, -border:] = False, False, False, False
        v, u = np.nonzero(peaks)
        du, dv = _parabolic_peak(response, u, v)
        scale = 2 ** level  # level pixel (x) is full-resolution pixel (x + 0.5) * scale - 0.5
        found.append(((u + du + 0.5) * scale - 0.5, (v + dv + 0.5) * scale - 0.5, response[v, u], gxx[v, u],
                      gxy[v, u], gyy[v, u], np.full(len(u), sigma)))
    u, v, s, gxx, gxy, gyy, sig = (np.concatenate(parts) for parts in zip(*found))
    if len(s) == 0:
        return Candidates(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2, 2)), np.zeros(0))
    keep = s >= min_relative * s.max()
    order = np.argsort(-s[keep])[:2 * MAX_CANDIDATES]
    u, v, s, gxx, gxy, gyy, sig = (x[keep][order] for x in (u, v, s, gxx, gxy, gyy, sig))
    # One candidate per place: a weaker response within 1.5 sigma (of the stronger) of a stronger one is the same
    # saddle seen at another scale.
    points = np.column_stack([u, v]).astype(float)
    tree = cKDTree(points)
    alive = np.ones(len(points), bool)
    for i in range(len(points)):
        if alive[i]:
            for j in tree.query_ball_point(points[i], 1.5 * sig[i] + 1.0):
                if j > i:
                    alive[j] = False
    index = np.flatnonzero(alive)
    points, s, sig = points[index], s[index], sig[index]
    edges = _edge_directions(gxx[index], gxy[index], gyy[index])
    # X-corners only: refined to sub-pixel, point symmetric about themselves (an L-corner at the board's border is
    # not: about 0.5, see corner_asymmetry), and as strong for their contrast as an X-corner is. At its best scale
    # an X-corner of contrast c (p95 - p5 of its disc) responds with about 0.08 c^2 (1/pi^2 ideally), whatever
    # its size, blur or brightness; an L-corner with a quarter of that, also when the board's edges are skewed.
    radius = np.maximum(3, np.round(1.5 * sig)).astype(int)
    refined = _refine(img, points, np.maximum(2, np.round(sig)).astype(int))
    asymmetry, contrast = symmetry_and_contrast(img, refined, radius)
    at_peak = symmetry_and_contrast(img, points, radius)[0]
    better = asymmetry <= at_peak  # the refinement may wander off on blocky (JPEG) or noisy pixels
    points = np.where(better[:, None], refined, points)
    asymmetry = np.minimum(asymmetry, at_peak)
    relative = s / np.maximum(contrast, 1.0) ** 2
    keep = np.flatnonzero((asymmetry <= MAX_CANDIDATE_ASYMMETRY) & (relative >= MIN_RELATIVE_STRENGTH)
                          & (contrast >= MIN_CONTRAST))[:MAX_CANDIDATES]
    return Candidates(points[keep], s[keep], edges[keep], sig[keep])


def _refine(img: np.ndarray, points: np.ndarray, half: np.ndarray) -> np.ndarray:
    """cornerSubPix of each point (k, 2) in its own half window (k,) px."""
    out = points.astype(np.float32).copy()
    for h in np.unique(half):
        m = half == h
        out[m] = cv2.cornerSubPix(img, out[m].reshape(-1, 1, 2), (int(h), int(h)), (-1, -1),
                                  (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)).reshape(-1, 2)
    return out.astype(float)


def symmetry_and_contrast(img: np.ndarray, points: np.ndarray, radius: np.ndarray):
    """(k,) corner_asymmetry and contrast (p95 - p5) of each point's disc of its own radius (k,) px."""
    img = np.asarray(img, dtype=np.float32)
    asymmetry, contrast = np.empty(len(points)), np.empty(len(points))
    for r in np.unique(radius):
        index = np.flatnonzero(radius == r)
        r = int(r)
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        disc = (xx * xx + yy * yy) <= r * r
        patches = np.stack([cv2.getRectSubPix(img, (2 * r + 1, 2 * r + 1), (float(u), float(v)))
                            for u, v in points[index]])
        lo, hi = np.percentile(patches[:, disc], [5, 95], axis=1)
        difference = np.abs(patches - patches[:, ::-1, ::-1])[:, disc].mean(axis=1)
        asymmetry[index] = difference / np.maximum(hi - lo, 1.0)
        contrast[index] = hi - lo
    return asymmetry, contrast


# ---------------------------------------------------------------------------------------------------- lattices

def _along(direction: np.ndarray, edges: np.ndarray, max_angle_deg: float = EDGE_ANGLE_DEG) -> bool:
    """Whether a unit direction (2,) runs along one of two edge lines (2, 2) (sign does not matter)."""
    return bool(np.max(np.abs(edges @ direction)) >= np.cos(np.radians(max_angle_deg)))


def _seed(cands: Candidates, i: int, k: int = 12):
    """A first square of the lattice at candidate i: {(0, 0): i, (1, 0): j, (0, 1): k, (1, 1): l}, or None. j and
    k are i's nearest neighbours along its two edges (each with an edge of its own along the line joining them),
    l the candidate nearest to where the parallelogram puts the fourth corner."""
    p = cands.points
    distance, index = cands.tree.query(p[i], k=min(k, len(p)))
    distance, index = np.atleast_1d(distance), np.atleast_1d(index)
    keep = (index != i) & (distance >= 2.0) & np.isfinite(distance)
    distance, index = distance[keep], index[keep]
    if len(index) < 3:
        return None
    steps = (p[index] - p[i]) / distance[:, None]
    cos_limit = np.cos(np.radians(EDGE_ANGLE_DEG))
    # a neighbour's own edges must include the line joining them
    joined = np.max(np.abs(np.einsum("kej,kj->ke", cands.edges[index], steps)), axis=1) >= cos_limit
    along = steps @ cands.edges[i].T  # (k, 2): cosines with i's two edges
    nearest = {}
    for e in (0, 1):
        for sign in (1, -1):
            ok = np.flatnonzero(joined & (sign * along[:, e] >= cos_limit))
            nearest[e, sign] = int(index[ok[0]]) if len(ok) else None  # sorted by distance already
    for s1 in (1, -1):
        j = nearest[0, s1]
        if j is None:
            continue
        for s2 in (1, -1):
            k2 = nearest[1, s2]
            if k2 is None or k2 == j:
                continue
            guess = p[j] + p[k2] - p[i]
            side = min(np.linalg.norm(p[j] - p[i]), np.linalg.norm(p[k2] - p[i]))
            d, l = cands.tree.query(guess)
            if d <= MATCH_RADIUS * side and l not in (i, j, k2):
                return {(0, 0): i, (1, 0): j, (0, 1): k2, (1, 1): int(l)}
    return None


def homography(cells: np.ndarray, points: np.ndarray):
    """Least-squares homography lattice -> pixels (cv2.findHomography: DLT, then Levenberg-Marquardt), or None."""
    if len(cells) < 4 or _collinear(cells):
        return None
    H, _ = cv2.findHomography(cells.astype(np.float64), points.astype(np.float64), 0)
    return H


def quick_homography(cells: np.ndarray, points: np.ndarray):
    """The normalised DLT homography lattice -> pixels (Hartley and Zisserman, Alg. 4.2), or None: ten times
    faster than cv2.findHomography for the few points a lattice's growth predicts from, and as good there."""
    if len(cells) < 4 or _collinear(cells):
        return None
    src, dst = cells.astype(float), points.astype(float)
    T = []
    for x in (src, dst):
        mean = x.mean(axis=0)
        scale = np.sqrt(2) / max(np.sqrt(((x - mean) ** 2).sum(axis=1)).mean(), 1e-12)
        T.append(np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1]]))
    a = (src - src.mean(axis=0)) * T[0][0, 0]
    b = (dst - dst.mean(axis=0)) * T[1][0, 0]
    zero, one = np.zeros(len(a)), np.ones(len(a))
    A = np.concatenate([
        np.column_stack([a[:, 0], a[:, 1], one, zero, zero, zero, -b[:, 0] * a[:, 0], -b[:, 0] * a[:, 1], -b[:, 0]]),
        np.column_stack([zero, zero, zero, a[:, 0], a[:, 1], one, -b[:, 1] * a[:, 0], -b[:, 1] * a[:, 1], -b[:, 1]])])
    h = np.linalg.eigh(A.T @ A)[1][:, 0]  # the least-squares null vector (A's last right singular vector)
    H = np.linalg.inv(T[1]) @ h.reshape(3, 3) @ T[0]
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else None


def _collinear(cells: np.ndarray) -> bool:
    d = cells[1:] - cells[0]
    return not np.any(d[:, 0] * d[0:1, 1] - d[:, 1] * d[0:1, 0]) if len(d) else True


def apply_homography(H: np.ndarray, cells) -> np.ndarray:
    return cv2.perspectiveTransform(np.asarray(cells, np.float64).reshape(1, -1, 2), H)[0]


def _grow(cands: Candidates, seed: dict, max_cells: int = 1600) -> dict:
    """Grow a lattice {(x, y): candidate} from a seed square. Each round predicts every free cell next to the
    lattice by the homography of the whole lattice plus the mean misfit of its lattice neighbours (mild lens
    distortion bends a board; the misfit varies slowly across it), and gives it the nearest free candidate within
    MATCH_RADIUS local squares whose edges run along the lattice's lines there."""
    cells = dict(seed)
    taken = set(seed.values())
    steps = np.array([(1, 0), (-1, 0), (0, 1), (0, -1)])
    while len(cells) < max_cells:
        keys = np.array(list(cells.keys()))
        pts = cands.points[list(cells.values())]
        H = quick_homography(keys, pts)
        if H is None:
            break
        misfit = dict(zip(cells.keys(), pts - apply_homography(H, keys)))
        frontier = sorted({(x + dx, y + dy) for x, y in cells for dx, dy in steps} - cells.keys())
        if not frontier:
            break
        f = np.array(frontier, float)
        p, px, py = (apply_homography(H, f + d) for d in ((0, 0), (1, 0), (0, 1)))
        correction = np.array([np.mean([misfit[(x + dx, y + dy)] for dx, dy in steps if (x + dx, y + dy) in cells],
                                       axis=0) for x, y in frontier])
        p = p + correction
        lx, ly = np.linalg.norm(px - p + correction, axis=1), np.linalg.norm(py - p + correction, axis=1)
        side = np.minimum(lx, ly)
        usable = np.isfinite(side) & (side >= 2.0)
        proposals = []  # (distance in squares, cell, candidate)
        for n in np.flatnonzero(usable):
            ax, ay = (px[n] - p[n] + correction[n]) / lx[n], (py[n] - p[n] + correction[n]) / ly[n]
            for j in cands.tree.query_ball_point(p[n], MATCH_RADIUS * side[n]):
                if j not in taken and _along(ax, cands.edges[j]) and _along(ay, cands.edges[j]):
                    proposals.append((float(np.linalg.norm(cands.points[j] - p[n])) / side[n], frontier[n], j))
        added = False
        for _, cell, j in sorted(proposals):  # one candidate per cell and one cell per candidate, closest first
            if cell not in cells and j not in taken:
                cells[cell] = j
                taken.add(j)
                added = True
        if not added:
            break
    return cells


def find_lattices(cands: Candidates, channel: np.ndarray | None = None, max_lattices: int = 8) -> list[dict]:
    """Disjoint lattices of X-corners {(x, y): candidate index}, the largest first. Each grows from the strongest
    candidate not yet in a lattice, free to take candidates of earlier ones (a seed across two overlapping boards
    must not keep a board's corners from the lattice that explains the whole board); the largest then win. With
    the `channel` image, a seed square grows only when the squares around it alternate (`alternation`), and a
    grown lattice is kept only when its squares do: texture and stripes make X-like points, not checkerboards."""
    in_any = np.zeros(len(cands.points), bool)
    grown = []
    for i in range(min(len(cands.points), MAX_SEEDS)):  # strongest first
        if in_any[i]:
            continue
        seed = _seed(cands, i)
        if seed is None:
            continue
        if channel is not None and not alternation(channel, np.array(list(seed)),
                                                    cands.points[list(seed.values())])[0]:
            continue
        cells = _grow(cands, seed)
        in_any[list(cells.values())] = True
        if channel is None or alternation(channel, np.array(list(cells)), cands.points[list(cells.values())])[0]:
            grown.append(cells)
        if len(grown) >= 2 * max_lattices:
            break
    grown.sort(key=len, reverse=True)
    taken = np.zeros(len(cands.points), bool)
    lattices = []
    for cells in grown:
        if len(cells) >= 4 and not taken[list(cells.values())].any():
            taken[list(cells.values())] = True
            lattices.append(cells)
    return lattices[:max_lattices]


def inside(points: np.ndarray, shape, margin: float) -> np.ndarray:
    h, w = shape[:2]
    return ((points[:, 0] >= margin) & (points[:, 0] <= w - 1 - margin)
            & (points[:, 1] >= margin) & (points[:, 1] <= h - 1 - margin))


def square_stats_at(channel: np.ndarray, H: np.ndarray, squares: np.ndarray, samples: int = 5):
    """Mean and standard deviation (k,) of the channel over the middle half (in each direction) of the squares
    whose lower lattice corner is squares (k, 2), mapped to the image by H (lattice -> pixels); nan for squares
    not wholly inside the image."""
    t = 0.25 + 0.5 * (np.arange(samples) + 0.5) / samples
    sx, sy = np.meshgrid(t, t)
    points = squares[:, None, :] + np.column_stack([sx.ravel(), sy.ravel()])[None]  # (k, samples^2, 2)
    px = apply_homography(H, points.reshape(-1, 2)).astype(np.float32)
    values = cv2.remap(channel.astype(np.float32), px[:, 0].reshape(1, -1), px[:, 1].reshape(1, -1),
                       cv2.INTER_LINEAR).reshape(len(squares), -1)
    whole = inside(px, channel.shape, 0).reshape(len(squares), -1).all(axis=1)
    mean = np.where(whole, values.mean(axis=1), np.nan)
    std = np.where(whole, values.std(axis=1), np.nan)
    return mean, std


def alternation(img: np.ndarray, cells: np.ndarray, points: np.ndarray):
    """Whether the squares touching a lattice's corners (cells (k, 2) -> points (k, 2)) alternate like a
    checkerboard's in both directions: every square between four found corners on its colour's side of each of
    its neighbours in view (brighter than all, or darker than all: a shadow across the board darkens a white
    square below a black one in the light, never below its own dark neighbours; one threshold for the whole board
    refused such boards), three quarters of those touching the lattice at all, and the two colours at least
    MIN_CONTRAST and MIN_SQUARE_CNR times the spread within a square apart. Stripes (which alternate in one direction only),
    texture and noise fail. Returns (ok, signed contrast of the squares of even
    lattice parity over the others, their noise: the median spread within a square)."""
    H = quick_homography(cells, points)
    if H is None:
        return False, 0.0, np.inf
    have = {tuple(c) for c in cells.astype(int)}
    squares = sorted({(x - dx, y - dy) for x, y in have for dx in (0, 1) for dy in (0, 1)})
    sq = np.array(squares)
    inner = np.array([all((x + dx, y + dy) in have for dx in (0, 1) for dy in (0, 1)) for x, y in squares])
    values, spread = (a.ravel() for a in square_stats_at(img, H, sq))
    seen = np.isfinite(values)
    even = sq.sum(axis=1) % 2 == 0
    if not (even & seen).any() or not (~even & seen).any():
        return False, 0.0, np.inf
    mean_even, mean_odd = values[even & seen].mean(), values[~even & seen].mean()
    contrast = float(mean_even - mean_odd)
    expected = np.where(even, 1, -1) * np.sign(contrast)
    agree = np.sign(values - 0.5 * (mean_even + mean_odd)) == expected  # a square without neighbours in view
    index = {square: i for i, square in enumerate(squares)}
    for i, (x, y) in enumerate(squares):
        if not seen[i]:
            continue
        around = [index.get(n) for n in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1))]
        around = [j for j in around if j is not None and seen[j]]
        if around:
            agree[i] = bool(np.all(np.sign(values[i] - values[around]) == expected[i]))
    noise = float(np.median(spread[seen]))
    ok = (abs(contrast) >= max(MIN_CONTRAST, MIN_SQUARE_CNR * noise) and agree[inner & seen].all()
          and agree[seen].mean() >= 0.75 and (inner & seen).sum() >= 1)
    return bool(ok), contrast, noise
