"""An independent renderer of the Duckiebot calibration set-up, with OpenCV and numpy alone (not PyBullet): test
data that shares no code with a mock's renderer.

The scene (the seed paper's set-up, docs/DUCKIEBOT.md): a floor with a line of AprilTag 36h11 markers (6.5 cm,
about 15 cm apart, all oriented alike: the marker image's top towards +x, the boards) on white paper, and upright
chessboards of 7 x 5 inner corners (0.031 m squares, Duckietown's board) on white panels standing on a
semicircle, facing its centre. World frame: z up, the robot starts at the origin facing +x, the boards ahead, the
marker line behind it along -x.

The camera: a hidden robot's (intrinsics and plumb_bob distortion drawn from the real robots' ranges, its pose on
the body perturbed), rendered exactly by ray casting: each output pixel's distorted position is undistorted
(Newton on solver.camera.distort), its ray meets the floor and the panels, the nearest is sampled from its texture
(bilinear, cv2.remap), supersampled 2 x 2 per pixel; then a slight optical blur and noise. Truth pixel positions
come from solver.camera.project_points, the project's one projection.

The drive: duties held piecewise constant, the robot moving as Duckietown's forward kinematics says with hidden
gain, trim, k and baseline (kinds.duckiebot.kinematics), integrated exactly; frames grabbed while the robot stands
still (no motion blur); encoder ticks from the true wheel angles. The result is a drive log in the format
kinds.duckiebot.drive_log reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from naocal.kinds.duckiebot.drive_log import SCHEMA, DriveLog, write_drive_log, write_frame
from naocal.kinds.duckiebot.fit import (EFFECTS, PWM_DRIVER, body_motion, commanded_wheel_speeds, driver_duty,
                                        lag_factors)
from naocal.kinds.duckiebot.intrinsics import LensCamera
from naocal.kinds.duckiebot.kinematics import integrate_pose
from naocal.kinds.duckiebot.robot import Kinematics, camera_mount, duckiebot
from naocal.solver.camera import CameraIntrinsics, distort, project_points, undistort_points
from naocal.solver.fileio import check_output_directory
from naocal.solver.transforms import invert_transform, make_transform, rot_z, transform_points

SIMULATION_STEP_S = 0.001  # with a hidden wheel lag: the pose integrated in steps this long
MARKER_SIZE_M = 0.065
MARKER_SPACING_M = 0.15
MARKER_CELLS = 8  # tag36h11: 6 x 6 data cells and a one-cell black border
MARKER_TEXELS_PER_CELL = 6
PAPER_MARGIN_CELLS = 2  # white paper around each marker (its quiet zone)
BOARD_INNER_CORNERS = (7, 5)  # (columns, rows): Duckietown's board
BOARD_SQUARE_M = 0.031
BOARD_TEXELS_PER_SQUARE = 20
PANEL_MARGIN_SQUARES = 1  # white margin left, right and above the board
PANEL_BELOW_TEXELS = 24  # white below the board, down to the floor: the board's centre is 0.130 m up
FLOOR_GREY, PAPER_GREY, BLACK_GREY, WALL_GREY, PANEL_BACK_GREY = 70.0, 235.0, 25.0, 150.0, 120.0


@dataclass(frozen=True)
class Scene:
    """Marker centres (n, 2) on the floor (m, world) with their ids, and board panels (centre xy, facing yaw)."""

    marker_ids: tuple[int, ...]
    marker_centres: np.ndarray
    board_centres: np.ndarray  # (b, 2) panel centres on the floor
    board_yaws: np.ndarray  # (b,) direction from the panel's front towards the origin is yaw + pi
    marker_size_m: float = MARKER_SIZE_M
    inner_corners: tuple[int, int] = BOARD_INNER_CORNERS
    square_m: float = BOARD_SQUARE_M

    @property
    def marker_texel_m(self) -> float:
        return self.marker_size_m / (MARKER_CELLS * MARKER_TEXELS_PER_CELL)

    @property
    def board_texel_m(self) -> float:
        return self.square_m / BOARD_TEXELS_PER_SQUARE

    def marker_corners(self) -> np.ndarray:
        """(n, 4, 3) world corners of each marker's black square, in the detector's order: clockwise from the
        marker image's top-left (top towards +x, the image's right towards -y)."""
        h = self.marker_size_m / 2.0
        offsets = np.array([[h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0], [-h, h, 0.0]])
        centres = np.column_stack([self.marker_centres, np.zeros(len(self.marker_centres))])
        return centres[:, None, :] + offsets[None]

    def panel_frames(self):
        """Per board: (top-left corner (3,), right axis a (3,), down axis b (3,), width m, height m) of its panel."""
        columns, rows = self.inner_corners
        texel = self.board_texel_m
        width = (columns + 1 + 2 * PANEL_MARGIN_SQUARES) * BOARD_TEXELS_PER_SQUARE * texel
        height = ((rows + 1 + PANEL_MARGIN_SQUARES) * BOARD_TEXELS_PER_SQUARE + PANEL_BELOW_TEXELS) * texel
        frames = []
        for (x, y), yaw in zip(self.board_centres, self.board_yaws):
            right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])  # the viewer's right, facing the panel
            top_left = np.array([x, y, height]) - right * width / 2.0
            frames.append((top_left, right, np.array([0.0, 0.0, -1.0]), width, height))
        return frames

    def board_corners(self) -> np.ndarray:
        """(b, rows, columns, 3) world inner corners of each board; row 0 at the top, columns left to right as
        seen from the front (the image order of agent.board_detect for an upright view)."""
        columns, rows = self.inner_corners
        texel = self.board_texel_m
        out = []
        for top_left, right, down, _, _ in self.panel_frames():
            c = (PANEL_MARGIN_SQUARES + 1 + np.arange(columns)) * BOARD_TEXELS_PER_SQUARE * texel
            r = (PANEL_MARGIN_SQUARES + 1 + np.arange(rows)) * BOARD_TEXELS_PER_SQUARE * texel
            out.append(top_left + r[:, None, None] * down + c[None, :, None] * right)
        return np.array(out)


def calibration_scene(n_markers: int = 12, board_radius_m: float = 0.6,
                      board_angles_rad=(-0.9, 0.0, 0.9), first_marker_m: float = 0.3) -> Scene:
    """The paper's set-up: boards on a semicircle of `board_radius_m` ahead of the start (numbered counter-
    clockwise), a line of markers behind it along -x from `first_marker_m`, about 15 cm apart (snapped to the
    floor texture's texels, so that every printed edge is exact)."""
    texel = MARKER_SIZE_M / (MARKER_CELLS * MARKER_TEXELS_PER_CELL)
    spacing = round(MARKER_SPACING_M / texel) * texel
    first = round(first_marker_m / texel) * texel
    centres = np.column_stack([-(first + spacing * np.arange(n_markers)), np.zeros(n_markers)])
    angles = np.sort(np.asarray(board_angles_rad, dtype=float))
    boards = board_radius_m * np.column_stack([np.cos(angles), np.sin(angles)])
    return Scene(tuple(range(n_markers)), centres, boards, angles)


# ------------------------------------------------------------------------------------------------ textures

def _marker_line_texture(scene: Scene):
    """(texture, x_max, y_max): the floor strip holding the markers; row i, column j is the texel centred at
    x = x_max - (i + 0.5) texel, y = y_max - (j + 0.5) texel (rows run along -x, columns along -y)."""
    texel = scene.marker_texel_m
    side = MARKER_CELLS * MARKER_TEXELS_PER_CELL
    margin = PAPER_MARGIN_CELLS * MARKER_TEXELS_PER_CELL
    half = scene.marker_size_m / 2.0
    x_max = scene.marker_centres[:, 0].max() + half + margin * texel
    x_min = scene.marker_centres[:, 0].min() - half - margin * texel
    y_max = scene.marker_centres[:, 1].max() + half + margin * texel
    y_min = scene.marker_centres[:, 1].min() - half - margin * texel
    rows, cols = int(round((x_max - x_min) / texel)), int(round((y_max - y_min) / texel))
    texture = np.full((rows, cols), FLOOR_GREY, np.float32)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    for marker_id, (x, y) in zip(scene.marker_ids, scene.marker_centres):
        r0 = int(round((x_max - (x + half)) / texel))
        c0 = int(round((y_max - (y + half)) / texel))
        image = cv2.aruco.generateImageMarker(dictionary, marker_id, side, borderBits=1)
        texture[r0 - margin:r0 + side + margin, c0 - margin:c0 + side + margin] = PAPER_GREY
        texture[r0:r0 + side, c0:c0 + side] = np.where(image > 127, PAPER_GREY, BLACK_GREY)
    return texture, x_max, y_max


def _panel_texture(scene: Scene) -> np.ndarray:
    columns, rows = scene.inner_corners
    n = BOARD_TEXELS_PER_SQUARE
    margin = PANEL_MARGIN_SQUARES * n
    width = (columns + 1) * n + 2 * margin
    height = (rows + 1) * n + margin + PANEL_BELOW_TEXELS
    texture = np.full((height, width), PAPER_GREY, np.float32)
    for r in range(rows + 1):
        for c in range(columns + 1):
            if (r + c) % 2 == 0:  # the top-left square black
                texture[margin + r * n:margin + (r + 1) * n, margin + c * n:margin + (c + 1) * n] = BLACK_GREY
    return texture


# ------------------------------------------------------------------------------------------------ camera rays

def undistort_exact(uv_px, intrinsics, iterations: int = 8) -> np.ndarray:
    """Normalised undistorted coordinates (..., 2) of distorted pixels: solver.camera's fixed point as the start,
    then Newton steps on solver.camera.distort (its fixed point alone is 0.03 px off in a wide lens's corners)."""
    uv_px = np.asarray(uv_px, dtype=float)
    fx, fy, cx, cy = (intrinsics[k] for k in ("fx_px", "fy_px", "cx_px", "cy_px"))
    target = np.stack([(uv_px[..., 0] - cx) / fx, (uv_px[..., 1] - cy) / fy], axis=-1)
    start = undistort_points(uv_px, intrinsics)
    xn, yn = (start[..., 0] - cx) / fx, (start[..., 1] - cy) / fy
    k = tuple(np.asarray(intrinsics["distortion"], dtype=float))
    for _ in range(iterations):
        xd, yd, _, D = distort(xn, yn, k)
        ex, ey = target[..., 0] - xd, target[..., 1] - yd
        det = D[..., 0, 0] * D[..., 1, 1] - D[..., 0, 1] * D[..., 1, 0]
        xn = xn + (D[..., 1, 1] * ex - D[..., 0, 1] * ey) / det
        yn = yn + (D[..., 0, 0] * ey - D[..., 1, 0] * ex) / det
    return np.stack([xn, yn], axis=-1)


def fisheye_normalised(uv_px, lens: LensCamera, iterations: int = 20) -> np.ndarray:
    """Normalised undistorted coordinates (n, 2) of pixels (n, 2) of a Kannala-Brandt lens (OpenCV's fisheye:
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), theta the ray's angle off the axis):
    Newton on theta, exact where OpenCV's undistortPoints stops after a few fixed-point steps."""
    K, k = lens.K, np.asarray(lens.distortion, dtype=float).ravel()[:4]
    uv = np.asarray(uv_px, dtype=float)
    yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
    xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    theta_d = np.hypot(xd, yd)
    theta = theta_d.copy()
    for _ in range(iterations):
        t2 = theta * theta
        f = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - theta_d
        df = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
        theta = theta - f / df
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(theta_d > 1e-12, np.tan(theta) / theta_d, 1.0)
    return np.column_stack([xd * scale, yd * scale])


class Renderer:
    """Renders grey images of a scene seen by one camera mounted on a robot at planar poses (x, y, theta)."""

    def __init__(self, scene: Scene, camera: CameraIntrinsics, T_base_camera, supersample: int = 2,
                 lens: LensCamera | None = None):
        """`lens`: a fisheye lens (LensCamera, Kannala-Brandt) instead of `camera`'s plumb_bob (its size is used)."""
        self.scene, self.camera, self.lens = scene, camera, lens
        self.T_base_camera = np.asarray(T_base_camera, dtype=float)
        self.supersample = supersample
        w, h, s = camera.width_px, camera.height_px, supersample
        offsets = (np.arange(s) - (s - 1) / 2.0) / s  # sub-pixel sample positions about each pixel centre
        u = (np.arange(w)[:, None] + offsets[None, :]).ravel()
        v = (np.arange(h)[:, None] + offsets[None, :]).ravel()
        uu, vv = np.meshgrid(u, v)
        grid = np.stack([uu, vv], axis=-1)
        normalised = (undistort_exact(grid, camera.intrinsics()) if lens is None
                      else fisheye_normalised(grid.reshape(-1, 2), lens).reshape(grid.shape))
        radius = np.hypot(normalised[..., 0], normalised[..., 1])
        # the field of view: beyond the image border's largest normalised radius a wide lens's polynomial folds
        # back, and points far outside the view would "project" into the image
        self.max_radius = float(max(radius[0].max(), radius[-1].max(), radius[:, 0].max(), radius[:, -1].max()))
        # naocal's camera frame: x optical axis, y left, z up; (xn, yn) = (-y / x, -z / x)
        self.rays = np.stack([np.ones_like(uu), -normalised[..., 0], -normalised[..., 1]], axis=-1).astype(np.float32)
        self.floor_texture, self.floor_x_max, self.floor_y_max = _marker_line_texture(scene)
        self.panel_texture = _panel_texture(scene)

    def T_world_camera(self, pose) -> np.ndarray:
        x, y, theta = pose
        return make_transform(rot_z(theta), (x, y, 0.0)) @ self.T_base_camera

    def render(self, pose, rng: np.random.Generator | None = None, noise_grey: float = 1.5,
               blur_px: float = 0.5) -> np.ndarray:
        """(h, w) uint8 grey image from the robot at `pose` (x, y, theta)."""
        T = self.T_world_camera(pose)
        o = T[:3, 3]
        along = {}  # ray components along a world direction, computed once each

        def component(axis) -> np.ndarray:
            key = tuple(np.round(axis, 12))
            if key not in along:
                along[key] = self.rays @ (T[:3, :3].T @ axis).astype(np.float32)
            return along[key]

        dz = component(np.array([0.0, 0.0, 1.0]))
        with np.errstate(divide="ignore", invalid="ignore"):
            s_floor = np.where(dz < -1e-6, -o[2] / dz, np.inf).astype(np.float32)
        hit = np.isfinite(s_floor)
        s_safe = np.where(hit, s_floor, 0.0)
        texel = self.scene.marker_texel_m
        x = o[0] + s_safe * component(np.array([1.0, 0.0, 0.0]))
        y = o[1] + s_safe * component(np.array([0.0, 1.0, 0.0]))
        floor = cv2.remap(self.floor_texture, ((self.floor_y_max - y) / texel - 0.5).astype(np.float32),
                          ((self.floor_x_max - x) / texel - 0.5).astype(np.float32), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=FLOOR_GREY)
        image = np.where(hit, floor, np.float32(WALL_GREY))
        nearest = s_floor
        texel = self.scene.board_texel_m
        for top_left, right, down, width, height in self.scene.panel_frames():
            normal = np.cross(right, down)  # away from the viewer's side: a ray meeting the printed face has dn > 0
            dn = component(normal)
            offset = o - top_left
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (-(offset @ normal) / dn).astype(np.float32)
            s = np.where(s > 0, s, np.float32(np.inf))
            s_safe = np.where(np.isfinite(s), s, 0.0)
            a = offset @ right + s_safe * component(right)
            b = offset @ down + s_safe * component(down)
            on = np.isfinite(s) & (a >= 0) & (a <= width) & (b >= 0) & (b <= height) & (s < nearest)
            if not on.any():
                continue
            panel = cv2.remap(self.panel_texture, (a / texel - 0.5).astype(np.float32),
                              (b / texel - 0.5).astype(np.float32), cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
            image = np.where(on, np.where(dn > 0, panel, np.float32(PANEL_BACK_GREY)), image)
            nearest = np.where(on, s, nearest)
        size = (self.camera.width_px, self.camera.height_px)
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)  # the supersamples' mean: exact for s x s
        if blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        if noise_grey > 0:
            rng = rng or np.random.default_rng(0)
            image = image + rng.normal(0.0, noise_grey, image.shape)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    def project(self, pose, points_world) -> tuple[np.ndarray, np.ndarray]:
        """(pixels (..., 2), within the field of view (...)) of world points seen from `pose`, by
        solver.camera.project_points."""
        p_cam = transform_points(invert_transform(self.T_world_camera(pose)), np.asarray(points_world, float))
        if self.lens is None:
            uv, depth = project_points(p_cam, self.camera.intrinsics())
        else:  # OpenCV's camera frame (x right, y down, z ahead) of naocal's (x ahead, y left, z up)
            depth = p_cam[..., 0]
            cv_points = np.stack([-p_cam[..., 1], -p_cam[..., 2], depth], axis=-1).reshape(-1, 3)
            uv = self.lens.project(cv_points, np.zeros(3), np.zeros(3)).reshape(p_cam.shape[:-1] + (2,))
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.hypot(p_cam[..., 1], p_cam[..., 2]) / depth
        return uv, (depth > 0.02) & (radius <= self.max_radius)

    def in_image(self, uv, margin_px: float = 2.0) -> np.ndarray:
        return ((uv[..., 0] >= margin_px) & (uv[..., 0] <= self.camera.width_px - 1 - margin_px) &
                (uv[..., 1] >= margin_px) & (uv[..., 1] <= self.camera.height_px - 1 - margin_px))


# ------------------------------------------------------------------------------------------------ the hidden robot

@dataclass(frozen=True)
class HiddenRobot:
    """The truth a calibration must find: Duckietown's kinematics parameters with which the forward map gives the
    true motion, the true camera and its true pose on the body."""

    kinematics: Kinematics
    camera: CameraIntrinsics
    T_base_camera: np.ndarray = field(repr=False)
    effects: dict = field(default_factory=dict)  # hidden wheel effects {parameter (fit.EFFECTS): value, pwm_driver}
    lens: LensCamera | None = None  # a hidden wide (fisheye) lens, which `camera` then only sizes

    def truth(self) -> dict:
        """What truth.json records: Duckietown's kinematics, the camera (the lens), its pose, the hidden effects."""
        kin = self.kinematics
        lens = self.lens or LensCamera.from_intrinsics(self.camera)
        return {"kinematics": {"gain": kin.gain, "trim": kin.trim, "k": kin.k, "baseline_m": kin.baseline_m,
                               "radius_m": kin.radius_m},
                "lens": {"model": lens.model, "K": lens.K.tolist(), "distortion": np.ravel(lens.distortion).tolist()},
                "T_base_camera": np.asarray(self.T_base_camera).tolist(), "effects": dict(self.effects)}


# The hidden wide lens: Kannala-Brandt, about 150 deg across the image's diagonal (a DB21's is about 160), its
# focal length this share of the drawn plumb_bob camera's.
WIDE_LENS_FOCAL_SHARE = 0.8
WIDE_LENS_K = (0.03, -0.01, 0.0, 0.0)


def hidden_robot(seed: int, hidden=None) -> HiddenRobot:
    """The hidden robot `seed` (`_drawn_robot`) with the hidden effects `hidden` {name: value}: the wheel effects of
    fit.EFFECTS (their parameter's value), `pwm_driver` (the duties through Duckietown's wheel driver: on for a
    value above 0), `wide_lens` (a fisheye lens instead of the drawn plumb_bob one, any value)."""
    robot = _drawn_robot(seed)
    hidden = dict(hidden or {})
    for name in hidden:
        if name not in EFFECTS and name not in (PWM_DRIVER, "wide_lens"):
            raise ValueError(f"unknown hidden effect {name!r} (expected one of {', '.join(EFFECTS)}, {PWM_DRIVER}, "
                             "wide_lens)")
    effects = {EFFECTS[name][0]: float(value) for name, value in hidden.items() if name in EFFECTS}
    if hidden.get(PWM_DRIVER, 0.0) > 0:
        effects[PWM_DRIVER] = 1.0
    lens = None
    if "wide_lens" in hidden:
        c = robot.camera
        f = WIDE_LENS_FOCAL_SHARE * c.fx_px
        lens = LensCamera("fisheye", np.array([[f, 0.0, c.cx_px], [0.0, f * c.fy_px / c.fx_px, c.cy_px],
                                               [0.0, 0.0, 1.0]]), np.array(WIDE_LENS_K))
    return HiddenRobot(robot.kinematics, robot.camera, robot.T_base_camera, effects, lens)


def _drawn_robot(seed: int) -> HiddenRobot:
    """A DB21 drawn from the real robots' ranges (docs/DUCKIEBOT.md): trim sd 0.05, gain 0.8-1.2, k 27 +- 30 %,
    baseline 0.1 +- 3 mm; fx 319-360 px, fy/fx 0.985-1.01, cx 300-336, cy 212-257, k1 -0.32..-0.25,
    k2 0.043..0.094, |p1|, |p2| <= 0.003; the mount +-5 mm, +-2 deg."""
    rng = np.random.default_rng(seed)
    kin = Kinematics(gain=rng.uniform(0.8, 1.2), trim=float(np.clip(rng.normal(0.0, 0.05), -0.12, 0.12)),
                     k=27.0 * rng.uniform(0.7, 1.3), baseline_m=0.1 + rng.uniform(-0.003, 0.003))
    fx = rng.uniform(319.0, 360.0)
    camera = CameraIntrinsics(640, 480, fx, fx * rng.uniform(0.985, 1.01), rng.uniform(300.0, 336.0),
                              rng.uniform(212.0, 257.0),
                              (rng.uniform(-0.32, -0.25), rng.uniform(0.043, 0.094), rng.uniform(-0.003, 0.003),
                               rng.uniform(-0.003, 0.003), 0.0))
    deg = math.radians
    mount = camera_mount(ahead_m=0.066 + rng.uniform(-0.005, 0.005), height_m=0.108 + rng.uniform(-0.005, 0.005),
                         pitch_down_rad=deg(19.0) + rng.uniform(-deg(2), deg(2)), lateral_m=rng.uniform(-0.003, 0.003),
                         roll_rad=rng.uniform(-deg(1), deg(1)), yaw_rad=rng.uniform(-deg(2), deg(2)))
    return HiddenRobot(kin, camera, mount)


# ------------------------------------------------------------------------------------------------ the drive

@dataclass(frozen=True)
class DriveStep:
    """Hold duties (left, right) for duration_s; then, if `grab`, stand still for settle_s and grab a frame in
    the middle of it."""

    duration_s: float
    left_duty: float
    right_duty: float
    grab: bool = True
    settle_s: float = 0.3
    face_rad: float | None = None  # spin at these duties until the true heading is face_rad (duration_s ignored):
    # the paper's closed-loop "turn until coaxial with the marker line", emulated with the truth


def paper_program(board_steps: int = 4, marker_drives: int = 5, step_duty: float = 0.25,
                  step_s: float = 0.1, drive_duty: float = 0.3, drive_s: float = 0.25) -> list[DriveStep]:
    """The paper's phases, open loop: look ahead; turn in one-wheel steps (the right wheel turns the robot left
    about the left wheel, then the left wheel right, then back) to see every board; spin in place until facing
    the marker line; drive forward in short stops-and-grabs, then back."""
    steps = [DriveStep(0.0, 0.0, 0.0)]
    turn_left, turn_right = DriveStep(step_s, 0.0, step_duty), DriveStep(step_s, step_duty, 0.0)
    one_wheel = [turn_left] * board_steps + [turn_right] * (2 * board_steps) + [turn_left] * board_steps
    steps += one_wheel
    steps.append(DriveStep(0.0, -0.3, 0.3, face_rad=np.pi))  # spin left until facing the marker line (-x)
    steps += [DriveStep(drive_s, drive_duty, drive_duty)] * marker_drives
    steps += [DriveStep(drive_s, -drive_duty, -drive_duty)] * marker_drives
    return steps


def joint_program(board_steps: int = 4, marker_drives: int = 5, wiggles: int = 2, returns: int = 3,
                  step_duty: float = 0.25, step_s: float = 0.05, drive_duty: float = 0.3,
                  drive_s: float = 0.25, drive_duties=None, step_duties=None) -> list[DriveStep]:
    """The paper's program, better where the data allow (kinds.duckiebot.fit): along the forward drive, at `wiggles`
    places, one-wheel steps left, right, right, left (about 6 deg each: without turns in view of the markers the
    baseline cannot be told from trim); then, after driving back, `returns` short drives each forward and straight
    back (a robot with a large trim curves off the marker line on the long drive: seed 3's trim of -0.12 lost it
    after two stretches; one stretch out and back keeps it in view). `drive_duties`, `step_duties`: duties the
    marker drives (and returns) and the wiggles take in turn instead of drive_duty and step_duty, each held so
    long that it drives as far (turns as much) as those would (diagnose_program)."""
    steps = paper_program(board_steps, 0, step_duty, step_s * 2, drive_duty, drive_s)
    drive_duties, step_duties = tuple(drive_duties or (drive_duty,)), tuple(step_duties or (step_duty,))

    def forward(i):
        duty = drive_duties[i % len(drive_duties)]
        return DriveStep(drive_s * drive_duty / duty, duty, duty)

    def back(i):
        duty = drive_duties[i % len(drive_duties)]
        return DriveStep(drive_s * drive_duty / duty, -duty, -duty)

    at = np.linspace(0, marker_drives - 1, wiggles).round().astype(int).tolist() if wiggles else []
    for i in range(marker_drives):
        steps.append(forward(i))
        for j in [j for j, a in enumerate(at) if a == i]:
            duty = step_duties[j % len(step_duties)]
            held = step_s * step_duty / duty
            left, right = DriveStep(held, 0.0, duty), DriveStep(held, duty, 0.0)
            steps += [left, right, right, left]
    steps += [back(i) for i in reversed(range(marker_drives))]
    for i in range(returns):
        steps += [forward(i), back(i)]
    return steps


# The program of `naocal simulate --robot duckiebot` (the mission's loop): joint_program with its marker drives at two
# duties and its wiggles at two, so that the wheel effects can be told from what they resemble: a dead zone from
# gain (a dead zone takes the same duty from every command, gain the same share), speed-dependent trim from trim,
# slip from the baseline (turns at two rates). With one duty each, dead zone, gain and slip are one direction.
DIAGNOSE_DRIVE_DUTIES = (0.3, 0.55)
DIAGNOSE_STEP_DUTIES = (0.25, 0.5)


def diagnose_program(board_steps: int = 4, wiggles: int = 4) -> list[DriveStep]:
    return joint_program(board_steps=board_steps, wiggles=wiggles, drive_duties=DIAGNOSE_DRIVE_DUTIES,
                         step_duties=DIAGNOSE_STEP_DUTIES)


@dataclass(frozen=True)
class SimulatedDrive:
    """A simulated drive: the commands as sent, the frames' times and true poses, the encoders' samples."""

    wheel_t_s: np.ndarray
    left_duty: np.ndarray
    right_duty: np.ndarray
    frame_t_s: np.ndarray
    frame_poses: np.ndarray  # (m, 3) true (x, y, theta) at each frame
    encoder_t_s: np.ndarray
    left_ticks: np.ndarray
    right_ticks: np.ndarray


def simulate_drive(steps, truth: Kinematics, start_pose=(0.0, 0.0, 0.0), t0_s: float = 0.0,
                   ticks_per_revolution: int = 135, encoder_period_s: float = 0.05, effects=None) -> SimulatedDrive:
    """Run a program on a robot whose true parameters are `truth` (Duckietown's forward kinematics, exact arcs), with
    the hidden wheel `effects` {parameter (fit.EFFECTS): value; pwm_driver: the duties logged reach the motors
    through Duckietown's wheel driver, fit.driver_duty} (the fit's formulas: commanded_wheel_speeds, body_motion; a
    wheel lag integrated exactly in SIMULATION_STEP_S steps)."""
    effects = dict(effects or {})
    driver = effects.pop(PWM_DRIVER, 0.0) > 0
    p = {"gain": truth.gain, "trim": truth.trim, "baseline_m": truth.baseline_m, **effects}
    lag = effects.get("wheel_lag_s", 0.0)
    t, pose = t0_s, np.asarray(start_pose, dtype=float)
    wheel_rows, frames, poses = [], [], []
    angle = np.zeros(2)  # cumulative true wheel angles (left, right), rad
    w = np.zeros(2)  # the true wheel speeds (left, right), rad/s
    segments = []  # (start t, duration, (w_left, w_right), angles at its start) for the encoders

    def motor(left, right):  # the duties the motors receive for those logged
        return (float(driver_duty(left)), float(driver_duty(right))) if driver else (left, right)

    def motion(left, right):
        return body_motion(commanded_wheel_speeds(*motor(left, right), p, truth.k)[0], None, p, None,
                           truth.radius_m)[:2]

    def hold(duration, left, right):
        nonlocal t, pose, angle, w
        if duration <= 0:
            return
        wheel_rows.append((t, left, right))
        command = commanded_wheel_speeds(*motor(left, right), p, truth.k)[0]
        steps = max(1, math.ceil(duration / SIMULATION_STEP_S)) if lag > 0 else 1
        h = duration / steps
        e, m, _, _ = lag_factors(lag, h)
        for _ in range(steps):
            mean = command + (w - command) * m  # the step's exact mean speed: the wheel angle it adds is exact
            v, omega = body_motion(mean, None, p, None, truth.radius_m)[:2]
            segments.append((t, h, mean, angle.copy()))
            pose = integrate_pose(pose, v, omega, h)
            angle = angle + mean * h
            w = command + (w - command) * e
            t += h

    for step in steps:
        duration = step.duration_s
        if step.face_rad is not None:
            _, omega = motion(step.left_duty, step.right_duty)
            if omega == 0:
                raise ValueError("a facing step must turn the robot")
            duration = float(np.mod((step.face_rad - pose[2]) * np.sign(omega), 2.0 * np.pi) / abs(omega))
        hold(duration, step.left_duty, step.right_duty)
        if step.grab:
            hold(step.settle_s / 2.0, 0.0, 0.0)
            frames.append(t)
            poses.append(pose.copy())
            hold(step.settle_s / 2.0, 0.0, 0.0)
    wheel_rows.append((t, 0.0, 0.0))  # the final stop
    sample_t = np.arange(t0_s, t + 1e-9, encoder_period_s)
    starts = np.array([s[0] for s in segments])
    index = np.clip(np.searchsorted(starts, sample_t, side="right") - 1, 0, len(segments) - 1)
    angles = np.array([segments[i][3] + segments[i][2] * min(ts - segments[i][0], segments[i][1])
                       for i, ts in zip(index, sample_t)])
    ticks = np.floor(angles * ticks_per_revolution / (2.0 * np.pi)).astype(np.int64)
    rows = np.array(wheel_rows)
    return SimulatedDrive(rows[:, 0], rows[:, 1], rows[:, 2], np.array(frames), np.array(poses), sample_t, ticks[:, 0],
                 ticks[:, 1])


# ------------------------------------------------------------------------------------------------ the log

@dataclass(frozen=True)
class RenderedLog:
    """A rendered drive log and its truth: per frame, the markers' and boards' true pixels where fully in view."""

    log: DriveLog
    robot: HiddenRobot
    scene: Scene
    drive: SimulatedDrive
    marker_px: list  # per frame: {marker id: (4, 2) true corners in the detector's order}
    board_px: list  # per frame: {board index: (rows, columns, 2) true inner corners in image order}


def render_drive_log(directory, seed: int = 1, steps=None, scene: Scene | None = None,
                     robot_id: str = "rendered", supersample: int = 2, hidden=None) -> RenderedLog:
    """Render a drive of the hidden robot `seed` with the hidden effects `hidden` (hidden_robot) through `steps`
    (default: paper_program()) and write it as a drive log in `directory` (frames as PNG in frames/). Returns the
    log as read back and the truth."""
    directory = check_output_directory(Path(directory))
    scene = scene or calibration_scene()
    robot = hidden_robot(seed, hidden)
    drive = simulate_drive(paper_program() if steps is None else steps, robot.kinematics, effects=robot.effects)
    renderer = Renderer(scene, robot.camera, robot.T_base_camera, supersample, robot.lens)
    rng = np.random.default_rng(seed + 1000)
    markers_world, boards_world = scene.marker_corners(), scene.board_corners()
    files, marker_px, board_px = [], [], []
    for i, pose in enumerate(drive.frame_poses):
        name = f"frames/{i:06d}.png"
        write_frame(directory, name, renderer.render(pose, rng))
        files.append(name)
        uv, front = renderer.project(pose, markers_world)
        seen = np.all(front & renderer.in_image(uv), axis=1)
        marker_px.append({scene.marker_ids[m]: uv[m] for m in np.flatnonzero(seen)})
        uv, front = renderer.project(pose, boards_world)
        seen = np.all(front & renderer.in_image(uv, margin_px=10.0), axis=(1, 2))
        board_px.append({int(b): uv[b] for b in np.flatnonzero(seen)})
    nominal = duckiebot("DB21")
    meta = {"schema": SCHEMA, "robot": {"id": robot_id, "model": nominal.model},
            "camera": {"width_px": robot.camera.width_px, "height_px": robot.camera.height_px},
            "wheels": {"radius_m": nominal.radius_m, "baseline_m": nominal.baseline_m, "k": 27.0, "limit": 1.0,
                       "ticks_per_revolution": nominal.ticks_per_revolution},
            "markers": {"family": "tag36h11", "size_m": scene.marker_size_m},
            "boards": {"inner_corners": list(scene.inner_corners), "square_m": scene.square_m},
            "source": f"kinds.duckiebot.render, hidden robot seed {seed}"}
    log = write_drive_log(directory, meta, (drive.wheel_t_s, drive.left_duty, drive.right_duty),
                          (drive.frame_t_s, files), (drive.encoder_t_s, drive.left_ticks, drive.right_ticks))
    return RenderedLog(log, robot, scene, drive, marker_px, board_px)
