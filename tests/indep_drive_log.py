"""A second, deliberately independent Duckiebot drive-log generator for tests (issue 23's "logs recorded
elsewhere"): OpenCV + numpy only, nothing imported from naocal but nothing at all, so that it shares no formula, no
projection and no file writer with naocal or with kinds/duckiebot/render.py.

What differs from render.py on purpose:
- motion: the robot turns continuously in place (not in one-wheel steps) with frames grabbed WHILE moving, at a
  camera frame rate (15 fps by default) on a Unix-time clock; the commands are republished at 10 Hz, unrelated to the
  frame times, with many decimals; then it drives along the marker line forward and back at its own speed, with a
  gentle S-curve and an in-place wiggle in view of the markers; encoders.csv only with `encoders`.
- kinematics: integrated here from the issue's formulas (w_r = u_r k / (gain + trim), w_l = u_l k / (gain - trim),
  v = r (w_r + w_l) / 2, omega = r (w_r - w_l) / b), by exact arcs between breakpoints; `Truth.turn_slip` hides a
  slip in turns (omega scaled by 1 - turn_slip, the encoders counting the wheels' turn as commanded).
- camera: OpenCV's own convention (z forward, x right, y down), rays from cv2.undistortPoints (iterated to
  1e-12), truth pixels from cv2.projectPoints; frames written as JPEG by cv2.imwrite; each frame an instant but
  `blur_frames`, averaged over 5 poses across a long exposure (motion blur).
- scene: boards and markers where `Variation` puts them (the issue's description: 2-3 identical 7 x 5 inner-corner
  chessboards standing upright on a semicircle facing the start; a line of flat tag36h11 markers, 6.5 cm, about
  15 cm apart, all oriented alike).

`make_log(DIR, Variation(...))` writes LOG/log.json, wheels.csv, frames.csv, frames/*.jpg (encoders.csv) and returns
the `Truth`. `Variation` also varies what a ROS bag export may look like: the clock, when the camera starts, commands
at the frames' times or written twice, the board's and markers' sizes, the model, CRLF, a BOM, extra log.json keys.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

# OpenCV camera frame (x right, y down, z forward) in the body frame (x forward, y left, z up)
R_BODY_CV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
FLOOR, PAPER, INK, WALL = 60.0, 225.0, 30.0, 140.0


@dataclass(frozen=True)
class Variation:
    """One generator setting per axis the brief names (defaults: the base log)."""

    t0_s: float = 1.7e9  # the clock's first value (Unix time)
    fps: float = 15.0
    image_ext: str = ".jpg"
    jpeg_quality: int = 90
    wheel_rate_hz: float = 10.0  # commands republished at this rate, phase unrelated to the frames
    duty_decimals: int = 12
    turn: str = "continuous"  # or "steps": the robot's own steps (stop, grab while still, go on)
    turn_rate_radps: float = 0.35
    line_speed_mps: float = 0.12
    line_distance_m: float = 0.5
    board_radius_m: float = 0.55
    board_angles_rad: tuple = (-0.75, 0.05, 0.8)
    board_square_m: float = 0.031
    board_centre_m: float = 0.13  # board centre height
    marker_size_m: float = 0.065
    marker_spacing_m: float = 0.15
    first_marker_m: float = 0.25  # distance behind the start of the first marker
    n_markers: int = 8
    marker_ids: tuple | None = None  # default 0..n-1
    exposure_s: float = 0.06  # of the blur frames
    blur_frames: tuple = ()  # frame indices with a long exposure (motion blur)
    dark_frames: tuple = ()  # frame indices with nothing detectable (lens covered)
    noise_grey: float = 2.0
    encoders: bool = False  # write encoders.csv (cumulative signed ticks as Duckietown counts them, int32)
    encoder_rate_hz: float = 30.0
    encoder_start_ticks: tuple = (123456, -98765)  # the counters' values at the log's start (counted since boot)
    ticks_per_revolution: int | None = 135  # in log.json when `encoders` (None: left out, as a DB18 log)
    # how a ROS bag export can differ (one at a time)
    camera_start_s: float = 0.021  # the first frame's time after the first wheel row (negative: the camera ran first)
    wheel_rows_at_frames: bool = False  # commands republished at exactly the frames' times
    duplicate_wheel_rows: bool = False  # every wheel row written twice (same time, same duties)
    board_inner_corners: tuple = (7, 5)  # (columns, rows)
    model: str = "DB21"
    newline: str = "\n"  # the CSVs' line ending ("\r\n": a Windows export)
    bom: bool = False  # a UTF-8 byte order mark before every text file
    trailing_blank_line: bool = False
    extra_meta: dict | None = None  # merged into log.json: {section or key: value}, a dict merges into a section
    seed: int = 0


@dataclass
class Truth:
    gain: float
    trim: float
    baseline_m: float
    K: np.ndarray
    dist: np.ndarray  # OpenCV plumb_bob k1, k2, p1, p2, k3
    T_body_camera: np.ndarray  # naocal's camera frame (x optical axis, y left, z up) in the body frame
    frame_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    radius_m: float = 0.0318
    k: float = 27.0
    # the share of the wheels' turning the ground does not follow (tyres scrubbing in turns): the body turns at
    # (1 - turn_slip) r (w_r - w_l) / b while the wheels (and their encoders) turn as commanded
    turn_slip: float = 0.0


def default_truth(seed: int = 0) -> Truth:
    rng = np.random.default_rng(1000 + seed)
    fx = 330.0 + rng.uniform(-8, 8)
    K = np.array([[fx, 0.0, 322.0 + rng.uniform(-6, 6)], [0.0, fx * 1.004, 238.0 + rng.uniform(-6, 6)],
                  [0.0, 0.0, 1.0]])
    dist = np.array([-0.27 + rng.uniform(-0.02, 0.02), 0.062 + rng.uniform(-0.01, 0.01), 0.001, -0.0008, 0.0])
    pitch, roll, yaw = math.radians(17.0 + rng.uniform(-1, 1)), math.radians(0.6), math.radians(-0.8)
    cy, sy, cp, sp, cr, sr = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll), \
        math.sin(roll)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])  # positive pitch about y (left): looks down
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = (0.07, 0.004, 0.105)
    return Truth(gain=0.93 + 0.02 * seed, trim=0.045 - 0.01 * seed, baseline_m=0.102, K=K, dist=dist,
                 T_body_camera=T)


# ------------------------------------------------------------------------------------------------ motion

def wheel_rates(left, right, truth: Truth):
    return left * truth.k / (truth.gain - truth.trim), right * truth.k / (truth.gain + truth.trim)


def arc(pose, v, omega, dt):
    x, y, th = pose
    if abs(omega) < 1e-12:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), th])
    th2 = th + omega * dt
    return np.array([x + v / omega * (math.sin(th2) - math.sin(th)), y - v / omega * (math.cos(th2) - math.cos(th)),
                     th2])


def duties_for(v, omega, truth: Truth, nominal: bool = True):
    """Duties the generator's own open-loop controller sends for a body velocity (nominal: gain 1, trim 0, the
    nominal baseline, as a robot before calibration)."""
    b = 0.1 if nominal else truth.baseline_m
    w_r, w_l = (v + omega * b / 2) / truth.radius_m, (v - omega * b / 2) / truth.radius_m
    return w_l / truth.k, w_r / truth.k


def plan(var: Variation, truth: Truth):
    """[(duration s, left duty, right duty, grab_while_still)] of the mission."""
    segs = []
    w = var.turn_rate_radps

    def turn(angle):
        left, right = duties_for(0.0, math.copysign(w, angle), truth)
        if var.turn == "continuous":
            segs.append((abs(angle) / w, left, right, False))
        else:  # steps of ~0.12 rad, stop 0.4 s to grab
            n = max(1, int(abs(angle) / 0.12))
            for _ in range(n):
                segs.append((abs(angle) / n / w, left, right, False))
                segs.append((0.4, 0.0, 0.0, True))

    segs.append((0.5, 0.0, 0.0, False))
    turn(-1.25)
    turn(+2.5)
    turn(math.pi - 1.25)  # to face the marker line behind the start (about: open loop)
    segs.append((0.4, 0.0, 0.0, False))
    v = var.line_speed_mps
    d = var.line_distance_m
    left, right = duties_for(v, 0.0, truth)
    segs.append((d / v, left, right, False))
    for sign in (+1, -1, -1, +1):  # an in-place wiggle with the markers in view
        l2, r2 = duties_for(0.0, sign * 0.4, truth)
        segs.append((0.4, l2, r2, False))
    for omega in (0.5, -0.5):  # an S-curve back
        l2, r2 = duties_for(-v, omega, truth)
        segs.append((d / v / 2, l2, r2, False))
    segs.append((0.5, 0.0, 0.0, False))
    return segs


def simulate(var: Variation, truth: Truth):
    """(wheel rows [(t, l, r)], frame times, a pose function) from the plan, on the Unix clock."""
    rng = np.random.default_rng(var.seed)
    segs = plan(var, truth)
    t = var.t0_s
    commands = []  # (t_start, l, r): the true commanded duties, piecewise constant
    still_grabs = []
    for dur, left, right, grab in segs:
        commands.append((t, left, right))
        if grab:
            still_grabs.append(t + dur / 2)
        t += dur
    t_end = t
    commands.append((t_end, 0.0, 0.0))
    # frame times: a free-running camera; with steps the frames at the grabs (mid-stop) only
    if var.turn == "steps":
        moving_from = commands[[i for i, s in enumerate(segs) if s[1] != 0 and abs(s[1] + s[2]) > 1e-9][0]][0]
        cam = np.arange(moving_from, t_end, 1.0 / var.fps)
        frame_t = np.sort(np.concatenate([still_grabs, cam]))
    else:
        first = var.t0_s + var.camera_start_s
        frame_t = first + np.arange(0.0, t_end - first - 0.029, 1.0 / var.fps)
    frame_t = frame_t + rng.uniform(-0.002, 0.002, len(frame_t))  # timestamp jitter
    frame_t = np.round(frame_t, 6)
    frame_t = frame_t[np.concatenate([[True], np.diff(frame_t) > 1e-4])]
    # rows as sent: republished at wheel_rate_hz with a phase of its own (or at the frames' times), plus a row at
    # every change
    period = 1.0 / var.wheel_rate_hz
    ticks = frame_t[(frame_t >= var.t0_s) & (frame_t < t_end)] if var.wheel_rows_at_frames else \
        var.t0_s + 0.0137 + np.arange(0.0, t_end - var.t0_s, period)
    starts = np.array([c[0] for c in commands])
    rows = {}
    for c in commands:
        rows[round(c[0], 6)] = (c[1], c[2])
    for tk in ticks:
        i = int(np.searchsorted(starts, tk, side="right") - 1)
        rows.setdefault(round(tk, 6), (commands[i][1], commands[i][2]))
    wheel_rows = sorted((tk, round(l, var.duty_decimals), round(r, var.duty_decimals)) for tk, (l, r) in rows.items())
    wt = np.array([r[0] for r in wheel_rows])
    wl = np.array([r[1] for r in wheel_rows])
    wr = np.array([r[2] for r in wheel_rows])

    def poses_at(times):
        """True poses at sorted `times`, integrating the rows as sent (exact arcs)."""
        out = np.zeros((len(times), 3))
        pose, t_prev = np.zeros(3), var.t0_s
        knots = np.union1d(wt, times)
        want = {float(x): i for i, x in enumerate(times)}
        for tk in knots:
            i = int(np.searchsorted(wt, t_prev, side="right") - 1)
            if i >= 0 and tk > t_prev:
                w_l, w_r = wheel_rates(wl[i], wr[i], truth)
                v = truth.radius_m * (w_r + w_l) / 2
                om = (1.0 - truth.turn_slip) * truth.radius_m * (w_r - w_l) / truth.baseline_m
                pose = arc(pose, v, om, tk - t_prev)
            t_prev = max(t_prev, float(tk))
            if float(tk) in want:
                out[want[float(tk)]] = pose
        return out

    return (wt, wl, wr), frame_t, poses_at


def wheel_angles(wheel_rows, times, truth: Truth):
    """(left, right) wheel angles (rad, 0 at the first row) at `times` of the commands as sent, each held."""
    wt, wl, wr = wheel_rows
    rates = np.array(wheel_rates(wl, wr, truth))  # (2, n): rad/s from each row to the next
    at_rows = np.concatenate([np.zeros((2, 1)), np.cumsum(rates[:, :-1] * np.diff(wt), axis=1)], axis=1)
    i = np.clip(np.searchsorted(wt, times, side="right") - 1, 0, None)
    held = np.asarray(times) >= wt[0]
    return np.where(held, at_rows[:, i] + rates[:, i] * (np.asarray(times) - wt[i]), 0.0)


def encoder_rows(var: Variation, wheel_rows, truth: Truth):
    """(times, ticks (2, n) int64) of encoders.csv: the wheels' angles (as commanded: slip or not) counted at
    135 a revolution from var.encoder_start_ticks, at var.encoder_rate_hz, as Duckietown's int32 counters."""
    wt = wheel_rows[0]
    enc_t = np.round(var.t0_s + 0.0071 + np.arange(0.0, wt[-1] - var.t0_s, 1.0 / var.encoder_rate_hz), 6)
    angles = wheel_angles(wheel_rows, enc_t, truth)
    ticks = np.floor(angles * 135 / (2 * math.pi)).astype(np.int64) + np.array(var.encoder_start_ticks)[:, None]
    return enc_t, (ticks + 2 ** 31) % 2 ** 32 - 2 ** 31  # Duckietown's counters are int32


# ------------------------------------------------------------------------------------------------ scene

@dataclass
class Plane:
    """A textured rectangle: texel (u, v) centre at origin + (u + 0.5) texel a + (v + 0.5) texel b."""

    origin: np.ndarray
    a: np.ndarray
    b: np.ndarray
    texel_m: float
    texture: np.ndarray
    background: float | None  # value outside the texture (None: not hit there)


def marker_plane(var: Variation) -> Plane:
    ids = var.marker_ids or tuple(range(var.n_markers))
    texel = var.marker_size_m / 48
    side, margin = 48, 12
    spacing = round(var.marker_spacing_m / texel)
    n = len(ids)
    length = margin * 2 + side + spacing * (n - 1)
    tex = np.full((side + 2 * margin, length), FLOOR, np.float32)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    for j, mid in enumerate(ids):
        c0 = margin + j * spacing
        tex[:, c0 - margin:c0 + side + margin] = PAPER
        img = cv2.aruco.generateImageMarker(dictionary, int(mid), side, borderBits=1)
        tex[margin:margin + side, c0:c0 + side] = np.where(img > 127, PAPER, INK)
    # columns (u) run along -x from behind the start; rows (v) along +y; marker tops (image row 0) towards -y... the
    # orientation is the same for all markers, that is all the issue says
    x0 = -var.first_marker_m + (margin + side / 2) * texel
    y0 = -(side / 2 + margin) * texel
    return Plane(np.array([x0, y0, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), texel, tex, FLOOR)


def board_planes(var: Variation) -> list:
    sq = 24
    texel = var.board_square_m / sq
    cols, rows = var.board_inner_corners[0] + 1, var.board_inner_corners[1] + 1  # squares
    m = sq  # white margin
    w, h = cols * sq + 2 * m, rows * sq + 2 * m
    tex = np.full((h, w), PAPER, np.float32)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2:
                tex[m + r * sq:m + (r + 1) * sq, m + c * sq:m + (c + 1) * sq] = INK
    planes = []
    for ang in var.board_angles_rad:
        centre = var.board_radius_m * np.array([math.cos(ang), math.sin(ang)])
        right = np.array([math.sin(ang), -math.cos(ang), 0.0])  # the viewer's right, facing the board from the start
        top = var.board_centre_m + h * texel / 2
        origin = np.array([centre[0], centre[1], top]) - right * w * texel / 2
        planes.append(Plane(origin, right, np.array([0.0, 0.0, -1.0]), texel, tex, None))
    return planes


def board_corners_world(var: Variation) -> np.ndarray:
    out = []
    for p in board_planes(var):
        sq = 24
        pts = [p.origin + (sq * (1 + c + 1)) * p.texel_m * p.a + (sq * (1 + r + 1)) * p.texel_m * p.b
               for r in range(var.board_inner_corners[1]) for c in range(var.board_inner_corners[0])]
        out.append(np.array(pts))
    return np.array(out)


# ------------------------------------------------------------------------------------------------ camera

class Camera:
    def __init__(self, truth: Truth, width=640, height=480, supersample=1):
        self.truth, self.w, self.h = truth, width, height
        s = supersample
        off = (np.arange(s) + 0.5) / s - 0.5
        u = (np.arange(width)[:, None] + off).ravel()
        v = (np.arange(height)[:, None] + off).ravel()
        uu, vv = np.meshgrid(u, v)
        pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2).astype(np.float64)
        norm = cv2.undistortPoints(pts, truth.K, truth.dist,
                                   criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
        norm = norm.reshape(-1, 2)
        self.shape = uu.shape
        self.s = s
        self.rays = np.column_stack([norm, np.ones(len(norm))]).astype(np.float32)  # OpenCV camera frame

    def world_from_cv(self, pose):
        x, y, th = pose
        T_wb = np.eye(4)
        T_wb[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
        T_wb[:2, 3] = (x, y)
        T_n_cv = np.eye(4)
        T_n_cv[:3, :3] = R_BODY_CV  # naocal camera frame -> OpenCV camera frame axes
        return T_wb @ self.truth.T_body_camera @ T_n_cv

    def project(self, pose, world_pts):
        T = np.linalg.inv(self.world_from_cv(pose))
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        pts = np.asarray(world_pts, float).reshape(-1, 3)
        uv, _ = cv2.projectPoints(pts, rvec, T[:3, 3], self.truth.K, self.truth.dist)
        depth = (pts @ T[:3, :3].T + T[:3, 3])[:, 2]
        return uv.reshape(-1, 2), depth

    def render_still(self, pose, planes):
        T = self.world_from_cv(pose)
        R, C = T[:3, :3], T[:3, 3]
        d = self.rays @ R.T.astype(np.float32)  # world directions
        img = np.where(d[:, 2] < 0, FLOOR, WALL).astype(np.float32)
        depth = np.full(len(d), np.inf)
        for p in planes:
            n = np.cross(p.a, p.b)
            dn = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = ((p.origin - C) @ n) / dn
            front = (lam > 1e-3) & (lam < depth)
            rel_a = (C - p.origin) @ p.a
            rel_b = (C - p.origin) @ p.b
            lam0 = np.where(front, lam, 0.0)
            u = (rel_a + lam0 * (d @ p.a)) / p.texel_m - 0.5
            v = (rel_b + lam0 * (d @ p.b)) / p.texel_m - 0.5
            th, tw = p.texture.shape
            inside = (u > -0.5) & (u < tw - 0.5) & (v > -0.5) & (v < th - 0.5)
            if p.background is None:
                front &= inside
            if not front.any():
                continue
            sample = cv2.remap(p.texture, u.reshape(self.shape).astype(np.float32),
                               v.reshape(self.shape).astype(np.float32),
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=p.background or 0.0).ravel()
            img = np.where(front, sample, img)
            depth = np.where(front, lam, depth)
        img = img.reshape(self.shape)
        if self.s == 1:
            return img
        return cv2.resize(img, (self.w, self.h), interpolation=cv2.INTER_AREA)


def make_log(directory, var: Variation = Variation(), truth: Truth | None = None, frames_from=None) -> Truth:
    """Write the log of `var` into `directory`; `frames_from`: a log made with the same scene, motion and frame count
    (a Variation differing in its files only), whose frames are linked instead of rendered again."""
    directory = Path(directory)
    (directory / "frames").mkdir(parents=True, exist_ok=True)
    truth = truth or default_truth(var.seed)
    (wt, wl, wr), frame_t, poses_at = simulate(var, truth)
    camera = None if frames_from else Camera(truth)
    planes = [marker_plane(var)] + board_planes(var)
    rng = np.random.default_rng(var.seed + 7)
    names = []
    poses = poses_at(frame_t)
    for i, t in enumerate(frame_t):
        if frames_from:
            names.append(f"frames/f{i:05d}{var.image_ext}")
            os.link(Path(frames_from) / names[-1], directory / names[-1])
            continue
        exposure = var.exposure_s  # the blur frames only: the others are instants (the turn moves 0.2 px in 1 ms)
        sub = np.linspace(t - exposure / 2, t + exposure / 2, 5) if i in var.blur_frames else np.array([t])
        img = np.mean([camera.render_still(p, planes) for p in poses_at(sub)], axis=0)
        if i in var.dark_frames:
            img = img * 0.03
        img = cv2.GaussianBlur(img, (0, 0), 0.5) + rng.normal(0, var.noise_grey, img.shape)
        name = f"frames/f{i:05d}{var.image_ext}"
        cv2.imwrite(str(directory / name), np.clip(img, 0, 255).astype(np.uint8),
                    [cv2.IMWRITE_JPEG_QUALITY, var.jpeg_quality] if var.image_ext != ".png" else [])
        names.append(name)
    fmt = f"{{:.{var.duty_decimals}f}}"
    repeat = 2 if var.duplicate_wheel_rows else 1
    write_csv(directory / "wheels.csv", "t_s,left_duty,right_duty",
              [f"{t:.6f},{fmt.format(l)},{fmt.format(r)}" for t, l, r in zip(wt, wl, wr) for _ in range(repeat)], var)
    write_csv(directory / "frames.csv", "t_s,file", [f"{t:.6f},{n}" for t, n in zip(frame_t, names)], var)
    wheels = {"radius_m": 0.0318, "baseline_m": 0.1, "k": 27.0, "limit": 1.0}
    if var.encoders:
        if var.ticks_per_revolution is not None:
            wheels["ticks_per_revolution"] = var.ticks_per_revolution
        enc_t, ticks = encoder_rows(var, (wt, wl, wr), truth)
        write_csv(directory / "encoders.csv", "t_s,left_ticks,right_ticks",
                  [f"{t:.6f},{a},{b}" for t, a, b in zip(enc_t, ticks[0], ticks[1])], var)
    meta = {"schema": "naocal.drive_log/1", "robot": {"id": "indep", "model": var.model},
            "camera": {"width_px": 640, "height_px": 480}, "wheels": wheels,
            "markers": {"family": "tag36h11", "size_m": var.marker_size_m},
            "boards": {"inner_corners": list(var.board_inner_corners), "square_m": var.board_square_m},
            "source": "tests/indep_drive_log.py (an independent generator)"}
    for key, value in (var.extra_meta or {}).items():
        if isinstance(value, dict):
            meta.setdefault(key, {}).update(value)
        else:
            meta[key] = value
    (directory / "log.json").write_bytes((b"\xef\xbb\xbf" if var.bom else b"") + json.dumps(meta, indent=1).encode())
    truth.frame_t_s, truth.frame_poses = frame_t, poses
    return truth


def write_csv(path, header, lines, var: Variation):
    text = var.newline.join([header, *lines]) + var.newline + (var.newline if var.trailing_blank_line else "")
    path.write_bytes((b"\xef\xbb\xbf" if var.bom else b"") + text.encode())


if __name__ == "__main__":
    import sys
    import time

    t = time.process_time()
    tr = make_log(sys.argv[1])
    print(len(tr.frame_t_s), "frames", time.process_time() - t, "s CPU")
