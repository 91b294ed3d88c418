"""Checkerboards as a real NAO camera shows them, made with OpenCV alone (not tests/synthetic_boards.py's exact
renderer, nor the mock's): a printed board texture warped through a homography and a lens, then the effects of a
real camera and scene, with the exact inner corners through the same geometry.

Geometry: board (x, y) in squares (square (i, j) covers [i, i + 1] x [j, j + 1], the first colour when i + j is
even) -> ideal pixel by the homography H (tests/synthetic_boards.board_homography's pose) -> OpenCV's radial and
tangential distortion (k1, k2, p1, p2, k3) about the image centre -> a rolling-shutter shear (a board moving
sideways during the readout: u += shear * v). Each output pixel averages 3 x 3 samples (2 x 2 above 640 x 480) of the texture (nearest
texel of a 64-texel square, so the edges are exact to 1/64 square and symmetric: no bias in the corners).

Effects after that (`Look`): optical blur, motion blur along a direction, vignetting, exposure gain and gamma,
glare blobs, a Bayer mosaic demosaiced by OpenCV with shot and read noise, the NAO's YUYV 4:2:2 chroma
subsampling and back, JPEG compression. Clutter: field lines, goal posts, robots, a foot over the board, a second
board. `scene(category, size, rng)` makes one seeded case of a named category with its truth and what a detector
must answer. Pixel (0, 0) is the centre of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tests.synthetic_boards import board_homography

BGR = {"black": (30, 30, 30), "white": (225, 225, 225), "orange": (40, 110, 235), "blue": (185, 115, 35),
       "green": (55, 150, 45), "grey": (120, 120, 120)}
TEXELS = 64  # per square
SUPERSAMPLE = 3


@dataclass
class Print:
    """A printed board: `columns` x `rows` squares in `colours` (square (0, 0) first), a `border` of plain
    `border_colour` around it (in squares; 0: no border)."""

    columns: int
    rows: int
    colours: tuple = ("black", "white")
    border: float = 0.5
    border_colour: str = "white"

    @property
    def border_texels(self) -> int:
        return int(round(self.border * TEXELS))

    def texture(self) -> np.ndarray:
        b = self.border_texels
        w, h = self.columns * TEXELS, self.rows * TEXELS
        y, x = np.mgrid[0:h, 0:w] // TEXELS
        first = (x + y) % 2 == 0
        tex = np.where(first[..., None], np.float32(BGR[self.colours[0]]), np.float32(BGR[self.colours[1]]))
        return cv2.copyMakeBorder(tex.astype(np.float32), b, b, b, b, cv2.BORDER_CONSTANT,
                                  value=BGR[self.border_colour])

    def corners(self) -> np.ndarray:
        """(rows - 1, columns - 1, 2) board coordinates of the inner corners, board order."""
        xs, ys = np.meshgrid(np.arange(1, self.columns), np.arange(1, self.rows))
        return np.stack([xs, ys], axis=-1).astype(float)


@dataclass
class Lens:
    distortion: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)  # OpenCV (k1, k2, p1, p2, k3) in normalised coordinates
    focal_px: float = 550.0
    shear: float = 0.0  # rolling shutter: u moves by shear * v

    def distort(self, ideal: np.ndarray, size) -> np.ndarray:
        """Ideal pixels (n, 2) -> observed pixels."""
        c = (np.array(size, float) - 1) / 2
        x, y = ((ideal - c) / self.focal_px).T
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        out = np.column_stack([xd, yd]) * self.focal_px + c
        out[:, 0] += self.shear * out[:, 1]
        return out

    def undistort(self, observed: np.ndarray, size) -> np.ndarray:
        """Distorted pixels (n, 2), without the shear, -> ideal pixels: fixed-point iteration of distort (it
        converges for the mild distortion of a camera whose image it maps)."""
        ideal = observed.astype(float).copy()
        for _ in range(30):
            shear, self.shear = self.shear, 0.0
            ideal += observed - self.distort(ideal, size)
            self.shear = shear
        return ideal

    def undistort_map(self, size, s: int) -> tuple[np.ndarray, np.ndarray]:
        """For every pixel of the s-times supersampled observed image, its ideal pixel (full resolution)."""
        w, h = size
        u, v = np.meshgrid((np.arange(w * s, dtype=np.float64) + 0.5) / s - 0.5,
                           (np.arange(h * s, dtype=np.float64) + 0.5) / s - 0.5)
        u = u - self.shear * v
        if not any(self.distortion):
            return u, v
        # undistort on a coarse grid (the map is smooth), interpolated to every sample
        step = 8
        gu, gv = np.meshgrid(np.arange(-step, w + 2 * step, step, dtype=np.float64),
                             np.arange(-step, h + 2 * step, step, dtype=np.float64))
        ideal = self.undistort(np.column_stack([gu.ravel(), gv.ravel()]), size).reshape(*gu.shape, 2)
        fx = (u + step) / step
        fy = (v + step) / step
        out = [cv2.remap(ideal[..., k].astype(np.float32), fx.astype(np.float32), fy.astype(np.float32),
                         cv2.INTER_LINEAR).astype(np.float64) for k in (0, 1)]
        return out[0], out[1]


@dataclass
class Look:
    blur_px: float = 0.5  # optical blur sigma
    motion_px: float = 0.0  # motion blur length
    motion_angle: float = 0.0
    vignetting: float = 0.0  # brightness falls by this share at the image corners
    gain: float = 1.0  # exposure
    gamma: float = 1.0
    glare: int = 0  # bright blobs
    bayer: bool = False
    shot_noise: float = 0.0  # std of the noise at full white (grey levels), scaled by sqrt(intensity)
    read_noise: float = 1.0
    yuyv: bool = False
    jpeg: int = 0  # quality, 0: none
    background: str = "green"


@dataclass
class Case:
    category: str
    image: np.ndarray  # (h, w, 3) uint8 BGR
    columns: int  # the board asked for
    rows: int
    truth_px: np.ndarray | None  # (rows - 1, columns - 1, 2) board order, or None when no such board is to be found
    expect: str  # "found", "none" (no board of this size is there: never any corners), "either" (cut or
    # covered: no board, or the right corners)
    colours: tuple = ("black", "white")
    notes: dict = field(default_factory=dict)


def _carpet(size, colour: str, rng) -> np.ndarray:
    w, h = size
    base = np.float32(BGR[colour])
    texture = cv2.GaussianBlur(rng.normal(0, 12, (h, w)).astype(np.float32), (0, 0), 1.5)
    return base[None, None, :] + texture[..., None]


def render(size, boards, lens: Lens, look: Look, rng, clutter: int = 0, foot=None,
           shadow=None) -> tuple[np.ndarray, list]:
    """The image of `boards` [(Print, H)] (drawn in order, later ones on top) through `lens` with `look`; returns
    (image, [corners (rows - 1, columns - 1, 2) px per board])."""
    w, h = size
    s = SUPERSAMPLE if w * h <= 640 * 480 else 2  # 1280 x 960: 2 x 2 samples (time)
    su, sv = lens.undistort_map(size, s)
    canvas = cv2.resize(_carpet(size, look.background, rng), (w * s, h * s), interpolation=cv2.INTER_LINEAR)
    for _ in range(clutter):  # on the floor and behind: boards lie on top (a foot covers them: `foot`)
        _draw_clutter(canvas, rng, s)
    truths = []
    for board, H in boards:
        Hinv = np.linalg.inv(H)
        d = Hinv[2, 0] * su + Hinv[2, 1] * sv + Hinv[2, 2]
        bx = (Hinv[0, 0] * su + Hinv[0, 1] * sv + Hinv[0, 2]) / d
        by = (Hinv[1, 0] * su + Hinv[1, 1] * sv + Hinv[1, 2]) / d
        tex = board.texture()
        tx = (bx * TEXELS + board.border_texels - 0.5).astype(np.float32)  # the texture's border: whole texels
        ty = (by * TEXELS + board.border_texels - 0.5).astype(np.float32)
        tx[d <= 0] = -1e6
        seen = (tx >= -0.5) & (tx <= tex.shape[1] - 0.5) & (ty >= -0.5) & (ty <= tex.shape[0] - 0.5)
        sampled = cv2.remap(tex, tx, ty, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        canvas = np.where(seen[..., None], sampled, canvas)
        ideal = cv2.perspectiveTransform(board.corners().reshape(1, -1, 2), H)[0]
        truths.append(lens.distort(ideal, size).reshape(*board.corners().shape))
    if foot is not None:
        cv2.fillPoly(canvas, [np.round(np.asarray(foot) * s).astype(np.int32)], (200, 200, 205))
    if shadow is not None:  # (point px, unit normal, darkening factor, edge width px): light cut off beyond a line
        point, normal, factor, width = shadow
        yy, xx = np.mgrid[0:h * s, 0:w * s].astype(np.float32)
        distance = ((xx + 0.5) / s - 0.5 - point[0]) * normal[0] + ((yy + 0.5) / s - 0.5 - point[1]) * normal[1]
        light = factor + (1 - factor) / (1 + np.exp(np.clip(distance / max(width / 4, 1e-3), -50, 50)))
        canvas = canvas * light[..., None]
    image = cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA)
    return _camera(image, look, rng), truths


def _draw_clutter(canvas, rng, s):
    h, w = canvas.shape[:2]
    kind = rng.integers(3)
    if kind == 0:  # a field line
        p, q = rng.uniform(0, 1, 2) * (w, h), rng.uniform(0, 1, 2) * (w, h)
        cv2.line(canvas, tuple(int(x) for x in p), tuple(int(x) for x in q), (235, 235, 235), int(rng.uniform(3, 12) * s / 2))
    elif kind == 1:  # a goal post
        x = int(rng.uniform(0, w))
        cv2.rectangle(canvas, (x, 0), (x + int(rng.uniform(6, 20) * s / 2), int(rng.uniform(0.3, 0.8) * h)),
                      (240, 240, 240), -1)
    else:  # a robot: grey and white blobs
        centre = rng.uniform(0, 1, 2) * (w, h)
        axes = rng.uniform(10, 40, 2) * s
        cv2.ellipse(canvas, tuple(int(x) for x in centre), tuple(int(x) for x in axes), float(rng.uniform(0, 180)),
                    0, 360, (90, 90, 95) if rng.random() < 0.5 else (230, 230, 230), -1)


def _camera(image: np.ndarray, look: Look, rng) -> np.ndarray:
    h, w = image.shape[:2]
    img = image.astype(np.float32)
    for _ in range(look.glare):  # specular glare: a bright blob added on top
        centre = rng.uniform(0, 1, 2) * (w, h)
        radius = rng.uniform(0.04, 0.12) * w
        yy, xx = np.mgrid[0:h, 0:w]
        img += (rng.uniform(80, 200) * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * radius ** 2))
                )[..., None].astype(np.float32)
    if look.blur_px:
        img = cv2.GaussianBlur(img, (0, 0), look.blur_px)
    if look.motion_px >= 1:
        n = int(np.ceil(look.motion_px)) | 1
        kernel = np.zeros((n, n), np.float32)
        c = n // 2
        dx, dy = np.cos(look.motion_angle), np.sin(look.motion_angle)
        for t in np.linspace(-look.motion_px / 2, look.motion_px / 2, 4 * n):
            kernel[int(round(c + t * dy)), int(round(c + t * dx))] += 1
        img = cv2.filter2D(img, -1, kernel / kernel.sum())
    if look.vignetting:
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        img *= (1 - look.vignetting * r2)[..., None].astype(np.float32)
    img = np.clip(img * look.gain, 0, 255)
    if look.gamma != 1.0:
        img = 255 * (img / 255) ** (1 / look.gamma)
    if look.bayer:  # one colour per pixel (BGGR in OpenCV's naming), noisy, demosaiced
        mosaic = np.empty((h, w), np.float32)
        mosaic[0::2, 0::2] = img[0::2, 0::2, 0]
        mosaic[0::2, 1::2] = img[0::2, 1::2, 1]
        mosaic[1::2, 0::2] = img[1::2, 0::2, 1]
        mosaic[1::2, 1::2] = img[1::2, 1::2, 2]
        mosaic += rng.normal(0, 1, mosaic.shape) * np.sqrt(look.shot_noise ** 2 * mosaic / 255 + look.read_noise ** 2)
        img = cv2.cvtColor(np.clip(np.round(mosaic), 0, 255).astype(np.uint8), cv2.COLOR_BayerBG2BGR).astype(np.float32)
    else:
        img += rng.normal(0, 1, img.shape).astype(np.float32) * np.sqrt(
            look.shot_noise ** 2 * np.clip(img, 0, 255) / 255 + look.read_noise ** 2).astype(np.float32)
    out = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if look.yuyv:
        out = yuyv_round_trip(out)
    if look.jpeg:
        ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg)])
        out = cv2.imdecode(data, cv2.IMREAD_COLOR)
    return out


def to_yuyv(image: np.ndarray) -> np.ndarray:
    """(h, w, 2) uint8 YUYV 4:2:2 of a BGR image (even width): Y per pixel, U and V per pair of pixels."""
    yuv = cv2.cvtColor(image, cv2.COLOR_BGR2YUV).astype(np.float32)
    out = np.empty(image.shape[:2] + (2,), np.float32)
    out[..., 0] = yuv[..., 0]
    out[:, 0::2, 1] = 0.5 * (yuv[:, 0::2, 1] + yuv[:, 1::2, 1])
    out[:, 1::2, 1] = 0.5 * (yuv[:, 0::2, 2] + yuv[:, 1::2, 2])
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def yuyv_round_trip(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(to_yuyv(image), cv2.COLOR_YUV2BGR_YUYV)


# ------------------------------------------------------------------------------------------------- categories

BOARDS = ((7, 5, ("black", "white")), (9, 6, ("black", "white")), (5, 4, ("black", "white")),
          (8, 6, ("white", "black")), (4, 4, ("orange", "blue")))
CATEGORIES = ("clean", "distortion", "blur", "motion", "sensor", "jpeg", "dark", "bright", "vignetting", "glare",
              "shadow", "clutter", "tilt", "small", "large", "no_border", "second_board", "bigger_board", "cut_off", "foot",
              "no_board")


def scene(category: str, size=(640, 480), rng=None, seed: int = 0) -> Case:
    """One seeded case of `category` (CATEGORIES) at `size` (w, h)."""
    rng = np.random.default_rng(seed) if rng is None else rng
    w, h = size
    columns, rows, colours = BOARDS[rng.integers(len(BOARDS))]
    if category == "bigger_board":
        columns, rows, colours = BOARDS[rng.integers(4)]
    board = Print(columns, rows, colours, border=0.0 if colours[0] == "orange" or category == "no_border" else
                  float(rng.uniform(0.3, 1.0)), border_colour="white")
    look = Look(blur_px=float(rng.uniform(0.4, 0.9)), read_noise=float(rng.uniform(0.5, 2.5)),
                background="green" if rng.random() < 0.6 else "grey")
    lens = Lens(distortion=(float(rng.uniform(-0.15, 0.05)), 0.0, 0.0, 0.0, 0.0), focal_px=w * 0.86)
    side = (columns + 2 * board.border)
    square_px = float(rng.uniform(0.35, 0.7) * min(w / side, h / (rows + 2 * board.border)))
    square_px = min(max(square_px, 6.0), 80.0)
    tilt = (float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-0.4, 0.4)))
    turn = float(rng.uniform(-0.4, 0.4)) + (np.pi if rng.random() < 0.2 else 0.0)
    shift = rng.uniform(-0.08, 0.08, 2) * (w, h)
    clutter, foot, shadow, expect, asked, extra = 0, None, None, "found", (columns, rows), []
    if category == "distortion":
        lens.distortion = (float(rng.uniform(-0.35, -0.15)), float(rng.uniform(0.0, 0.12)),
                           float(rng.uniform(-0.004, 0.004)), float(rng.uniform(-0.004, 0.004)), 0.0)
        lens.shear = float(rng.uniform(-0.04, 0.04))
    elif category == "blur":
        look.blur_px = float(rng.uniform(1.2, 2.2)) * max(1.0, w / 640)
    elif category == "motion":
        look.motion_px = float(rng.uniform(3, 8)) * max(1.0, w / 640)
        look.motion_angle = float(rng.uniform(0, np.pi))
        lens.shear = float(rng.uniform(-0.05, 0.05))
    elif category == "sensor":
        look.bayer, look.yuyv = True, True
        look.shot_noise, look.read_noise = float(rng.uniform(6, 14)), float(rng.uniform(2, 5))
    elif category == "jpeg":
        look.jpeg = int(rng.integers(50, 91))
        look.yuyv = True
    elif category == "dark":
        look.gain, look.gamma = float(rng.uniform(0.15, 0.3)), float(rng.uniform(1.0, 1.8))
        look.shot_noise, look.read_noise = 4.0, 2.0
    elif category == "bright":
        look.gain = float(rng.uniform(1.4, 2.2))
    elif category == "vignetting":
        look.vignetting, look.gamma = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.6, 2.0))
        shift = rng.uniform(-0.2, 0.2, 2) * (w, h)
        square_px *= 0.75
    elif category == "glare":
        look.glare = int(rng.integers(1, 3))
    elif category == "shadow":  # a robot's shadow: a soft edge across the board, 40-70 % of the light beyond
        angle = float(rng.uniform(0, 2 * np.pi))
        shadow = ((np.array(size, float) - 1) / 2 + shift + rng.uniform(-0.2, 0.2, 2) * square_px * columns,
                  np.array([np.cos(angle), np.sin(angle)]), float(rng.uniform(0.3, 0.6)), float(rng.uniform(2, 15)))
    elif category == "clutter":
        clutter = int(rng.integers(3, 8))
    elif category == "tilt":
        angle = float(rng.uniform(0.9, 1.22))  # 52-70 deg
        tilt = (angle * (1 if rng.random() < 0.5 else -1), float(rng.uniform(-0.2, 0.2)))
        if rng.random() < 0.5:
            tilt = tilt[::-1]
        square_px = float(min(80.0, square_px * 1.3))
    elif category == "small":
        square_px = float(rng.uniform(6, 10))
        look.blur_px = float(rng.uniform(0.4, 0.7))
    elif category == "large":
        square_px = float(min(80.0, 0.85 * min(w / side, h / (rows + 2 * board.border))))
        shift = rng.uniform(-0.02, 0.02, 2) * (w, h)
        tilt = (tilt[0] * 0.3, tilt[1] * 0.3)
    elif category == "second_board":  # a different-size board beside the one asked for
        other = BOARDS[(BOARDS.index((columns, rows, colours)) + 1 + rng.integers(len(BOARDS) - 1)) % len(BOARDS)]
        if (other[0], other[1]) == (columns, rows) or (other[0] >= columns and other[1] >= rows) or \
                (other[1] >= columns and other[0] >= rows):
            other = (4, 4, ("orange", "blue")) if columns != 4 else (5, 4, ("black", "white"))
        extra.append(Print(other[0], other[1], other[2], border=0.5))
    elif category == "bigger_board":  # a board one square larger each way than the one asked for: refuse
        asked = (columns - 1, rows - 1) if rows > 4 else (columns - 1, rows)
        expect = "none"
    elif category == "cut_off":
        expect = "either"
        out = float(rng.uniform(0.6, 2.0))  # squares beyond the image edge (below 1: only the outer squares)
        direction = int(rng.integers(4))  # right, left, down, up
        along = direction // 2
        half = (columns if along == 0 else rows) / 2 * square_px
        shift = np.zeros(2)
        shift[along] = (size[along] / 2 - half + out * square_px) * (1 if direction % 2 == 0 else -1)
        tilt = (tilt[0] * 0.5, tilt[1] * 0.5)
        turn = float(rng.uniform(-0.15, 0.15))
    elif category == "foot":
        expect = "either"
    elif category == "no_board":
        expect = "none"
        clutter = int(rng.integers(3, 8))
        asked = (columns, rows)
    H = board_homography(columns, rows, size=size, square_px=square_px, tilt_x=tilt[0], tilt_y=tilt[1], turn=turn,
                         shift_px=shift, focal_px=lens.focal_px)
    boards = [] if category == "no_board" else [(board, H)]
    if extra:
        other = extra[0]
        # both boards side by side, each in its half of the image
        sq2 = min(square_px, 0.4 * w / (max(columns, other.columns) + 1), 0.8 * h / (max(rows, other.rows) + 1))
        H = board_homography(columns, rows, size=size, square_px=sq2, tilt_x=tilt[0], turn=turn,
                             shift_px=(-0.25 * w, 0.0), focal_px=lens.focal_px)
        H2 = board_homography(other.columns, other.rows, size=size, square_px=sq2, tilt_x=tilt[0], turn=-turn,
                              shift_px=(0.25 * w, 0.0), focal_px=lens.focal_px)
        boards = [(Print(columns, rows, colours, border=0.5), H), (other, H2)]
    if category == "foot":  # a foot over one end of the board, covering a corner or two (or more)
        ideal = cv2.perspectiveTransform(np.array([[[columns * rng.uniform(0.7, 0.95), rows * rng.uniform(-0.5, 0.5)],
                                                    [columns * 1.6, rows * 0.2]]]), H)[0]
        a, b = ideal
        d = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        n = np.array([-d[1], d[0]]) * square_px * rng.uniform(0.8, 1.5)
        foot = [a - n, a + n, b + n * 1.5, b - n * 1.5]
    image, truths = render(size, boards, lens, look, rng, clutter=clutter, foot=foot, shadow=shadow)
    outline = np.array([[[0, 0], [columns, 0], [columns, rows], [0, rows]]], float)
    seen = lens.distort(cv2.perspectiveTransform(outline, H)[0], size)
    if expect == "found" and not np.all((seen >= 0) & (seen <= np.array(size) - 1)):
        expect = "either"  # the board runs out of the image (a strong tilt, a large board): it may be refused
    truth = truths[0] if boards and expect != "none" else None
    if category == "no_board":
        truth = None
    return Case(category, image, asked[0], asked[1], truth, expect, colours,
                notes={"square_px": square_px, "tilt_deg": np.degrees(tilt).round(1).tolist()})
