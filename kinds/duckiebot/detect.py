"""What a Duckiebot's camera sees for calibration: AprilTag 36h11 floor markers and upright chessboards.

Markers: OpenCV's class API (`cv2.aruco.ArucoDetector` with `getPredefinedDictionary(DICT_APRILTAG_36h11)`; the old
free functions are gone from OpenCV 4.14 and 5.0), corners refined to sub-pixel. Corners come in the detector's
order: clockwise from the marker image's top-left corner (as cv2.aruco.generateImageMarker draws it).

Boards: agent.board_detect (naocal's one chessboard detector), repeatedly, covering each board found, for the 2-3
boards of the set-up. A board of 7 x 5 inner corners (8 x 6 squares) looks the same turned by 180 deg, so its board
order cannot come from one image: the corners are returned in image order (rows left to right, row 0 at the top),
which for an upright board seen by an upright camera is the board's top row first, left to right.
Pixel convention: (0, 0) is the centre of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from naocal.agent.board_detect import BoardSpec, channel_image, detect_board

MARKER_FAMILIES = {"tag36h11": cv2.aruco.DICT_APRILTAG_36h11}
MAX_BOARDS = 3  # the set-up's boards on their semicircle; never more in one image


@dataclass(frozen=True)
class MarkerSighting:
    id: int
    corners_px: np.ndarray  # (4, 2): clockwise from the marker image's top-left


@dataclass(frozen=True)
class BoardSighting:
    corners_px: np.ndarray  # (rows, columns, 2) inner corners in image order
    detail: str


@lru_cache(maxsize=None)
def _marker_detector(family: str) -> cv2.aruco.ArucoDetector:
    if family not in MARKER_FAMILIES:
        raise ValueError(f"unsupported marker family {family!r} (expected one of {', '.join(MARKER_FAMILIES)})")
    parameters = cv2.aruco.DetectorParameters()
    # sub-pixel corners (OpenCV's default refines nothing). On rendered floor markers (docs/DUCKIEBOT.md, seed 3)
    # a window of half a marker cell is best: corners of markers whose sides are all >= 20 px within 0.37 px
    # (0.25 px RMS); 0.3 cells (OpenCV's default) 1.0 px, 0.7 cells 2.3 px. CORNER_REFINE_APRILTAG and CONTOUR
    # were worse (1.2 and 0.9 px RMS, seed 1).
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    parameters.cornerRefinementWinSize = 4
    parameters.relativeCornerRefinmentWinSize = 0.5  # (sic: OpenCV's spelling)
    parameters.cornerRefinementMaxIterations = 50
    parameters.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(MARKER_FAMILIES[family]), parameters)


def refinement_window_px(quad: np.ndarray, family: str = "tag36h11") -> int:
    """The half-width of OpenCV's cornerSubPix window for a detected quad (4, 2) with this module's settings
    (ArucoDetector: relativeCornerRefinmentWinSize x the mean marker cell, rounded, 1 at least, at most
    cornerRefinementWinSize). The corners' inward bias is about 1 px^2 over it (docs/DUCKIEBOT.md, "The detector's
    corner error, measured")."""
    parameters = _marker_detector(family).getDetectorParameters()
    cell = np.linalg.norm(np.roll(quad, -1, axis=0) - quad, axis=1).sum() / (4 * 8)  # tag36h11: 8 cells a side
    return int(min(parameters.cornerRefinementWinSize,
                   max(1, round(parameters.relativeCornerRefinmentWinSize * cell))))


def detect_markers(image: np.ndarray, family: str = "tag36h11") -> list[MarkerSighting]:
    """The markers of `family` in a BGR or grey uint8 image, sorted by id (each id once: a second sighting of an id
    is dropped with the first, since which is the true one cannot be told)."""
    return detect_markers_and_repeats(image, family)[0]


def detect_markers_and_repeats(image: np.ndarray, family: str = "tag36h11") -> tuple[list[MarkerSighting], list]:
    """(detect_markers' sightings, the ids seen more than once, dropped from them): a caller can tell a log whose
    markers share an id from one where none was seen."""
    grey = channel_image(image, "grey")
    corners, ids, _ = _marker_detector(family).detectMarkers(grey)
    if ids is None:
        return [], []
    ids = ids.ravel()
    unique, counts = np.unique(ids, return_counts=True)
    once = set(unique[counts == 1].tolist())
    return sorted((MarkerSighting(int(i), np.asarray(c, dtype=float).reshape(4, 2)) for i, c in zip(ids, corners)
                   if int(i) in once), key=lambda s: s.id), unique[counts > 1].tolist()


def detect_boards(image: np.ndarray, inner_corners: tuple[int, int], square_m: float = float("nan"),
                  max_boards: int = MAX_BOARDS) -> list[BoardSighting]:
    """The chessboards of `inner_corners` (columns, rows) in an image, largest first, each with its corners in image
    order (module docstring). A board found is covered (its hull filled with the image's median) and the search
    repeated, so boards side by side are each found."""
    columns, rows = inner_corners
    spec = BoardSpec(columns + 1, rows + 1, square_m)
    work = np.array(image, copy=True)
    found = []
    for _ in range(max_boards):
        result = detect_board(work, spec, channel="grey")
        if result.image_order_px is None:
            break
        grid = result.image_order_px.reshape(rows, columns, 2)
        found.append(BoardSighting(grid, result.detail))
        _cover(work, grid)
    return found


def _cover(image: np.ndarray, grid: np.ndarray) -> None:
    """Fill a found board (its inner corners' hull grown by two squares) with the image's median."""
    centre = grid.reshape(-1, 2).mean(axis=0)
    # one square beyond the inner corners reaches the board's edge (more along a diagonal); two are safe
    square_px = (np.linalg.norm(np.diff(grid, axis=1), axis=-1).mean() +
                 np.linalg.norm(np.diff(grid, axis=0), axis=-1).mean()) / 2.0
    outline = np.concatenate([grid[0], grid[:, -1], grid[-1, ::-1], grid[::-1, 0]])
    away = outline - centre
    away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
    hull = cv2.convexHull((outline + away * 2.0 * square_px).astype(np.float32)).astype(np.int32)
    fill = np.median(image.reshape(-1, image.shape[-1]) if image.ndim == 3 else image.ravel(), axis=0)
    cv2.fillConvexPoly(image, hull, fill.tolist() if np.ndim(fill) else float(fill))
