"""Finding a checkerboard's inner corners in a camera image without a prediction: any size, colours, polarity.

A board is described by a `BoardSpec` (squares per row and column, square size, the two colours); the sandal's
7 x 5 black/white board is `SANDAL`. `detect_board` finds the board's (columns - 1) x (rows - 1) inner corners:

1. Channels: grey (the Y of YCrCb) separates black from white; the chroma channels Cr and Cb separate colours of
   similar brightness (an orange/blue board on green carpet is nearly flat in grey). With known colours only the
   channels in which they differ are tried; otherwise all three, and the board whose squares differ most for the
   noise within them wins (corner precision goes with that contrast to noise). A channel in which a board already
   found differs less is not searched (a black/white board is found in grey alone).
2. X-corners and their lattices (agent.xcorners): saddle points that look like X-corners at any scale, grown
   into lattices along their edges, kept when the squares between them alternate like a checkerboard's.
3. The board: a complete (columns - 1) x (rows - 1) window of a lattice, in either orientation. A further complete
   line of corners makes it a bigger board (refused, never cut down to size). Up to a quarter of the corners may
   be missing inside the image (predicted, and they must prove clean X-corners); missing beyond the image edge
   make it `cut_off`; otherwise `missing`, saying what was found. Several boards in view: `ambiguous`, the largest
   given.
4. Refinement and checks: cornerSubPix in a window of 0.3 squares, shrunk for corners whose neighbourhood is not
   point symmetric (`refine_clean`); the squares must alternate.
5. A second opinion where no lattice passes: OpenCV's findChessboardCornersSB, then findChessboardCorners (both
   need the whole board; they find small, blurred, JPEG-compressed boards whose 5-px corner neighbourhoods fail
   the symmetry check), refined by cornerSubPix and held to the same rules: every square alternates, each corner
   lies on the homography through the others, no corner is much less point symmetric than the board's others
   (a half-hidden corner, which OpenCV puts on the occluder's edge), and the checkerboard does not go on beyond
   the board's outer squares. On 30 synthetic 10 x 7 boards of 7-12 px squares (blur, noise, JPEG 70): own lattices 19 found,
   with the second opinion 26, corners within 1.1 px of the truth.

Order. Corners are always available in the *image order* (`image_order`): rows of (columns - 1) corners; of the
grid's labellings (turns and mirror images) the one whose rows run most nearly left to right and whose rows
follow each other most nearly downwards, so that for a board seen roughly upright row 0 is the top row and the
columns go left to right. The *board order* (vertex index row * (columns - 1) + col, col along the board's x, row
along its y, square (0, 0) before vertex 0 in the first colour) follows from the image alone only when the board
has no symmetry its colours do not break: the camera sees the printed face, never its mirror image, which leaves
the turns; a turn by 180 deg keeps a board with columns + rows even (the sandal's 7 x 5, a 4 x 4), a square board
also has its 90 deg turns, and colours tell turns apart only when the turn swaps them and the polarity in the
channel is known. Otherwise the detection is `ambiguous` (the prediction of a calibration model resolves it:
agent.corners), with its corners in image order.

Pixel convention: (0, 0) is the centre of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from naocal.agent.xcorners import (Candidates, alternation, apply_homography, find_lattices, homography, inside,
                            quick_homography, saddle_candidates, square_stats_at, symmetry_and_contrast)
from naocal.solver.nao_model import BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M

REASONS = ("missing", "cut_off", "blurred", "ambiguous")
CHANNELS = ("grey", "cr", "cb")

# Nominal BGR of the colours a board may be named with (to choose channels and know the polarity in them).
COLOURS_BGR = {
    "black": (0, 0, 0), "white": (255, 255, 255), "grey": (128, 128, 128), "red": (30, 30, 210),
    "orange": (40, 120, 250), "yellow": (30, 220, 240), "green": (60, 170, 40), "blue": (200, 110, 30),
}
MIN_CHANNEL_SHARE = 0.3  # with known colours, a channel is tried when it separates them this well (of the best)

REFINE_WINDOW = 0.3  # cornerSubPix half window (in local squares)
OPENCV_PLANE_TOLERANCE = 0.15  # squares (at least 2 px): how far off its board's plane an OpenCV corner may lie
OPENCV_MAX_WIDTH_PX = 800  # OpenCV's detectors search a copy halved until it is at most this wide
MAX_ASYMMETRY = 0.25  # the most refine_clean's limit for a clean corner can be (see corner_asymmetry)


@dataclass(frozen=True)
class BoardSpec:
    """A checkerboard: `columns` x `rows` squares of `square_m`, coloured `colours` = (colour of the corner square
    before vertex 0, the other colour), names from COLOURS_BGR, or None when unknown. It has
    (columns - 1) x (rows - 1) inner corners ("vertices"), index row * (columns - 1) + col."""

    columns: int
    rows: int
    square_m: float = float("nan")
    colours: tuple[str, str] | None = None

    def __post_init__(self):
        for name in ("columns", "rows"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or not 3 <= value <= 40:
                raise ValueError(f"board {name} must be a whole number of squares from 3 to 40, got {value!r}")
        if not (np.isnan(self.square_m) or self.square_m > 0):
            raise ValueError(f"board square_m must be positive (or nan when unknown), got {self.square_m!r}")
        if self.colours is not None:
            if len(self.colours) != 2 or self.colours[0] == self.colours[1]:
                raise ValueError(f"board colours must be two different names, got {self.colours!r}")
            for colour in self.colours:
                if colour not in COLOURS_BGR:
                    raise ValueError(f"unknown board colour {colour!r}: expected one of {sorted(COLOURS_BGR)}")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of inner corners."""
        return self.rows - 1, self.columns - 1

    @property
    def n_corners(self) -> int:
        return (self.rows - 1) * (self.columns - 1)

    def __str__(self) -> str:
        return f"{self.columns} x {self.rows}"


SANDAL = BoardSpec(BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M, ("black", "white"))
"""The NAO's checkerboard sandal (docs/CONVENTIONS.md): 7 x 5 squares of 25 mm, black corner squares."""


def parse_board(text: str) -> BoardSpec:
    """'COLSxROWS' (squares, e.g. '7x5', '4x4') -> BoardSpec with unknown colours. ValueError when malformed."""
    parts = text.lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise ValueError(f"board {text!r}: expected COLUMNSxROWS in squares, e.g. 7x5")
    return BoardSpec(int(parts[0]), int(parts[1]))


@dataclass(frozen=True)
class BoardDetection:
    """The result of one detection.

    vertices_px : (n, 2) in board order when `ok`, else None.
    reason : one of REASONS when not ok.
    image_order_px : (n, 2) the corners in image order (module docstring) whenever they were located - also when
        the board order could not be told (`ambiguous`).
    edge_width_px : 10 %-90 % rise distance of the board's edges (estimateChessboardSharpness).
    channel : the image channel the corners were found and refined in.
    line_rms_px : RMS distance of the corners from straight lines fitted to each row and column.
    """

    vertices_px: np.ndarray | None
    reason: str | None = None
    detail: str = ""
    edge_width_px: float = float("nan")
    image_order_px: np.ndarray | None = None
    channel: str = ""
    line_rms_px: float = float("nan")
    asymmetry: float = float("nan")  # the largest corner_asymmetry of the refined corners

    @property
    def ok(self) -> bool:
        return self.vertices_px is not None


def failure(reason: str, detail: str, **extra) -> BoardDetection:
    return BoardDetection(vertices_px=None, reason=reason, detail=detail, **extra)


# ---------------------------------------------------------------------------------------------------- channels

def channel_image(image: np.ndarray, channel: str) -> np.ndarray:
    """(h, w) uint8 channel of a (h, w, 3) BGR or (h, w) grey image: 'grey' (Y of YCrCb), 'cr' or 'cb'."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit image, got {image.dtype}")
    if image.ndim == 2:
        if channel != "grey":
            raise ValueError(f"a grey image has no {channel!r} channel")
        return image
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected a (h, w, 3) BGR or (h, w) grey image, got shape {image.shape}")
    if channel == "grey":
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if channel in ("cr", "cb"):
        return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)[..., 1 if channel == "cr" else 2])
    raise ValueError(f"unknown channel {channel!r}: expected one of {CHANNELS}")


def _nominal_values(colour: str) -> dict:
    ycc = cv2.cvtColor(np.uint8([[COLOURS_BGR[colour]]]), cv2.COLOR_BGR2YCrCb)[0, 0].astype(float)
    return {"grey": ycc[0], "cr": ycc[1], "cb": ycc[2]}


def polarity(board: BoardSpec, channel: str) -> int:
    """+1 when the board's first colour is the brighter in `channel`, -1 when darker, 0 when unknown or alike."""
    if board.colours is None:
        return 0
    first, second = (_nominal_values(c)[channel] for c in board.colours)
    return int(np.sign(first - second)) if abs(first - second) >= 20 else 0


def channels_to_try(image: np.ndarray, board: BoardSpec, channel: str = "auto") -> tuple[str, ...]:
    """The channels `detect_board` searches: the one asked for, or for 'auto' those that separate the board's
    colours (all three when they are unknown; grey only for a grey image)."""
    if channel != "auto":
        if channel not in CHANNELS:
            raise ValueError(f"unknown channel {channel!r}: expected auto or one of {CHANNELS}")
        return (channel,)
    if np.asarray(image).ndim == 2:
        return ("grey",)
    if board.colours is None:
        return CHANNELS
    first, second = (_nominal_values(c) for c in board.colours)
    separation = {c: abs(first[c] - second[c]) for c in CHANNELS}
    best = max(separation.values())
    return tuple(sorted((c for c in CHANNELS if separation[c] >= MIN_CHANNEL_SHARE * best),
                        key=lambda c: -separation[c]))


# ------------------------------------------------------------------------------------------------- grid orders

def labellings(grid: np.ndarray):
    """The 8 labellings of a (h, w, 2) grid: (name, array) for turns and mirror images."""
    out = []
    for transposed in (False, True):
        base = np.swapaxes(grid, 0, 1) if transposed else grid
        for rows_reversed in (False, True):
            for columns_reversed in (False, True):
                g = base[::-1] if rows_reversed else base
                g = g[:, ::-1] if columns_reversed else g
                out.append(((transposed, rows_reversed, columns_reversed), g))
    return out


def _directions(grid: np.ndarray):
    """Mean unit directions (2,) along the rows (increasing column) and down the columns (increasing row)."""
    along_row = (grid[:, -1] - grid[:, 0]).mean(axis=0)
    along_column = (grid[-1] - grid[0]).mean(axis=0)
    return (along_row / max(np.linalg.norm(along_row), 1e-12),
            along_column / max(np.linalg.norm(along_column), 1e-12))


def image_order(grid: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The grid's labelling (shape (rows, columns), a turn or mirror image of `grid`) in image order: rows that run
    most nearly left to right and follow each other most nearly downwards (the largest sum of the two mean
    directions' components along +u and +v)."""
    best, best_score = None, -np.inf
    for _, g in labellings(grid):
        if g.shape[:2] != tuple(shape):
            continue
        along_row, along_column = _directions(g)
        score = along_row[0] + along_column[1]
        if score > best_score + 1e-9:
            best, best_score = g, score
    return best


def _board_labellings(grid: np.ndarray, cells: np.ndarray, board: BoardSpec, brighter_even: int, sign: int):
    """The labellings of `grid` (h, w, 2) that can be the board's own: its shape, the printed face's handedness
    (board x to y turns clockwise in the image, whose v axis points down), and when the polarity is known
    (`sign` = polarity(board, channel), `brighter_even` = +1 when the squares of even lattice parity are the
    brighter) the first colour on square (0, 0). `cells` (h, w, 2) are the lattice coordinates of the corners."""
    out = []
    for (key, g), (_, c) in zip(labellings(grid), labellings(cells)):
        if g.shape[:2] != board.shape:
            continue
        along_row, along_column = _directions(g)
        if along_row[0] * along_column[1] - along_row[1] * along_column[0] >= 0:
            continue  # a mirror image
        if sign and brighter_even:
            centre = c[0, 0] - 0.5 * (c[0, 1] - c[0, 0]) - 0.5 * (c[1, 0] - c[0, 0])  # square (0, 0)
            even = int(np.floor(centre[0]) + np.floor(centre[1])) % 2 == 0
            if (brighter_even if even else -brighter_even) != sign:
                continue
        out.append(g)
    return out


# ---------------------------------------------------------------------------------------- refinement, checks

def corner_asymmetry(grey: np.ndarray, corners_px: np.ndarray, radius_px: int) -> np.ndarray:
    """(n,) How far each corner's neighbourhood is from point symmetry: mean |I(c + d) - I(c - d)| over a disc
    of `radius_px`, over the patch's contrast (p95 - p5). About 0.02 for a clean rendered X-corner (straight edges
    through it, also under perspective), 0.05-0.1 on real pixels; an L-corner gives 0.5, an occluding edge (the
    toe, the other leg) or damage near a corner raises it."""
    corners_px = np.asarray(corners_px, float).reshape(-1, 2)
    return symmetry_and_contrast(grey, corners_px, np.full(len(corners_px), int(radius_px)))[0]


def refine_clean(channel: np.ndarray, start: np.ndarray, half: int, grid_xy: np.ndarray,
                 max_asymmetry: float | None = None, refine_first: bool = True):
    """cornerSubPix of every corner (n, 2) in a window of `half` px, shrunk (down to 2 px) for the corners whose
    window holds something that is not their X-corner (an occluding edge near a corner pulls it:
    `corner_asymmetry` above a limit: 3 times the median of the board's corners in a window of the same size,
    within 0.03 and MAX_ASYMMETRY (noise and blur make all corners of a board about as asymmetric); or, when
    `max_asymmetry` is given, that or 3 times the board's median in the first window, whichever is larger,
    for all window sizes); those restart from the homography of the clean ones (`grid_xy` (n, 2): the corners'
    lattice coordinates). With refine_first=False the start positions (already refined by a
    detector) are only checked, and re-refined where unclean. Returns ((n, 2), asymmetry (n,), '') or
    (None, asymmetry, why)."""
    start = np.asarray(start, dtype=float)
    if not np.all(inside(start, channel.shape, half + 1)):
        return None, None, "a vertex lies at the edge of the searched region"
    refined = _subpix(channel, start, half) if refine_first else start.copy()
    asymmetry = corner_asymmetry(channel, refined, half)
    adaptive = max_asymmetry is None
    limit = _asymmetry_limit(asymmetry) if adaptive else max(max_asymmetry, 3.0 * float(np.median(asymmetry)))
    bad = asymmetry > limit
    smaller = half
    while bad.any() and smaller > 2 and (~bad).sum() >= max(4, len(start) // 3):
        smaller = max(2, int(smaller * 0.6))
        H = homography(grid_xy[~bad], refined[~bad])
        if H is None:
            break
        guess = apply_homography(H, grid_xy)
        retry = np.flatnonzero(bad)
        if not np.all(inside(guess[retry], channel.shape, smaller + 1)):
            return None, asymmetry, "a vertex lies at the edge of the searched region"
        refined[retry] = _subpix(channel, guess[retry], smaller)
        asymmetry[retry] = corner_asymmetry(channel, refined[retry], smaller)
        if adaptive:  # smaller windows look less symmetric (fewer pixels, sampling): compare like with like
            limit = _asymmetry_limit(corner_asymmetry(channel, refined[~bad], smaller))
        bad = asymmetry > limit
    if bad.any():
        return None, asymmetry, (f"vertices {np.flatnonzero(bad).tolist()} are partly hidden: neighbourhood "
                                 f"asymmetry up to {asymmetry.max():.2f} even in a {2 * smaller + 1} px window")
    drift = np.linalg.norm(refined - start, axis=1)
    if np.any(drift > 3.0 * half):
        return None, asymmetry, f"a vertex refinement wandered {drift.max():.1f} px"
    return refined, asymmetry, ""


def _asymmetry_limit(asymmetry: np.ndarray) -> float:
    return float(np.clip(3.0 * np.median(asymmetry), 0.03, MAX_ASYMMETRY))


def _subpix(channel: np.ndarray, start: np.ndarray, half: int) -> np.ndarray:
    return cv2.cornerSubPix(channel, start.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1),
                            (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)).reshape(-1, 2).astype(float)


def line_rms_px(grid: np.ndarray) -> float:
    """RMS distance (px) of a (h, w, 2) grid's points from the straight line fitted to each row and column
    (total least squares); nan for lines of fewer than 3 points only."""
    residuals = []
    for lines in (grid, np.swapaxes(grid, 0, 1)):
        for line in lines:
            if len(line) < 3:
                continue
            centred = line - line.mean(axis=0)
            normal = np.linalg.svd(centred)[2][1]
            residuals.append(centred @ normal)
    return float(np.sqrt(np.mean(np.concatenate(residuals) ** 2))) if residuals else float("nan")


def edge_width_px(channel: np.ndarray, grid: np.ndarray) -> float:
    """10 %-90 % rise distance (px) of the board's edges between the corners of a (h, w, 2) grid, averaged over
    the edges of each of the two families (OpenCV's estimateChessboardSharpness), the worse family: about 1.5-2 px
    for a sharp image, more with defocus or motion blur (which widens only the edges across the motion)."""
    h, w = grid.shape[:2]
    corners = grid.reshape(-1, 1, 2).astype(np.float32)
    widths = [cv2.estimateChessboardSharpness(channel, (w, h), corners, 0.8, vertical)[0][0]
              for vertical in (False, True)]
    return float(max(widths))


# ------------------------------------------------------------------------------------------------ the board

@dataclass
class _ChannelResult:
    """What one channel shows: a complete board (grid, cells, ...) or a failure (reason, detail), and how many of
    the board's corners it found (to choose what to report)."""

    channel: str
    found: int
    reason: str | None = None
    detail: str = ""
    lattice_size: int = 0  # corners in the lattice behind a failure (to report the best-supported one)
    grid: np.ndarray | None = None  # (h, w, 2) refined, in lattice labelling
    cells: np.ndarray | None = None  # (h, w, 2) lattice coordinates
    asymmetry: np.ndarray | None = None
    brighter_even: int = 0
    contrast: float = float("nan")
    cnr: float = float("nan")  # contrast between the squares over the noise within them
    others: int = 0  # further complete boards in this channel


def _window_count(filled: np.ndarray, x0: int, y0: int, w: int, h: int) -> int:
    return int(filled[max(y0, 0):max(y0 + h, 0), max(x0, 0):max(x0 + w, 0)].sum())


def _full_rectangle(filled: np.ndarray, x0: int, y0: int, w: int, h: int):
    """Grow a complete window of the lattice by every complete line of corners next to it."""
    H_, W_ = filled.shape
    grown = True
    while grown:
        grown = False
        if y0 > 0 and filled[y0 - 1, x0:x0 + w].all():
            y0, h, grown = y0 - 1, h + 1, True
        if y0 + h < H_ and filled[y0 + h, x0:x0 + w].all():
            h, grown = h + 1, True
        if x0 > 0 and filled[y0:y0 + h, x0 - 1].all():
            x0, w, grown = x0 - 1, w + 1, True
        if x0 + w < W_ and filled[y0:y0 + h, x0 + w].all():
            w, grown = w + 1, True
    return x0, y0, w, h


@dataclass
class _Placement:
    """A lattice matched to the board: `window` (x0, y0, w, h) in lattice coordinates, `start` (h, w, 2) the
    corners (found, or predicted from the found ones where `predicted`; `detail` then says what was found), or
    a failure (reason, detail)."""

    count: int
    reason: str | None = None
    detail: str = ""
    lattice_size: int = 0
    window: tuple | None = None
    start: np.ndarray | None = None
    predicted: np.ndarray | None = None


def _locate(lattice: dict, cands: Candidates, board: BoardSpec, shape) -> _Placement:
    """Match one lattice to the board: a complete window of the board's size (in either orientation), unless a
    further complete line of corners makes it a bigger board; or a window short of at most a quarter of its
    corners, all inside the image (a corner the candidate filter dropped: predicted here, checked after
    refinement); or `cut_off` when the missing corners of a window lie beyond the image edge, or `missing`."""
    keys = np.array(list(lattice))
    origin = keys.min(axis=0)
    W, H_ = keys.max(axis=0) - origin + 1
    filled = np.zeros((H_, W), bool)
    filled[keys[:, 1] - origin[1], keys[:, 0] - origin[0]] = True
    n = board.n_corners
    best, windows = -1, []
    for h, w in sorted({board.shape, board.shape[::-1]}):
        for y0 in range(-(h - 1), H_):
            for x0 in range(-(w - 1), W):
                count = _window_count(filled, x0, y0, w, h)
                if count > best:
                    best, windows = count, []
                if count == best:
                    windows.append((x0, y0, w, h))
    if best == n:
        for window in windows:
            fx0, fy0, fw, fh = _full_rectangle(filled, *window)
            if (fw, fh) != window[2:]:
                return _Placement(best, "missing", f"the corners form a complete {fw} x {fh} grid: a board of "
                                                   f"{fw + 1} x {fh + 1} squares, not {board}", len(lattice))
        if len(lattice) >= n + min(board.shape):  # a line of corners more, not quite complete
            return _Placement(best, "missing", f"the grid of corners is larger than the board's: {len(lattice)} "
                                               f"corners within {W} x {H_}, not {board}", len(lattice))
    if filled.all():
        shortfall = (f"only {best} of {n} corners found: they form a complete {W} x {H_} grid, as a board of "
                     f"{W + 1} x {H_ + 1} squares would")
    else:
        shortfall = (f"only {best} of {n} corners found (the largest grid of checkerboard corners has "
                     f"{len(lattice)}, within {W} x {H_})")
    points = cands.points[list(lattice.values())]
    H_all = quick_homography(keys, points)
    cut_off = False
    for x0, y0, w, h in windows:
        xs, ys = np.meshgrid(np.arange(x0, x0 + w), np.arange(y0, y0 + h))
        in_lattice = (xs >= 0) & (ys >= 0) & (xs < W) & (ys < H_)
        have = in_lattice & filled[np.clip(ys, 0, H_ - 1), np.clip(xs, 0, W - 1)]
        cells = np.stack([xs, ys], axis=-1) + origin
        start = np.zeros((h, w, 2))
        for (y, x) in zip(*np.nonzero(have)):
            start[y, x] = cands.points[lattice[tuple(cells[y, x])]]
        if not have.all():
            if H_all is None:
                continue
            start[~have] = apply_homography(H_all, cells[~have])
            if not np.all(inside(start[~have], shape, 3.0)):
                cut_off |= best >= n / 2 and np.sum(inside(start[~have], shape, 3.0)) <= n // 4
                continue
            if (~have).sum() > n // 4:
                continue
            near_all = _predict_locally(keys, points, cells[~have])
            start[~have] = np.where(np.isfinite(near_all), near_all, start[~have])
        return _Placement(best, None, shortfall, len(lattice), (x0 + origin[0], y0 + origin[1], w, h), start,
                          ~have)
    if cut_off:
        return _Placement(best, "cut_off", f"{best} of {n} corners found; the others lie at or beyond the image "
                                           "edge", len(lattice))
    return _Placement(best, "missing", shortfall, len(lattice))


def _predict_locally(keys: np.ndarray, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Each cell's position (k, 2) from a homography of the lattice's corners within 2 cells of it (nan when
    too few)."""
    out = np.full((len(cells), 2), np.nan)
    for i, cell in enumerate(cells):
        near = np.max(np.abs(keys - cell), axis=1) <= 2
        H = quick_homography(keys[near], points[near]) if near.sum() >= 5 else None
        if H is not None:
            out[i] = apply_homography(H, cell[None].astype(float))[0]
    return out


def _boards(image: np.ndarray, channels: tuple[str, ...], board: BoardSpec) -> list[_ChannelResult]:
    """The board in each channel that can show it best: our own lattices channel by channel, skipping a channel
    in which the squares of a board already found differ less for their noise than in the channel that found it
    (the one kept would be that one; a black/white board is not searched for in Cr and Cb again). Where no channel
    has it: a second opinion, OpenCV's detectors, which see small, blurred, compressed boards that fail the X-corner
    checks (a 10-px square's corner is never point-symmetric after JPEG); they need the whole board, so they cannot
    say why a board is missing: the own results' reasons are kept. Returns the channels' results, those with a
    board first."""
    found, failed = [], []
    for attempt in (_own_lattices, _opencv_board):
        for channel in channels:
            img = channel_image(image, channel)
            if found and _weaker_channel(img, found):
                continue
            result = attempt(img, channel, board)
            if result is not None:
                (found if result.grid is not None else failed).append(result)
        if found:
            break
    return found + failed


def _weaker_channel(img: np.ndarray, found: list[_ChannelResult]) -> bool:
    """Whether the squares of the strongest board found so far differ less for their noise in `img` than in the
    channel that found it."""
    best = max(found, key=lambda r: r.cnr)
    ok, contrast, noise = alternation(img, best.cells.reshape(-1, 2).astype(float), best.grid.reshape(-1, 2))
    return abs(contrast) / max(noise, 0.5) <= best.cnr


def _own_lattices(img: np.ndarray, channel: str, board: BoardSpec) -> _ChannelResult:
    cands = saddle_candidates(img)
    lattices = find_lattices(cands, img)
    if not lattices:
        return _ChannelResult(channel, 0, "missing", f"no grid of checkerboard corners in {channel}")
    placements = [(_locate(lattice, cands, board, img.shape), lattice) for lattice in lattices]
    usable = [(p, float(np.median(cands.strength[list(lattice.values())]))) for p, lattice in placements
              if p.reason is None]
    if not usable:
        worst = max((p for p, _ in placements), key=lambda p: (p.count, p.lattice_size))
        return _ChannelResult(channel, worst.count, worst.reason, f"{worst.detail} in {channel}", worst.lattice_size)
    usable.sort(key=lambda item: (-item[0].count, -item[1]))
    passed, failed = [], []
    for place, _ in usable:
        result = _verify(img, channel, board, place)
        (passed if result.grid is not None else failed).append(result)
    if not passed:
        return failed[0]
    best = max(passed, key=lambda r: _area_px(r.grid))  # the nearest board, when there are several
    best.others = len(passed) - 1
    return best


def _opencv_board(img: np.ndarray, channel: str, board: BoardSpec) -> _ChannelResult | None:
    """The board by cv2.findChessboardCornersSB or the classic detector (each refined by cornerSubPix), checked as
    ours are: the squares must alternate, and every corner must lie on the plane's homography through the others
    (within OPENCV_PLANE_TOLERANCE squares, at least 2 px: SB now and then puts one corner several px off).
    None if neither gives such a board."""
    rows, columns = board.shape
    if min(rows, columns) < 3:  # OpenCV's detectors need 3 x 3 inner corners
        return None
    xs, ys = np.meshgrid(np.arange(columns), np.arange(rows))
    cells = np.stack([xs, ys], axis=-1)
    cells_xy = cells.reshape(-1, 2).astype(float)
    # On a large image they search a half-size copy (each halving cuts their time by about 4; a 1280 x 960 frame
    # took them 2-4 s per channel without a board, and boards of squares under 12 px are our lattices' anyway);
    # the corners are refined at full size. The classic detector's fast check refuses an image without a board.
    small, scale = img, 1
    while small.shape[1] > OPENCV_MAX_WIDTH_PX:
        small, scale = cv2.pyrDown(small), 2 * scale
    attempts = (lambda: cv2.findChessboardCornersSB(small, (columns, rows),
                                                    flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY),
                lambda: cv2.findChessboardCorners(small, (columns, rows), flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                                  | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK))
    for attempt in attempts:
        found, corners = attempt()
        if not found:
            continue
        grid = (corners.reshape(rows, columns, 2).astype(float) + 0.5) * scale - 0.5  # pixel centres: OpenCV's
        side = min(float(np.linalg.norm(np.diff(grid, axis=a), axis=-1).min()) for a in (0, 1))
        half = max(2, int(round(REFINE_WINDOW * side)))
        refined = cv2.cornerSubPix(img, grid.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.01)).reshape(-1, 2)
        if _off_plane_px(cells_xy, refined).max() > max(2.0, OPENCV_PLANE_TOLERANCE * side):
            continue
        # a corner partly hidden (a foot, a robot, a line over it) is put on the occluder's edge, within the plane
        # tolerance of a large square: held to the X-corner symmetry as ours are, relative to the board's own
        refined, asymmetry, _ = refine_clean(img, refined, half, cells_xy, MAX_ASYMMETRY, refine_first=False)
        if refined is None:
            continue
        ok, contrast, noise = alternation(img, cells_xy, refined)
        if not ok or not _all_squares_alternate(img, cells_xy, refined, contrast, rows, columns) or \
                _continues_beyond(img, cells_xy, refined, contrast, rows, columns):
            continue
        return _ChannelResult(channel, board.n_corners, grid=refined.reshape(rows, columns, 2).astype(float),
                              cells=cells, asymmetry=asymmetry,
                              brighter_even=int(np.sign(contrast)), contrast=abs(contrast),
                              cnr=abs(contrast) / max(noise, 0.5))
    return None


def _square_agreement(img, H, squares, contrast: float, middle: float) -> np.ndarray:
    """For each square wholly in the image: whether it is on its parity's side of `middle` (nan-free bool array)."""
    values, _ = square_stats_at(img, H, squares)
    seen = np.isfinite(values)
    even = (squares[seen, 0] + squares[seen, 1]) % 2 == 0
    return np.sign(values[seen] - middle) == np.where(even, 1, -1) * np.sign(contrast)


def _all_squares_alternate(img, cells_xy, points, contrast: float, rows: int, columns: int) -> bool:
    """Every square of the board in view, its outer ring too, alternates (alternation() allows a quarter of the
    outer ones to fail: OpenCV, not checking X-corners, otherwise takes a board's edge on the carpet for corners)."""
    H = homography(cells_xy, points)
    if H is None:
        return False
    xs, ys = np.meshgrid(np.arange(-1, columns), np.arange(-1, rows))
    squares = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    values, _ = square_stats_at(img, H, squares)
    middle = float(np.nanmean(values))
    return bool(_square_agreement(img, H, squares, contrast, middle).all())


def _continues_beyond(img, cells_xy, points, contrast: float, rows: int, columns: int) -> bool:
    """Whether the checkerboard goes on past a side of the board's outer squares (OpenCV finds a board of the size
    asked for inside a bigger one; ours refuses to cut a board down to size, and so must this): on a real board
    the squares beyond are its plain margin, of which only half can match the alternation."""
    H = homography(cells_xy, points)
    if H is None:
        return False
    # squares by their lower lattice corner: the board's are x in [-1, columns - 1], y in [-1, rows - 1]
    sides = ([(-2, y) for y in range(-1, rows)], [(columns, y) for y in range(-1, rows)],
             [(x, -2) for x in range(-1, columns)], [(x, rows) for x in range(-1, columns)])
    middle = float(np.nanmean(square_stats_at(img, H, cells_xy)[0]))
    for side in sides:
        agree = _square_agreement(img, H, np.array(side, dtype=float), contrast, middle)
        if len(agree) >= 3 and agree.mean() >= 0.9:
            return True
    return False


def _off_plane_px(cells_xy: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) each corner's distance from where the homography fitted to all the others puts it."""
    out = np.empty(len(points))
    for i in range(len(points)):
        keep = np.arange(len(points)) != i
        H = homography(cells_xy[keep], points[keep])
        out[i] = np.inf if H is None else float(np.linalg.norm(apply_homography(H, cells_xy[i:i + 1])[0] - points[i]))
    return out


def _area_px(grid: np.ndarray) -> float:
    """Area (px^2) of the quadrilateral of a (h, w, 2) grid's outer corners."""
    a, b, c, d = grid[0, 0], grid[0, -1], grid[-1, -1], grid[-1, 0]
    return 0.5 * abs((c[0] - a[0]) * (d[1] - b[1]) - (d[0] - b[0]) * (c[1] - a[1]))


def _verify(img: np.ndarray, channel: str, board: BoardSpec, place: _Placement) -> _ChannelResult:
    """Refine a placement's corners (refine_clean) and check that the squares around them alternate."""
    x0, y0, w, h = place.window
    start = place.start.reshape(-1, 2)
    steps = np.concatenate([np.linalg.norm(np.diff(place.start, axis=a), axis=-1).ravel() for a in (0, 1)])
    side = float(steps.min())
    half = max(2, int(round(REFINE_WINDOW * side)))
    xs, ys = np.meshgrid(np.arange(x0, x0 + w), np.arange(y0, y0 + h))
    cells = np.stack([xs, ys], axis=-1)
    grid_xy = cells.reshape(-1, 2).astype(float)
    refined, asymmetry, problem = refine_clean(img, start, half, grid_xy)
    if refined is None:
        if place.predicted.any():
            return _ChannelResult(channel, place.count, "missing", f"{place.detail}; where the others would be are "
                                  f"no clean X-corners, in {channel}", place.lattice_size)
        return _ChannelResult(channel, place.count, "missing" if "hidden" in problem else "cut_off",
                              f"{problem} in {channel}", place.lattice_size)
    ok, contrast, noise = alternation(img, grid_xy, refined)
    if not ok:
        return _ChannelResult(channel, place.count, "missing", f"the squares around the corners do not alternate "
                              f"like a checkerboard's in {channel}", place.lattice_size)
    # contrast to noise: how well this channel separates the squares (corner precision goes with its inverse)
    return _ChannelResult(channel, board.n_corners, grid=refined.reshape(h, w, 2), cells=cells,
                          asymmetry=asymmetry, brighter_even=int(np.sign(contrast)), contrast=abs(contrast),
                          cnr=abs(contrast) / max(noise, 0.5))


def detect_board(image: np.ndarray, board: BoardSpec, *, channel: str = "auto",
                 max_edge_width_px: float | None = None) -> BoardDetection:
    """The board's inner corners in an image, without a prediction (module docstring).

    Parameters
    ----------
    image : (h, w, 3) uint8 BGR or (h, w) uint8 grey, any size.
    board : the board to look for.
    channel : 'auto' (the channels that separate the board's colours, or all), 'grey', 'cr' or 'cb'.
    max_edge_width_px : edges wider than this make the board `blurred`; None: no limit (the width is reported).

    Returns a BoardDetection: `ok` with the corners in board order when the board and its orientation are
    found; `ambiguous` with `image_order_px` when the board is found but its orientation cannot be told, or when
    several boards are in view (then the largest's corners); `missing`, `cut_off` or `blurred` otherwise.
    """
    results = _boards(image, channels_to_try(image, board, channel), board)
    good = [r for r in results if r.grid is not None]
    if not good:
        worst = max(results, key=lambda r: (r.found, r.lattice_size))
        return failure(worst.reason, worst.detail)
    best = max(good, key=lambda r: r.cnr)
    img = channel_image(image, best.channel)
    ordered = image_order(best.grid, board.shape)
    width = edge_width_px(img, ordered)
    common = dict(image_order_px=ordered.reshape(-1, 2), channel=best.channel, line_rms_px=line_rms_px(ordered),
                  asymmetry=float(best.asymmetry.max()), edge_width_px=width)
    summary = (f"{board.n_corners} corners in {best.channel}, line fit {common['line_rms_px']:.2f} px RMS, "
               f"edges {width:.1f} px wide")
    if max_edge_width_px is not None and width > max_edge_width_px:
        return failure("blurred", f"edges {width:.2f} px wide (limit {max_edge_width_px})", **common)
    if best.others:
        return failure("ambiguous", f"{best.others + 1} boards of {board} squares in view (corners of the largest "
                                    "in image_order_px); " + summary, **common)
    options = _board_labellings(best.grid, best.cells, board, best.brighter_even, polarity(board, best.channel))
    if len(options) != 1:
        why = ("its colours' polarity in this channel is unknown" if polarity(board, best.channel) == 0 and
               board.colours is None else "it looks the same turned")
        return failure("ambiguous", f"found, but the board's orientation cannot be told ({len(options)} "
                                    f"orientations fit: {why}); " + summary, **common)
    return BoardDetection(vertices_px=options[0].reshape(-1, 2), detail=summary, **common)
