"""Rendering the mock's bottom camera: the body by PyBullet's TinyRenderer, the sandals from their exact homography.

The robot's body (primitive shapes, greys) and a segmentation mask come from TinyRenderer. Each printed board is
then drawn over it from its exact homography with area sampling: a high-resolution board texture is warped
(`cv2.warpPerspective`, bilinear) into a canvas `supersample` times finer than the image, restricted to the board's
bounding box, and averaged down (`cv2.resize`, INTER_AREA). Pixels where the mask shows another part of the robot
in front of the board keep the body (the foot or the other leg hides the board there).

Pixel convention (OpenCV, as the NAO camera model in docs/CONVENTIONS.md): pixel (0, 0) is the centre of the
top-left pixel, u = cx - fx * y / x, v = cy - fy * z / x in the NAO camera frame (x optical axis, y left, z up).
TinyRenderer samples each pixel at integer window coordinates and flips the rows, so with a projection matrix built
from (fx, fy, cx, cy) column k samples u = k but row r samples v = r + 1; the projection is therefore built with
cy + 1 (measured in tests/test_mock_render.py with the edge of a box).

Lens distortion (radial k1 on the normalised coordinates, OpenCV's model) is rendered by remapping: the body image
through the exact undistortion map, the boards by sampling the texture at the undistorted position of every
sub-pixel. The camera is a solver.camera.CameraIntrinsics; projection, undistortion and the board's homography
are solver.camera's (the one camera model).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from naocal.body.nao_body import BOARD_BORDER_M, BOARD_HALF_X_M, BOARD_HALF_Y_M, NaoBody
from naocal.body.pybullet_quiet import pybullet
from naocal.solver.camera import CameraIntrinsics, plane_homography
from naocal.solver.nao_model import BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M
from naocal.solver.transforms import invert_transform

BLACK = 0.08  # reflectance of the printed squares, 0..1
WHITE = 0.90
BACKGROUND = 0.55  # the room behind the robot (TinyRenderer leaves it white)
NEAR_M, FAR_M = 0.01, 6.0
R_CAM_GL = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # GL camera axes in the NAO camera frame
TEXTURE_PX_PER_SQUARE = 100


def projection_matrix_gl(camera: CameraIntrinsics) -> np.ndarray:
    """OpenGL projection (4, 4) for TinyRenderer such that its pixel (row r, column k) samples (u, v) = (k, r)."""
    w, h = camera.width_px, camera.height_px
    cy_gl = camera.cy_px + 1.0  # TinyRenderer's row flip: see the module docstring
    return np.array([
        [2 * camera.fx_px / w, 0.0, 1.0 - 2 * camera.cx_px / w, 0.0],
        [0.0, 2 * camera.fy_px / h, 2 * cy_gl / h - 1.0, 0.0],
        [0.0, 0.0, -(FAR_M + NEAR_M) / (FAR_M - NEAR_M), -2 * FAR_M * NEAR_M / (FAR_M - NEAR_M)],
        [0.0, 0.0, -1.0, 0.0],
    ])


def view_matrix_gl(T_world_cam: np.ndarray) -> np.ndarray:
    """OpenGL view matrix (4, 4) (world -> GL camera) of a NAO camera at T_world_cam."""
    T_world_gl = T_world_cam.copy()
    T_world_gl[:3, :3] = T_world_cam[:3, :3] @ R_CAM_GL
    return invert_transform(T_world_gl)


def board_texture(px_per_square: int = TEXTURE_PX_PER_SQUARE) -> tuple[np.ndarray, np.ndarray]:
    """The printed board as a premultiplied (reflectance, coverage) float32 texture (h, w, 2), and the matrix
    A (3, 3) taking texel coordinates (column, row; integer = texel centre) to board-frame metres (x, y)."""
    texel = BOARD_SQUARE_M / px_per_square
    border = int(round(BOARD_BORDER_M / texel))
    w = BOARD_COLUMNS * px_per_square + 2 * border
    h = BOARD_ROWS * px_per_square + 2 * border
    cols = (np.arange(w) - border) // px_per_square
    rows = (np.arange(h) - border) // px_per_square
    inside = ((rows[:, None] >= 0) & (rows[:, None] < BOARD_ROWS) & (cols[None, :] >= 0)
              & (cols[None, :] < BOARD_COLUMNS))
    black = inside & ((rows[:, None] + cols[None, :]) % 2 == 0)  # the four corner squares are black
    texture = np.empty((h, w, 2), dtype=np.float32)
    texture[..., 0] = np.where(black, BLACK, WHITE)
    texture[..., 1] = 1.0
    A = np.array([[texel, 0.0, -BOARD_HALF_X_M + 0.5 * texel],
                  [0.0, texel, -BOARD_HALF_Y_M + 0.5 * texel],
                  [0.0, 0.0, 1.0]])
    return texture, A


def board_outline_board_m(n_per_side: int = 8) -> np.ndarray:
    """Points (k, 3) along the printed region's outline in the board frame (for bounding boxes)."""
    s = np.linspace(-1.0, 1.0, n_per_side)
    one = np.ones_like(s)
    x = np.concatenate([s, one, -s, -one]) * BOARD_HALF_X_M
    y = np.concatenate([-one, s, one, -s]) * BOARD_HALF_Y_M
    return np.column_stack([x, y, np.zeros_like(x)])


@dataclass
class BoardView:
    """One sandal as the camera sees it during the exposure: its poses at sub-exposure times (motion blur), in
    rows v0 <= v < v1 (a band of a rolling shutter's rows; None: all rows)."""

    link_index: int  # the sandal's PyBullet link (its own plate never hides its print)
    T_cam_board: list  # [(4, 4)], one or more poses averaged over the exposure
    rows: tuple[int, int] | None = None


@dataclass
class RowBand:
    """Rows v0 <= v < v1 of a rolling-shutter image and a board's world poses during their exposure."""

    v0: int
    v1: int
    T_world_board: list  # [(4, 4)]


class SceneRenderer:
    """Renders the bottom camera's view of a `NaoBody` with exact boards. Grey float image in 0..1."""

    def __init__(self, body: NaoBody, camera: CameraIntrinsics, *, supersample: int = 4,
                 px_per_square: int = TEXTURE_PX_PER_SQUARE):
        self.body = body
        self.camera = camera
        self.supersample = int(supersample)
        self.texture, self.A_board_texel = board_texture(px_per_square)
        self._projection = projection_matrix_gl(camera).T.ravel().tolist()
        self._undistort_map = None
        if any(camera.distortion):
            v, u = np.mgrid[0:camera.height_px, 0:camera.width_px].astype(float)
            self._undistort_map = camera.undistort_px(np.stack([u, v], axis=-1)).astype(np.float32)

    # --- The body -----------------------------------------------------------------------------------------------
    def render_body(self, q_true, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grey body image (h, w) float32 in 0..1 and segmentation mask (h, w) int32 (PyBullet's object + link
        encoding, -1 = nothing), both through the lens distortion."""
        cam = self.camera
        self.body.set_angles(q_true)
        _, _, rgba, _, seg = pybullet.getCameraImage(
            cam.width_px, cam.height_px, view_matrix_gl(T_world_cam).T.ravel().tolist(), self._projection,
            renderer=pybullet.ER_TINY_RENDERER, shadow=0, lightDirection=[0.3, -0.2, 1.0],
            lightColor=[1.0, 1.0, 1.0], lightAmbientCoeff=0.65, lightDiffuseCoeff=0.35, lightSpecularCoeff=0.0,
            flags=pybullet.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX, physicsClientId=self.body.client)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(cam.height_px, cam.width_px, 4)
        grey = rgba[..., 1].astype(np.float32) * (1.0 / 255.0)  # the scene is grey: any channel will do
        seg = np.asarray(seg, dtype=np.int32).reshape(cam.height_px, cam.width_px)
        grey[seg < 0] = BACKGROUND
        if self._undistort_map is not None:
            mu, mv = self._undistort_map[..., 0], self._undistort_map[..., 1]
            grey = cv2.remap(grey, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            seg = cv2.remap(seg.astype(np.float32), mu, mv, cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_REPLICATE).astype(np.int32)
        return grey, seg

    def occluders(self, seg: np.ndarray, board_link: int) -> np.ndarray:
        """(h, w) bool: pixels where a part of the robot other than this sandal is the nearest surface."""
        robot = self.body.robot
        obj = np.where(seg >= 0, seg & ((1 << 24) - 1), -1)
        link = np.where(seg >= 0, (seg >> 24) - 1, -2)
        return (obj == robot) & (link != board_link)

    # --- The boards ---------------------------------------------------------------------------------------------
    def _bbox(self, T_cam_boards, rows=None) -> tuple[int, int, int, int] | None:
        """Inclusive pixel bounding box (u0, v0, u1, v1) of the printed region over all poses, clipped to the
        image (and to rows v0 <= v < v1 if given); None if it is not in front of the camera and facing it."""
        cam = self.camera
        outline = board_outline_board_m()
        uv_all = []
        for T in T_cam_boards:
            p = outline @ T[:3, :3].T + T[:3, 3]
            if np.any(p[:, 0] < 0.02):
                return None  # partly behind the camera: not drawn (the plate still renders)
            if T[:3, 2] @ T[:3, 3] >= 0.0:
                return None  # the camera looks at the plate's underside
            uv_all.append(cam.project(p))
        uv = np.concatenate(uv_all)
        u0, v0 = np.floor(uv.min(axis=0)).astype(int) - 1
        u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + 1
        u0, v0 = max(u0, 0), max(v0, 0)
        u1, v1 = min(u1, cam.width_px - 1), min(v1, cam.height_px - 1)
        if rows is not None:
            v0, v1 = max(v0, rows[0]), min(v1, rows[1] - 1)
        if u1 < u0 or v1 < v0:
            return None
        return int(u0), int(v0), int(u1), int(v1)

    def _warp_board(self, T_cam_board: np.ndarray, bbox) -> np.ndarray:
        """Premultiplied (reflectance, coverage) of one board pose over the bbox, area-sampled, (bh, bw, 2)."""
        u0, v0, u1, v1 = bbox
        s = self.supersample
        bw, bh = u1 - u0 + 1, v1 - v0 + 1
        H = plane_homography(T_cam_board, self.camera.intrinsics())  # board m -> undistorted px
        if self._undistort_map is None:
            # canvas sub-pixel (a, b) -> image u = u0 - 0.5 + (a + 0.5) / s
            S = np.array([[1.0 / s, 0.0, u0 - 0.5 + 0.5 / s], [0.0, 1.0 / s, v0 - 0.5 + 0.5 / s], [0, 0, 1.0]])
            M_canvas_to_texel = np.linalg.inv(self.A_board_texel) @ np.linalg.inv(H) @ S
            canvas = cv2.warpPerspective(self.texture, M_canvas_to_texel, (bw * s, bh * s),
                                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        else:
            # The undistorted position of every canvas sub-pixel, interpolated from the exact per-pixel map
            # (cv2.resize's sub-pixel centres are the canvas's), then board -> texel.
            crop = self._undistort_map[v0:v1 + 1, u0:u1 + 1].astype(np.float64)
            uv = cv2.resize(crop, (bw * s, bh * s), interpolation=cv2.INTER_LINEAR)
            M = np.linalg.inv(self.A_board_texel) @ np.linalg.inv(H)
            x = M[0, 0] * uv[..., 0] + M[0, 1] * uv[..., 1] + M[0, 2]
            y = M[1, 0] * uv[..., 0] + M[1, 1] * uv[..., 1] + M[1, 2]
            w = M[2, 0] * uv[..., 0] + M[2, 1] * uv[..., 1] + M[2, 2]
            canvas = cv2.remap(self.texture, (x / w).astype(np.float32), (y / w).astype(np.float32),
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return cv2.resize(canvas, (bw, bh), interpolation=cv2.INTER_AREA)

    def draw_boards(self, grey: np.ndarray, seg: np.ndarray, boards: list[BoardView]) -> np.ndarray:
        """The body image with every visible board's print drawn over it (a new array)."""
        out = grey.copy()
        for board in boards:
            bbox = self._bbox(board.T_cam_board, board.rows)
            if bbox is None:
                continue
            u0, v0, u1, v1 = bbox
            premult = sum(self._warp_board(T, bbox) for T in board.T_cam_board) / len(board.T_cam_board)
            region = out[v0:v1 + 1, u0:u1 + 1]
            hidden = self.occluders(seg[v0:v1 + 1, u0:u1 + 1], board.link_index)
            drawn = premult[..., 0] + (1.0 - premult[..., 1]) * region
            out[v0:v1 + 1, u0:u1 + 1] = np.where(hidden, region, drawn)
        return out

    def render(self, q_true, T_world_cam: np.ndarray, T_world_boards: dict) -> tuple[np.ndarray, np.ndarray]:
        """Grey image (h, w) in 0..1 and segmentation mask of the robot at q_true, with the boards' prints.

        T_world_boards: {link_index: [T_world_board (4, 4), ...]} poses of each board over the exposure (one pose
        for a still robot; several for motion blur), or {link_index: [RowBand, ...]} for a rolling shutter (each
        band of rows with the poses of its own exposure); the body itself is rendered at q_true.
        """
        grey, seg = self.render_body(q_true, T_world_cam)
        T_cam_world = invert_transform(T_world_cam)
        boards = []
        for link, poses in T_world_boards.items():
            if poses and isinstance(poses[0], RowBand):
                boards += [BoardView(link, [T_cam_world @ T for T in band.T_world_board], (band.v0, band.v1))
                           for band in poses]
            else:
                boards.append(BoardView(link, [T_cam_world @ T for T in poses]))
        return self.draw_boards(grey, seg, boards), seg


def add_glare(grey: np.ndarray, outline_px: np.ndarray, centre_px, sigma_px: float, amplitude: float,
              hidden: np.ndarray | None = None) -> np.ndarray:
    """The grey image (h, w) in 0..1 with a specular patch on a board: a Gaussian highlight of `amplitude` and
    `sigma_px` at `centre_px`, only inside the board's printed outline (polygon (k, 2) px) and not where `hidden`
    (h, w) bool shows something in front of the board; saturating at 1."""
    h, w = grey.shape
    mask = np.zeros((h, w), dtype=np.uint8)
    cv2.fillPoly(mask, [np.round(outline_px * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    if hidden is not None:
        mask[hidden] = 0
    v, u = np.mgrid[0:h, 0:w]
    blob = amplitude * np.exp(-((u - centre_px[0]) ** 2 + (v - centre_px[1]) ** 2) / (2.0 * sigma_px ** 2))
    return np.minimum(grey + (blob * mask).astype(np.float32), 1.0)


# --- Image formation: what the sensor and its YUYV capture do to the rendered scene -----------------------------
# ITU-R BT.601 "studio swing" (Y 16..235, Cb and Cr 16..240 around 128), the coefficients OpenCV's
# COLOR_YUV2BGR_YUYV inverts. The NAO V6's cameras deliver YUYV (YUV 4:2:2) through V4L2.
_Y_FROM_RGB = np.array([65.481, 128.553, 24.966]) / 255.0
_CB_FROM_RGB = np.array([-37.797, -74.203, 112.0]) / 255.0
_CR_FROM_RGB = np.array([112.0, -93.786, -18.214]) / 255.0


def bgr_to_yuyv(bgr: np.ndarray, rng=None, *, luma_noise_std: float = 0.0, chroma_noise_std: float = 0.0
                ) -> np.ndarray:
    """YUYV 4:2:2 (h, w, 2) uint8 of a BGR image (h, w, 3) in 0..255 (float or uint8), w even: Y per pixel, Cb and
    Cr per pair of pixels (their mean), Gaussian sensor noise added before the 8-bit rounding."""
    bgr = np.asarray(bgr, dtype=np.float32)
    h, w, _ = bgr.shape
    if w % 2:
        raise ValueError("YUYV needs an even image width")
    rgb = bgr[..., ::-1]
    y = 16.0 + rgb @ _Y_FROM_RGB.astype(np.float32)
    pairs = rgb.reshape(h, w // 2, 2, 3).mean(axis=2)
    cb = 128.0 + pairs @ _CB_FROM_RGB.astype(np.float32)
    cr = 128.0 + pairs @ _CR_FROM_RGB.astype(np.float32)
    if rng is not None and luma_noise_std > 0:
        y = y + rng.standard_normal(y.shape, dtype=np.float32) * luma_noise_std
    if rng is not None and chroma_noise_std > 0:
        cb = cb + rng.standard_normal(cb.shape, dtype=np.float32) * chroma_noise_std
        cr = cr + rng.standard_normal(cr.shape, dtype=np.float32) * chroma_noise_std
    out = np.empty((h, w, 2), dtype=np.float32)
    out[..., 0] = y
    out[:, 0::2, 1] = cb
    out[:, 1::2, 1] = cr
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def grey_to_yuyv(grey: np.ndarray, rng=None, *, luma_noise_std: float = 0.0, chroma_noise_std: float = 0.0
                 ) -> np.ndarray:
    """bgr_to_yuyv of a grey scene (h, w) in 0..1 (B = G = R), without building the colour image: Y = 16 + 219 grey,
    Cb = Cr = 128, plus the same sensor noise."""
    h, w = grey.shape
    if w % 2:
        raise ValueError("YUYV needs an even image width")
    out = np.empty((h, w, 2), dtype=np.float32)
    out[..., 0] = 16.0 + 219.0 * np.asarray(grey, dtype=np.float32)
    out[..., 1] = 128.0
    if rng is not None and luma_noise_std > 0:
        out[..., 0] += rng.standard_normal((h, w), dtype=np.float32) * luma_noise_std
    if rng is not None and chroma_noise_std > 0:
        out[..., 1] += rng.standard_normal((h, w), dtype=np.float32) * chroma_noise_std  # Cb, Cr: half resolution
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def yuyv_to_bgr(yuyv: np.ndarray) -> np.ndarray:
    """BGR (h, w, 3) uint8 of a YUYV image (h, w, 2), as a V4L2 client converts it (OpenCV)."""
    return cv2.cvtColor(np.ascontiguousarray(yuyv), cv2.COLOR_YUV2BGR_YUYV)


def form_image(grey: np.ndarray, rng, *, luma_noise_std: float, chroma_noise_std: float = 0.0,
               defocus_sigma_px: float = 0.0, yuyv: bool = True) -> np.ndarray:
    """The camera's BGR uint8 image (h, w, 3) of a rendered grey scene (h, w) in 0..1: slight defocus (Gaussian
    blur), then the sensor's noise and its YUYV 4:2:2 capture, converted back to BGR as the robot's driver does."""
    grey = np.asarray(grey, dtype=np.float32)
    if defocus_sigma_px > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), defocus_sigma_px, borderType=cv2.BORDER_REPLICATE)
    if not yuyv:
        noisy = grey * 255.0 + rng.standard_normal(grey.shape, dtype=np.float32) * luma_noise_std
        return np.repeat(np.clip(np.rint(noisy), 0, 255).astype(np.uint8)[:, :, None], 3, axis=2)
    return yuyv_to_bgr(grey_to_yuyv(grey, rng, luma_noise_std=luma_noise_std, chroma_noise_std=chroma_noise_std))
