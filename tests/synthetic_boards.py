"""Checkerboards seen by a pinhole camera, rendered with exact anti-aliasing, and their exact inner corners.

A board of `columns` x `rows` squares lies in its plane with x along the columns and y along the rows, in units of
squares; square (i, j) covers [i, i + 1] x [j, j + 1] and has the first colour when i + j is even (square (0, 0),
before vertex 0, is the first colour: agent.board_detect's board order). Its printed face looks towards the
camera: board x to y turns clockwise in the image, as a real camera sees a real board. Each output pixel averages
`supersample`^2 samples of the exact scene; pixel (0, 0) is the centre of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

BGR = {"black": (25, 25, 25), "white": (235, 235, 235), "orange": (40, 110, 245), "blue": (190, 120, 40),
       "green": (60, 160, 50), "grey": (128, 128, 128)}


@dataclass
class Scene:
    image: np.ndarray  # (h, w, 3) uint8 BGR
    corners_px: np.ndarray  # (rows - 1, columns - 1, 2) in board order: [row][col]
    H: np.ndarray  # board (x, y, 1) in squares -> pixel


def rot(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def board_homography(columns: int, rows: int, *, size=(640, 480), square_px: float = 40.0,
                     tilt_x: float = 0.0, tilt_y: float = 0.0, turn: float = 0.0, shift_px=(0.0, 0.0),
                     focal_px: float = 550.0) -> np.ndarray:
    """Board (x, y, 1) in squares -> pixels for a board facing the camera, its centre `square_px` per square
    from the image centre (+ shift_px), turned in its plane by `turn` and tilted about x and y (rad)."""
    w, h = size
    K = np.array([[focal_px, 0, (w - 1) / 2], [0, focal_px, (h - 1) / 2], [0, 0, 1]])
    distance = focal_px / square_px  # in squares
    R = rot("x", tilt_x) @ rot("y", tilt_y) @ np.diag([1.0, -1.0, -1.0]) @ rot("z", turn)
    t = np.array([shift_px[0] / square_px, shift_px[1] / square_px, distance])
    centre = np.array([columns / 2, rows / 2])
    M = np.column_stack([R[:, 0], R[:, 1], t - R[:, :2] @ centre])
    H = K @ M
    return H / H[2, 2]


def render(columns: int, rows: int, H: np.ndarray, *, size=(640, 480), colours=("black", "white"),
           margin_squares: float = 0.0, margin_colour: str = "white", background: str = "grey",
           supersample: int = 4, blur_px: float = 0.0, noise: float = 0.0, seed: int = 0) -> Scene:
    """The scene through H, averaged over supersample^2 samples per pixel, optionally blurred and noisy."""
    w, h = size
    s = supersample
    u, v = np.meshgrid((np.arange(w * s, dtype=np.float32) + 0.5) / s - 0.5,
                       (np.arange(h * s, dtype=np.float32) + 0.5) / s - 0.5)
    Hinv = np.linalg.inv(H)
    d = Hinv[2, 0] * u + Hinv[2, 1] * v + Hinv[2, 2]
    x = (Hinv[0, 0] * u + Hinv[0, 1] * v + Hinv[0, 2]) / d
    y = (Hinv[1, 0] * u + Hinv[1, 1] * v + Hinv[1, 2]) / d
    on_board = (x >= 0) & (x < columns) & (y >= 0) & (y < rows) & (d > 0)
    on_margin = ((x >= -margin_squares) & (x < columns + margin_squares) & (y >= -margin_squares)
                 & (y < rows + margin_squares) & (d > 0))
    first = (np.floor(x).astype(np.int32) + np.floor(y).astype(np.int32)) % 2 == 0
    regions = ((on_board & first, colours[0]), (on_board & ~first, colours[1]), (on_margin & ~on_board, margin_colour),
               (~on_margin, background))
    image = np.zeros((h, w, 3), np.float32)
    for mask, colour in regions:  # each colour weighted by the share of the pixel it covers
        share = cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
        image += share[..., None] * np.float32(BGR[colour])
    if blur_px:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    if noise:
        image = image + np.random.default_rng(seed).normal(0, noise, image.shape)
    image = np.clip(np.round(image), 0, 255).astype(np.uint8)
    return Scene(image, inner_corners(columns, rows, H), H)


def inner_corners(columns: int, rows: int, H: np.ndarray) -> np.ndarray:
    """The board's exact inner corners through H: (rows - 1, columns - 1, 2) in board order."""
    cols, rws = np.meshgrid(np.arange(1, columns), np.arange(1, rows))
    grid = np.stack([cols, rws], axis=-1).reshape(-1, 2).astype(np.float64)
    return cv2.perspectiveTransform(grid[None], H)[0].reshape(rows - 1, columns - 1, 2)
