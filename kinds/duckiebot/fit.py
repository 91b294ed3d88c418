"""The Duckiebot's joint fit (issue 23): wheels, camera pose on the body and floor markers from every frame of
every drive of a drive log, through the core's one identification path (solver.identify.solve).

Unknowns (`DriveFit.names`):
- `gain`, `trim`: Duckietown's (kinds.duckiebot.kinematics), with k and the wheel radius known from the log (each
  scales the wheel speeds like gain does, so they cannot be told from it: gain absorbs them);
- `baseline_m`;
- the camera's pose on the body, `camera.x_m .y_m .z_m .roll_rad .pitch_rad .yaw_rad`
  (T_base_camera = translation, then R = Rz(yaw) Ry(pitch) Rx(roll): kinds.duckiebot.robot.camera_mount);
- `anchor.x_m .y_m .theta_rad`: the robot's pose at the first frame with a marker in view (the start of the
  observed drive). Anchored there, not at the log's first row: no frame before it sees a marker, so a free pose at
  the log's start would absorb all motion before the anchor exactly; anchoring at the first seen frame is the same
  model without the long lever arm of the turns before it. A log in segments (Drive.segment_t_s: a run stopped
  and resumed wherever the robot then stood, drive_log's segments.csv) has one anchor per segment,
  `anchor<s>.x_m .y_m .theta_rad` for segment s >= 1 (anchor_names), at that segment's first frame with a marker
  in view, driven by that segment's commands only; the wheels, the camera and the markers are shared. A segment
  seen in fewer than MIN_SEGMENT_FRAMES frames is left out, with a warning;
- `corner_bias_px`: the detector's corners lie inside the true ones (BIAS);
- optional wheel effects, each off unless named (`fit_drive(effects=...)`; the registry's differential-drive
  effects, solver/effects/ with the drive_parameters hook: WHEEL_EFFECTS): `dead_zone`, `slip_s_per_m`,
  `wheel_lag_s`, `speed_trim`, `wheel_lag_difference_s` (kinds.duckiebot.diagnose names the missing one); and
  Duckietown's 8-bit PWM wheel driver between the duties and the motors (PWM_DRIVER, Drive.pwm_driver: a choice
  of model without a parameter; named where the log's robot is known to have it, or by identify --effects);
- `marker<id>.x_m .y_m .yaw_rad` of every marker seen but one, the reference (the gauge): the floor's frame is
  arbitrary (a planar rigid motion, 3 DoF), so the reference marker's pose is the world frame (0, 0, 0). The
  reference is the marker seen in the most frames (ties: the smallest id): it is the best tied to the drive, so the
  other markers' and the anchor's stds are relative to the best-known frame.

Observations: the detected marker corners, rectified (undistorted with the calibrated lens, whatever its model,
and re-projected with its camera matrix K), in pixels. The robot's pose at each frame is integrated from the wheel
commands (each held until the next row) with Duckietown's forward kinematics, exact arcs; the Jacobian of each
pose with respect to the kinematics and the anchor is propagated exactly through every arc (forward mode).

Clusters of the cluster-robust covariance: a marker's sighting run (sighting_runs: the frames in a row that see it).
A marker seen from nearly the same place in consecutive frames is detected with nearly the same error (its corners'
bias at that size, blur and angle), so a run's corners share one error; one cluster per frame counted each of a
run's frames as independent, and the stds came out small (realistic mock, seeds 1-5: camera.pitch_rad 1.6, 2.4, 2.9,
0.8, 3.5 stds off; 1.2, 1.2, 1.7, 0.4, 1.9 by runs). Drive segments would leave 2-4 clusters for 20-50 parameters,
far too few for the sandwich. Errors shared by the whole log (the lens's intrinsics, the detector's corner error
over its window) are no cluster's: kinds.duckiebot.identify carries them into the covariance as considered
nuisances (DriveFit.considered, std_parts).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from naocal.kinds.duckiebot.kinematics import PWM_MAX, PWM_MIN, duty_to_pwm
from naocal.solver.camera import project
from naocal.solver.effects import DRIVE_EFFECTS
from naocal.solver.effects import EFFECTS as REGISTRY
from naocal.solver.errors import SolveError
from naocal.solver.identify import (MAD_TO_SIGMA, OUTLIER_SCALES, Normal, check_identifiable, last_pass_cached,
                                    solve, trimmed)
from naocal.solver.transforms import d_rot_x, d_rot_y, d_rot_z, make_transform, rot_rpy, rot_x, rot_y, rot_z, rpy_from_rot

KINEMATIC = ("gain", "trim", "baseline_m")
# The detector's corners lie inside the marker's true ones, the more the smaller the marker (a rendered log, seed 1:
# 0.20 px for sides of 30-100 px, 0.36 px at 20-30, 0.41 px at 15-20, 0.70 px below 15; ArUco's sub-pixel refinement
# on a blurred L-corner). Unmodelled, the markers look smaller, so farther, and the gain came out 0.7 % off (8 stds).
# Fitted: one bias, each corner moved along its marker's image diagonal by corner_bias_px (a second term, px^2 over
# the half-diagonal, made the gain worse on the same log: 0.40 % off against 0.30 %).
BIAS = "corner_bias_px"
CAMERA = ("camera.x_m", "camera.y_m", "camera.z_m", "camera.roll_rad", "camera.pitch_rad", "camera.yaw_rad")
ANCHOR = ("anchor.x_m", "anchor.y_m", "anchor.theta_rad")
SEGMENT_ANCHOR = re.compile(r"anchor([1-9]\d{0,8})\.(x_m|y_m|theta_rad)")  # a later segment's anchor (anchor_names)
# a segment seen in fewer frames is left out of the fit: one frame fixes its anchor and tells nothing of the wheels
MIN_SEGMENT_FRAMES = 2
# The variables' scales (solver.identify.levenberg_marquardt conditions on them; the identifiability policy judges
# the columns scaled by them): about the prior uncertainty of each.
SCALES = {"gain": 0.1, "trim": 0.05, "baseline_m": 0.003, "camera.x_m": 0.005, "camera.y_m": 0.005,
          "camera.z_m": 0.005, "camera.roll_rad": 0.02, "camera.pitch_rad": 0.03, "camera.yaw_rad": 0.03,
          "anchor.x_m": 0.05, "anchor.y_m": 0.05, "anchor.theta_rad": 0.05, BIAS: 0.1}
MARKER_SCALES = (0.05, 0.05, 0.05)  # x, y, yaw
# The wheel effects: the differential drive's terms of the effect registry (solver/effects/, each one module with
# the drive_parameters hook; docs/EFFECTS.md), each off unless named (fit_drive(effects=...)), in the registry's
# order. Each parameter's value 0 is the base model; this model's term for each (keyed by the parameter's name):
# dead_zone and speed_trim in commanded_wheel_speeds, slip_s_per_m in body_motion, wheel_lag_s and
# wheel_lag_difference_s in _lagged; pwm_driver, a choice of model without a parameter: Drive.pwm_driver.
WHEEL_EFFECTS = {name: REGISTRY[name] for name in DRIVE_EFFECTS}
ALL_EFFECTS = tuple(WHEEL_EFFECTS)  # every name fit_drive(effects=...) takes, in its order
# {effect: its parameters' names} of the effects that have parameters
EFFECTS = {name: tuple(p.name for p in e.drive_parameters()) for name, e in WHEEL_EFFECTS.items()
           if e.drive_parameters()}
SCALES.update({p.name: p.scale for e in WHEEL_EFFECTS.values() for p in e.drive_parameters()})
# where each effect's parameter starts (0 unless its effect says: a wheel lag's signature vanishes at 0)
EFFECT_START = {p.name: p.start for e in WHEEL_EFFECTS.values() for p in e.drive_parameters() if p.start}
PWM_DRIVER = "pwm_driver"  # the effect whose term is Drive.pwm_driver (kinematics.duty_to_pwm's driver)
# fitted from the fit without them (fit_drive)
LAG_EFFECTS = tuple(name for name, e in WHEEL_EFFECTS.items() if e.drive_from_base_fit)
LAG_SUBSTEP_S = 0.01  # with wheel_lag: one arc per this much time, at the exact mean lagged wheel speeds
MAX_ITERATIONS = 100
# DriveFit.std_parts: the statistical std (cluster-robust), then the considered nuisances' (model errors the fit
# takes as known, their effect on the estimate carried into the stds: kinds.duckiebot.identify.add_considered)
STATISTICAL = "fit"
LENS = "lens"  # the intrinsics, fitted beforehand (identify.add_lens_covariance)
CORNER_WINDOW = "corner_window"  # the detector's corner error over its window's size (identify.add_corner_covariance)
STD_PARTS = (STATISTICAL, LENS, CORNER_WINDOW)
# sighting_runs: a marker missed in up to this many frames less one (a failed detection) stays in one run
SIGHTING_GAP_FRAMES = 3
# drive_start: the planar poses' scale (m; the heading's, POSE_SCALE_M / POSE_HEADING_M rad) and iterations
POSE_SCALE_M, POSE_HEADING_M, POSE_FIT_ITERATIONS = 0.02, 0.2, 50
START_GAIN_CHORD_M = 0.05  # start_values' gain: distances between frames this far apart (nominal), not consecutive


def marker_offsets(size_m: float) -> np.ndarray:
    """(4, 2) corners of a marker's black square about its centre, in its own frame, in the detector's order
    (clockwise from the marker image's top-left; the image's top along the marker's +x)."""
    h = size_m / 2.0
    return np.array([[h, h], [h, -h], [-h, -h], [-h, h]])


@dataclass(frozen=True)
class Sightings:
    """The detected marker corners of a log, one row per corner: frame index, marker id, corner (0-3), the
    rectified pixel (u, v) (undistorted, on the lens's K) and its expected noise (px; None: 1 px for all)."""

    frame: np.ndarray  # (N,) int
    marker: np.ndarray  # (N,) int: marker id
    corner: np.ndarray  # (N,) int
    uv_px: np.ndarray  # (N, 2)
    noise_px: np.ndarray | None = None  # (N,)

    @property
    def sigma_px(self) -> np.ndarray:
        return np.ones(len(self.frame)) if self.noise_px is None else np.asarray(self.noise_px, dtype=float)

    def subset(self, rows) -> "Sightings":
        return Sightings(self.frame[rows], self.marker[rows], self.corner[rows], self.uv_px[rows],
                         None if self.noise_px is None else self.noise_px[rows])


@dataclass(frozen=True)
class Drive:
    """What the fit needs of a drive log: the commands as sent, the frames' times, k, the wheel radius, limit."""

    wheel_t_s: np.ndarray
    left_duty: np.ndarray
    right_duty: np.ndarray
    frame_t_s: np.ndarray
    k: float
    radius_m: float
    baseline_m: float  # the log's nominal: the start value
    limit: float = 1.0
    # the duties went through Duckietown's wheel driver (kinematics.duty_to_pwm: an 8-bit PWM, floored): the
    # motors receive motor_duties(), not the duties logged. Only where the log's robot is known to have that driver
    # (the mission's mock and ROS bridge): an independent log generator may send exact duties
    pwm_driver: bool = False
    # the log's breaks (drive_log's segments.csv): a command before a break does not move the robot after it
    segment_t_s: tuple = ()

    @classmethod
    def of_log(cls, log, *, pwm_driver: bool = False) -> "Drive":
        """The log's drive, a row that repeats the row before it in its segment left out: it holds what already
        holds (a recorder republishing commands at a high rate would otherwise cost an arc a row)."""
        segment_t_s = tuple(float(t) for t in log.segment_t_s)
        segment = np.searchsorted(np.asarray(segment_t_s, dtype=float), log.wheel_t_s, side="right")
        new = np.ones(len(log.wheel_t_s), dtype=bool)
        new[1:] = ((np.diff(log.left_duty) != 0) | (np.diff(log.right_duty) != 0) | (np.diff(segment) != 0))
        return cls(log.wheel_t_s[new], log.left_duty[new], log.right_duty[new], log.frame_t_s, log.wheels.k,
                   log.wheels.radius_m, log.wheels.baseline_m, log.wheels.limit, pwm_driver, segment_t_s)

    def segment_of(self, t_s) -> np.ndarray:
        """The segment (0, 1, ...) each time in t_s belongs to: the number of breaks at or before it."""
        return np.searchsorted(np.asarray(self.segment_t_s, dtype=float), np.asarray(t_s, dtype=float), side="right")

    def segment(self, s: int) -> "Drive":
        """Segment s alone: its wheel commands (the robot at rest before the first), every frame's time."""
        if not self.segment_t_s:
            return self
        rows = self.segment_of(self.wheel_t_s) == s
        return replace(self, wheel_t_s=self.wheel_t_s[rows], left_duty=self.left_duty[rows],
                       right_duty=self.right_duty[rows], segment_t_s=())

    def motor_duties(self) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) duties as the motors receive them: as logged, or with pwm_driver driver_duty's."""
        if not self.pwm_driver:
            return self.left_duty, self.right_duty
        return driver_duty(self.left_duty), driver_duty(self.right_duty)


def driver_duty(u):
    """The duty Duckietown's wheel driver gives the motors for the duty `u` sent: its PWM (kinematics.duty_to_pwm,
    floored) above its floor PWM_MIN as a duty, sign(u) (pwm - PWM_MIN) / (PWM_MAX - PWM_MIN) (0 where it sends no
    PWM)."""
    return np.sign(u) * np.maximum(duty_to_pwm(u) - PWM_MIN, 0) / (PWM_MAX - PWM_MIN)


def pose_parameters(T_base_camera) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) of a camera pose on the body (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    T = np.asarray(T_base_camera, dtype=float)
    return np.array([*T[:3, 3], *rpy_from_rot(T[:3, :3])])


def camera_transform(p) -> np.ndarray:
    """T_base_camera of (x, y, z, roll, pitch, yaw)."""
    return make_transform(rot_rpy(p[3], p[4], p[5]), p[:3])


# ------------------------------------------------------------------------------------------------ the trajectory

def _sinc_and_derivative(a):
    """(sin a / a, its derivative), accurate near 0."""
    a = float(a)
    if abs(a) < 1e-4:
        return 1.0 - a * a / 6.0, -a / 3.0 + a ** 3 / 30.0
    s, c = math.sin(a), math.cos(a)
    return s / a, (a * c - s) / (a * a)


def trajectory(drive: Drive, gain: float, trim: float, baseline_m: float, anchor, anchor_t_s: float, times_s,
               effects=None):
    """Poses (m, 3) at `times_s` (each at or after anchor_t_s, increasing) of a robot at `anchor` (x, y, theta) at
    anchor_t_s, driven by the log's commands (each held until the next row; 0 before the first) through
    Duckietown's forward kinematics, exact arcs, and their exact Jacobian (m, 3, 6 + E) with respect to
    (gain, trim, baseline, anchor x, y, theta, then the `effects` {parameter: value} in their order: EFFECTS).
    With wheel_lag_s the wheel speeds are a state from the log's first row on, integrated in LAG_SUBSTEP_S steps
    (each an arc at the step's exact mean wheel speeds)."""
    effects = dict(effects or {})
    times_s = np.asarray(times_s, dtype=float)
    col = {n: i for i, n in enumerate(KINEMATIC + ANCHOR + tuple(effects))}
    p = {"gain": gain, "trim": trim, "baseline_m": baseline_m, **effects}
    lag = "wheel_lag_s" in effects or "wheel_lag_difference_s" in effects
    start = min(float(drive.wheel_t_s[0]), float(anchor_t_s)) if lag and len(drive.wheel_t_s) else float(anchor_t_s)
    end = float(times_s.max()) if len(times_s) else start  # the commands after the last time wanted move nothing wanted
    knots = np.union1d(drive.wheel_t_s[(drive.wheel_t_s > start) & (drive.wheel_t_s <= end)], times_s)
    if lag:
        knots = np.union1d(knots, [anchor_t_s])
    pose = np.asarray(anchor, dtype=float).copy()
    J = np.zeros((3, len(col)))
    J[:, 3:6] = np.eye(3)
    poses, jacobians = np.zeros((len(times_s), 3)), np.zeros((len(times_s), 3, len(col)))
    want = {float(t): i for i, t in enumerate(times_s)}
    r, k, t_prev = drive.radius_m, drive.k, start
    left_duty, right_duty = drive.motor_duties()
    w, dw = np.zeros(2), np.zeros((2, len(col)))  # the lagged wheel speeds (left, right) and their derivatives
    if t_prev in want:
        poses[want[t_prev]], jacobians[want[t_prev]] = pose, J
    for t in knots:
        dt = float(t) - t_prev
        if dt > 0:
            row = np.searchsorted(drive.wheel_t_s, t_prev, side="right") - 1
            u_l, u_r = (left_duty[row], right_duty[row]) if row >= 0 else (0.0, 0.0)
            moving = t_prev >= anchor_t_s
            if lag:
                wc, dwc = commanded_wheel_speeds(u_l, u_r, p, k, col)
                pose, J, w, dw = _lagged(pose, J, w, dw, wc, dwc, p, col, r, dt, moving)
            elif u_l != 0.0 or u_r != 0.0:
                wc, dwc = commanded_wheel_speeds(u_l, u_r, p, k, col)
                pose, J = _arc(pose, J, *body_motion(wc, dwc, p, col, r), dt)
        t_prev = float(t)
        if t_prev in want:
            poses[want[t_prev]], jacobians[want[t_prev]] = pose, J
    return poses, jacobians


def commanded_wheel_speeds(u_left, u_right, p: dict, k: float, col=None):
    """(w (2,) rad/s of the left and right wheel, d w / d parameters (2, len(col)) or None) for held duties, by
    Duckietown's forward map w = u k / (gain -+ trim) with the optional effects of `p`: dead_zone (the duty's
    magnitude less the dead zone, 0 inside it) and speed_trim (trim + speed_trim |u| after the dead zone)."""
    dead, speed_trim = p.get("dead_zone", 0.0), p.get("speed_trim", 0.0)
    w = np.zeros(2)
    dw = None if col is None else np.zeros((2, len(col)))
    for i, (u, side) in enumerate(((u_left, -1.0), (u_right, 1.0))):
        sign = math.copysign(1.0, u)
        magnitude = max(abs(u) - dead, 0.0) if u != 0.0 else 0.0  # a stopped wheel stays stopped
        den = p["gain"] + side * (p["trim"] + speed_trim * magnitude)
        w[i] = sign * magnitude * k / den
        if dw is None:
            continue
        dw[i, col["gain"]] = -w[i] / den
        dw[i, col["trim"]] = -side * w[i] / den
        if "speed_trim" in col:
            dw[i, col["speed_trim"]] = -side * magnitude * w[i] / den
        if "dead_zone" in col and magnitude > 0.0:
            dw[i, col["dead_zone"]] = -sign * k / den + side * speed_trim * w[i] / den
    return w, dw


def body_motion(w, dw, p: dict, col, r: float):
    """(v, omega, d v, d omega) of the robot whose wheels turn at w (left, right) (derivatives dw (2, P) or None: then
    d v, d omega are None too): Duckietown's
    v = r (w_r + w_l) / 2, omega = r (w_r - w_l) / b, both scaled by 1 - slip r |w_r - w_l| (slip_s_per_m: the
    wheels' ground speed lost in turns, growing with the turn rate)."""
    b, slip = p["baseline_m"], p.get("slip_s_per_m", 0.0)
    difference = w[1] - w[0]
    f = 1.0 - slip * r * abs(difference)
    v, omega = f * r * (w[1] + w[0]) / 2.0, f * r * difference / b
    if dw is None:
        return v, omega, None, None
    df = -slip * r * math.copysign(1.0, difference) * (dw[1] - dw[0])
    if "slip_s_per_m" in col:
        df[col["slip_s_per_m"]] -= r * abs(difference)
    dv = df * r * (w[1] + w[0]) / 2.0 + f * r * (dw[1] + dw[0]) / 2.0
    domega = df * r * difference / b + f * r * (dw[1] - dw[0]) / b
    domega[col["baseline_m"]] -= omega / b
    return v, omega, dv, domega


def lag_factors(tau_s: float, h_s: float):
    """(e, m, de/dtau, dm/dtau) of a first-order lag over a step h: the speed's remaining share of its distance to
    the command at the step's end, e = exp(-h / tau), and over the step on average, m = tau / h (1 - e); the limit
    tau -> 0 (no lag) included."""
    if tau_s <= 1e-12:
        return 0.0, 0.0, 0.0, 1.0 / h_s
    e = math.exp(-h_s / tau_s)
    return e, tau_s / h_s * (1.0 - e), e * h_s / tau_s ** 2, (1.0 - e) / h_s - e / tau_s


def _lagged(pose, J, w, dw, wc, dwc, p, col, r, dt, moving):
    """A held command with lagged wheels: the wheel speeds (w, dw) follow the commanded ones (wc, dwc) with time
    constant wheel_lag_s; the pose moves (if `moving`: from the anchor on) by one arc per step at the mean speeds."""
    steps = max(1, math.ceil(dt / LAG_SUBSTEP_S - 1e-9))
    h = dt / steps
    lag, half = p.get("wheel_lag_s", 0.0), p.get("wheel_lag_difference_s", 0.0) / 2.0
    sides = np.array([-1.0, 1.0])
    factors = np.array([lag_factors(t, h) for t in (lag - half, lag + half)])  # (2 wheels, e m de dm)
    e, m, de, dm = factors[:, 0], factors[:, 1], factors[:, 2], factors[:, 3]
    # d / d wheel_lag_s and d / d wheel_lag_difference_s of each wheel's factors (its lag's derivative: 1, -+1/2)
    lag_columns = [(col[n], d) for n, d in (("wheel_lag_s", 1.0), ("wheel_lag_difference_s", sides / 2.0))
                   if n in col]
    for _ in range(steps):
        gap, dgap = w - wc, dw - dwc
        if moving and (np.any(w) or np.any(wc) or np.any(dgap)):  # at rest with every derivative 0: no move
            mean, dmean = wc + gap * m, dwc + dgap * m[:, None]
            for c, d in lag_columns:
                dmean[:, c] += gap * dm * d
            pose, J = _arc(pose, J, *body_motion(mean, dmean, p, col, r), h)
        w, dw = wc + gap * e, dwc + dgap * e[:, None]
        for c, d in lag_columns:
            dw[:, c] += gap * de * d
    return pose, J, w, dw


def _arc(pose, J, v, omega, dv, domega, dt):
    """The pose after moving at (v, omega) for dt (exact arc) and the propagated Jacobian (3, P), given the
    velocities' derivatives dv, domega (P,) with respect to the parameters."""
    a = omega * dt / 2.0
    S, dS = _sinc_and_derivative(a)
    chord = v * dt * S
    heading = pose[2] + a
    ch, sh = math.cos(heading), math.sin(heading)
    new = np.array([pose[0] + chord * ch, pose[1] + chord * sh, pose[2] + 2.0 * a])
    Phi = np.array([[1.0, 0.0, -chord * sh], [0.0, 1.0, chord * ch], [0.0, 0.0, 1.0]])
    dchord_dv, dchord_domega = dt * S, v * dt * dS * dt / 2.0
    G = np.array([[dchord_dv * ch, dchord_domega * ch - chord * sh * dt / 2.0],
                  [dchord_dv * sh, dchord_domega * sh + chord * ch * dt / 2.0],
                  [0.0, dt]])  # d new / d (v, omega)
    return new, Phi @ J + G @ np.vstack([dv, domega])


def anchor_names(segment: int) -> tuple:
    """The names of segment `segment`'s anchor: ANCHOR for the first, anchor<s>.* after a break."""
    return ANCHOR if segment == 0 else tuple(f"anchor{segment}.{n.split('.', 1)[1]}" for n in ANCHOR)


def anchor_times(drive: Drive, frames) -> dict:
    """{segment: the time of its first frame among `frames` (indices, increasing)}: where its anchor is."""
    times = drive.frame_t_s[np.asarray(frames, dtype=int)]
    segments = drive.segment_of(times)
    return {int(s): float(times[np.argmax(segments == s)]) for s in np.unique(segments)}


def drive_poses(drive: Drive, x, column: dict, effects, times_s, anchors: dict):
    """(poses (F, 3), d poses / d x[columns] (F, 3, C), columns (C,)) at times_s (increasing), each pose from its
    segment's anchor (anchor_names, at anchors[segment]: anchor_times) through that segment's commands
    (trajectory); `columns`: x's indices (of `column`) of the kinematics, every anchor and the effects' parameters
    `effects`, those the poses depend on."""
    times_s = np.asarray(times_s, dtype=float)
    segments = drive.segment_of(times_s)
    names = list(KINEMATIC) + [n for s in sorted(anchors) for n in anchor_names(s)] + list(effects)
    columns = np.array([column[n] for n in names], dtype=int)
    local = {n: i for i, n in enumerate(names)}
    poses, J = np.zeros((len(times_s), 3)), np.zeros((len(times_s), 3, len(names)))
    kin = [x[column[n]] for n in KINEMATIC]
    values = {n: x[column[n]] for n in effects}
    for s in np.unique(segments):
        rows = np.flatnonzero(segments == s)
        order = KINEMATIC + anchor_names(int(s)) + tuple(effects)
        p, dp = trajectory(drive.segment(int(s)), *kin, x[[column[n] for n in anchor_names(int(s))]],
                           anchors[int(s)], times_s[rows], values)
        poses[rows] = p
        J[np.ix_(rows, range(3), [local[n] for n in order])] = dp
    return poses, J, columns


# ------------------------------------------------------------------------------------------------ the equations

class DriveEquations:
    """The joint fit's normal equations for solver.identify.solve (as kinds.arm.identify.ArmEquations are the
    arm's): residuals = (predicted - detected rectified pixels) / the corner's expected noise (N, 2), one row per
    corner, each row's score for the cluster-robust covariance (its cluster: sighting_runs)."""

    def __init__(self, drive: Drive, sightings: Sightings, K, marker_size_m: float, reference: int,
                 names, base, free):
        self.drive, self.obs = drive, sightings
        self.K = np.asarray(K, dtype=float)
        self.offsets = marker_offsets(marker_size_m)
        self.reference = int(reference)
        self.names = list(names)
        self.base = np.asarray(base, dtype=float)
        self.index = np.flatnonzero(free)
        self.scales = parameter_scales(self.names)[self.index]
        self.column = {n: i for i, n in enumerate(self.names)}
        self.effect_parameters = tuple(n for names in EFFECTS.values() for n in names if n in self.column)
        self.frames = np.unique(sightings.frame)
        self.anchors = anchor_times(drive, self.frames)  # {segment: its anchor's time}
        self.row_frame = np.searchsorted(self.frames, sightings.frame)
        self.inverse_sigma = 1.0 / sightings.sigma_px

    @property
    def anchor_t_s(self) -> float:
        """The first segment's anchor time."""
        return self.anchors[min(self.anchors)]

    def values(self, free) -> np.ndarray:
        x = self.base.copy()
        x[self.index] = free
        return x

    def predict(self, x, *, jacobian=True):
        """(pixels (N, 2), d pixels / d x (N, 2, P) or None) at the full vector x: each corner's projection moved
        outward along its marker's image diagonal by corner_bias_px (BIAS)."""
        corner_uv, corner_J = self._project(x, self.offsets[self.obs.corner], jacobian)
        centre_uv, centre_J = self._project(x, np.zeros((len(self.obs.frame), 2)), jacobian)
        d = corner_uv - centre_uv
        L = np.linalg.norm(d, axis=1)
        b = x[self.column[BIAS]]
        uv = corner_uv + b * d / L[:, None]
        if not jacobian:
            return uv, None
        # d (d / L) = (I / L - d d^T / L^3) d d
        M = np.eye(2)[None] / L[:, None, None] - d[:, :, None] * d[:, None, :] / (L ** 3)[:, None, None]
        J = corner_J + b * M @ (corner_J - centre_J)
        J[:, :, self.column[BIAS]] = d / L[:, None]
        return uv, J

    def _project(self, x, o, jacobian):
        """(pixels (N, 2), d pixels / d x) of the points at offsets o (N, 2) in each row's marker frame."""
        c = self.column
        obs, N, P = self.obs, len(self.obs.frame), len(self.names)
        poses, dposes, pose_columns = drive_poses(self.drive, x, c, self.effect_parameters,
                                                  self.drive.frame_t_s[self.frames], self.anchors)
        pose, dpose = poses[self.row_frame], dposes[self.row_frame]
        # markers: the reference at the origin, the others from x
        m_xy, m_yaw = np.zeros((N, 2)), np.zeros(N)
        m_cols = np.full((N, 3), -1)
        others = obs.marker != self.reference
        for i in np.flatnonzero(others):
            m_cols[i] = [c[f"marker{obs.marker[i]}.x_m"], c[f"marker{obs.marker[i]}.y_m"],
                         c[f"marker{obs.marker[i]}.yaw_rad"]]
        m_xy[others] = x[m_cols[others, :2]]
        m_yaw[others] = x[m_cols[others, 2]]
        cy, sy = np.cos(m_yaw), np.sin(m_yaw)
        world = m_xy + np.stack([cy * o[:, 0] - sy * o[:, 1], sy * o[:, 0] + cy * o[:, 1]], axis=1)
        ct, st = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        rel = world - pose[:, :2]
        base_xy = np.stack([ct * rel[:, 0] + st * rel[:, 1], -st * rel[:, 0] + ct * rel[:, 1]], axis=1)
        cam = x[[c[n] for n in CAMERA]]
        R = rot_rpy(cam[3], cam[4], cam[5])
        d = np.column_stack([base_xy, np.zeros(N)]) - cam[:3]
        p_cam = d @ R  # R^T d per row
        K = self.K
        proj = project(p_cam, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        if not jacobian:
            return proj.uv_px, None
        A = proj.point_jacobian()  # (N, 2, 3)
        Jx = np.zeros((N, 2, P))
        AR = A @ R.T  # d uv / d base point (N, 2, 3)
        for j, name in enumerate(CAMERA[:3]):
            Jx[:, :, c[name]] = -AR[:, :, j]
        dR = (rot_z(cam[5]) @ rot_y(cam[4]) @ d_rot_x(cam[3]), rot_z(cam[5]) @ d_rot_y(cam[4]) @ rot_x(cam[3]),
              d_rot_z(cam[5]) @ rot_y(cam[4]) @ rot_x(cam[3]))
        for name, D in zip(CAMERA[3:], dR):
            Jx[:, :, c[name]] = np.einsum("nij,nj->ni", A, d @ D)
        B = AR[:, :, :2]  # d uv / d base xy
        RT = np.stack([np.stack([ct, st], -1), np.stack([-st, ct], -1)], axis=1)  # (N, 2, 2) R(theta)^T
        dRT = np.stack([np.stack([-st, ct], -1), np.stack([-ct, -st], -1)], axis=1)
        d_base_d_pose = np.concatenate([-RT, np.einsum("nij,nj->ni", dRT, rel)[:, :, None]], axis=2)  # (N, 2, 3)
        Jx[:, :, pose_columns] += B @ d_base_d_pose @ dpose
        BR = B @ RT  # d uv / d world xy
        d_world_d_yaw = np.stack([-sy * o[:, 0] - cy * o[:, 1], cy * o[:, 0] - sy * o[:, 1]], axis=1)
        rows = np.flatnonzero(others)
        Jx[rows, :, m_cols[rows, 0]] = BR[rows, :, 0]
        Jx[rows, :, m_cols[rows, 1]] = BR[rows, :, 1]
        Jx[rows, :, m_cols[rows, 2]] = np.einsum("nij,nj->ni", BR[rows], d_world_d_yaw[rows])
        return proj.uv_px, Jx

    def __call__(self, free, *, weights=None, jacobian: bool = True) -> Normal:
        uv, Jx = self.predict(self.values(free), jacobian=jacobian)
        r = (uv - self.obs.uv_px) * self.inverse_sigma[:, None]
        rw = r if weights is None else r * np.sqrt(weights)[:, None]
        p = len(self.index)
        if not jacobian:
            return Normal(np.zeros((p, p)), np.zeros(p), 0.5 * float(np.sum(rw ** 2)), r, np.zeros((len(r), p)))
        Js = Jx[:, :, self.index] * self.scales * self.inverse_sigma[:, None, None]
        flat = Js.reshape(-1, p)
        A = flat.T @ flat
        return Normal(0.5 * (A + A.T), flat.T @ rw.reshape(-1), 0.5 * float(np.sum(rw ** 2)), r,
                      np.einsum("ncp,nc->np", Js, rw))

    def dense(self, free):
        """(r, J) flattened, unscaled: for scipy's solvers (robust losses)."""
        uv, Jx = self.predict(self.values(free))
        w = self.inverse_sigma[:, None]
        return ((uv - self.obs.uv_px) * w).reshape(-1), (Jx[:, :, self.index] * w[:, :, None]).reshape(
            -1, len(self.index))


def sighting_runs(frame, marker, segment=None, max_gap: int = SIGHTING_GAP_FRAMES) -> np.ndarray:
    """(N,) the cluster of each corner (frame and marker id per row): its marker's run of sightings, frames that
    see it no more than `max_gap` frames apart (the module docstring's clusters). `segment` (N,), the log's segment
    of each row (Drive.segment_of): a break ends a run (the robot was carried: what follows is another run's)."""
    frame, marker = np.asarray(frame), np.asarray(marker)
    segment = np.zeros(len(frame), dtype=int) if segment is None else np.asarray(segment)
    labels, first = np.zeros(len(frame), dtype=int), 0
    for m, s in np.unique(np.column_stack([marker, segment]), axis=0):
        rows = np.flatnonzero((marker == m) & (segment == s))
        seen = np.unique(frame[rows])
        run = np.concatenate([[0], np.cumsum(np.diff(seen) > max_gap)])
        labels[rows] = first + run[np.searchsorted(seen, frame[rows])]
        first += int(run[-1]) + 1
    return labels


def parameter_scales(names) -> np.ndarray:
    def scale(n):
        if n in SCALES:
            return SCALES[n]
        if SEGMENT_ANCHOR.fullmatch(n):  # a later segment's anchor: the first's
            return SCALES[f"anchor.{n.split('.', 1)[1]}"]
        return MARKER_SCALES[("x_m", "y_m", "yaw_rad").index(n.split(".")[1])]

    return np.array([scale(n) for n in names])


# ------------------------------------------------------------------------------------------------ start values

def _floor_points(uv_px, K, T_base_camera) -> np.ndarray:
    """Where rectified pixels' rays meet the floor (z = 0), in the base frame (N, 2)."""
    xn = (uv_px[:, 0] - K[0, 2]) / K[0, 0]
    yn = (uv_px[:, 1] - K[1, 2]) / K[1, 1]
    rays = np.column_stack([np.ones(len(xn)), -xn, -yn]) @ T_base_camera[:3, :3].T
    o = T_base_camera[:3, 3]
    s = -o[2] / np.minimum(rays[:, 2], -1e-6)
    return o[:2] + s[:, None] * rays[:, :2]


def marker_on_floor(uv_px, corners, K, T_base_camera, marker_size_m) -> np.ndarray:
    """(x, y, yaw) of a marker in the body frame from its rectified corner pixels (`corners`: which of the four each
    is), the rays meeting the floor under the camera pose T_base_camera (2-D Procrustes of the corners)."""
    floor = _floor_points(np.asarray(uv_px, dtype=float), K, T_base_camera)
    o = marker_offsets(marker_size_m)[np.asarray(corners)]
    a, b = o - o.mean(axis=0), floor - floor.mean(axis=0)
    yaw = math.atan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    c, s = math.cos(yaw), math.sin(yaw)
    mean = o.mean(axis=0)
    return np.array([*(floor.mean(axis=0) - np.array([c * mean[0] - s * mean[1], s * mean[0] + c * mean[1]])), yaw])


def _compose(a, b):
    """Planar pose a (x, y, theta) composed with b (expressed in a)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _inverse(a):
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def chain_floor(seen: dict, reference: int) -> tuple[dict, dict]:
    """(frames, markers): planar poses (x, y, yaw) on the floor of every frame and marker that `seen` {(frame,
    marker): the marker's pose relative to the frame's} ties to the `reference` marker (the floor's frame, 0),
    through frames that see two markers; what is not tied is left out."""
    markers, frames = {reference: np.zeros(3)}, {}
    changed = True
    while changed:
        changed = False
        for (f, m), relative in sorted(seen.items()):
            if m in markers and f not in frames:
                frames[f] = _compose(markers[m], _inverse(relative))
                changed = True
            elif f in frames and m not in markers:
                markers[m] = _compose(frames[f], relative)
                changed = True
    return frames, markers


class PoseEquations:
    """drive_start's problem for solver.identify.solve: the frames' planar poses seen from the markers (`seen`,
    (F, 3), at the frames `frames`) against the drive's from each segment's anchor at its first of them
    (drive_poses), residuals (F, 3) in POSE_SCALE_M (the heading's POSE_SCALE_M / POSE_HEADING_M rad); unknowns
    the kinematics, the anchors and the effects' parameters (`columns` of the joint fit's `names`, those `free`)."""

    def __init__(self, drive: Drive, frames, seen, names, base, free):
        self.drive, self.times_s, self.seen = drive, drive.frame_t_s[np.asarray(frames)], np.asarray(seen)
        self.anchors = anchor_times(drive, frames)
        self.column = {n: i for i, n in enumerate(names)}
        self.effects = tuple(n for ns in EFFECTS.values() for n in ns if n in self.column)
        _, _, columns = drive_poses(drive, np.asarray(base, dtype=float), self.column, self.effects,
                                    self.times_s[:1], {s: self.anchors[s] for s in self.anchors})
        self.unknowns = [j for j, i in enumerate(columns) if free[i]]  # drive_poses' columns
        self.index = columns[self.unknowns]
        self.base = np.asarray(base, dtype=float)
        self.scales = parameter_scales(names)[self.index]
        self.unit = np.array([POSE_SCALE_M, POSE_SCALE_M, POSE_SCALE_M / POSE_HEADING_M])

    def values(self, free) -> np.ndarray:
        x = self.base.copy()
        x[self.index] = free
        return x

    def dense(self, free):
        """(r (3F,), J (3F, P)) unscaled."""
        poses, J, _ = drive_poses(self.drive, self.values(free), self.column, self.effects, self.times_s, self.anchors)
        d = poses - self.seen
        d[:, 2] = np.remainder(d[:, 2] + np.pi, 2 * np.pi) - np.pi
        return (d / self.unit).reshape(-1), (J[:, :, self.unknowns] / self.unit[None, :, None]).reshape(
            -1, len(self.unknowns))

    def __call__(self, free, *, weights=None, jacobian: bool = True) -> Normal:
        r, J = self.dense(free)
        r = r.reshape(-1, 3)
        rw = r if weights is None else r * np.sqrt(weights)[:, None]
        Js = (J * self.scales).reshape(len(r), 3, -1)
        flat = Js.reshape(-1, Js.shape[2])
        return Normal(flat.T @ flat, flat.T @ rw.reshape(-1), 0.5 * float(np.sum(rw ** 2)), r,
                      np.einsum("ncp,nc->np", Js, rw))


def drive_start(drive: Drive, frames: dict, names, x0, free) -> np.ndarray:
    """x0 with the kinematics, the anchor and the drive effects' parameters fitted to the frames' poses seen from the
    markers (`frames`: start_values'; PoseEquations), instead of dead reckoning at the nominal wheels: over many
    one-wheel turns (the mission's lens views: 50 half steps) that drifted so far that markers in view projected
    behind the camera and the first Jacobian was meaningless (realistic mock, seed 3: 'cannot determine 8
    parameter combinations'). Cauchy loss (a badly chained frame); kept only where it lowers that loss."""
    ordered = sorted(frames)
    if len(ordered) < 3:
        return x0
    equations = PoseEquations(drive, ordered, [frames[f] for f in ordered], names, x0, free)
    if not len(equations.index):
        return x0

    def cost(free):
        return float(np.sum(np.log1p(equations.dense(free)[0] ** 2)))

    start = np.asarray(x0, dtype=float)[equations.index]
    try:
        solution = solve(equations, last_pass_cached(equations), start, loss="cauchy",
                         max_iterations=POSE_FIT_ITERATIONS)
    except SolveError:
        return x0
    if not np.all(np.isfinite(solution.free)) or not cost(solution.free) < cost(start):
        return x0
    return equations.values(solution.free)


def start_values(drive: Drive, obs: Sightings, K, marker_size_m, T_base_camera, reference):
    """(frame poses {frame: (x, y, theta)}, marker poses {id: (x, y, yaw)}, gain) from the detections alone: each
    marker's pose in the body frame from its corners' floor points under the nominal camera pose, chained from the
    reference marker through the frames that see two; gain from the distances driven between seen frames."""
    seen = {}  # (frame, marker) -> marker pose in the body frame
    for f, m in {(int(f), int(m)) for f, m in zip(obs.frame, obs.marker)}:
        rows = np.flatnonzero((obs.frame == f) & (obs.marker == m))
        seen[(f, m)] = marker_on_floor(obs.uv_px[rows], obs.corner[rows], K, T_base_camera, marker_size_m)
    frames, markers = chain_floor(seen, int(reference))
    ordered = np.array(sorted(frames))
    segments = drive.segment_of(drive.frame_t_s[ordered])
    driven = seen_moved = 0.0
    for s in np.unique(segments):  # within each segment: a break moves the robot by hand
        here = ordered[segments == s]
        nominal, _ = trajectory(drive.segment(int(s)), 1.0, 0.0, drive.baseline_m, np.zeros(3),
                                drive.frame_t_s[here[0]], drive.frame_t_s[here])
        # over chords of at least START_GAIN_CHORD_M on the nominal path: summed frame to frame, the seen positions'
        # noise outgrew the distance driven at a camera's 15-30 fps (an independent log at 15 fps: gain started at
        # 0.46 for 0.93, and the fit ended at a baseline of -2.9 m)
        picked = [0]
        for i in range(1, len(here)):
            if np.linalg.norm(nominal[i, :2] - nominal[picked[-1], :2]) >= START_GAIN_CHORD_M:
                picked.append(i)
        driven += np.sum(np.linalg.norm(np.diff(nominal[picked, :2], axis=0), axis=1))
        seen_moved += np.sum(np.linalg.norm(np.diff(np.array([frames[here[i]][:2] for i in picked]), axis=0),
                                            axis=1))
    gain = driven / seen_moved if seen_moved > 1e-3 and driven > 1e-3 else 1.0
    return frames, markers, gain


# ------------------------------------------------------------------------------------------------ the fit

@dataclass
class DriveFit:
    names: list
    x: np.ndarray  # full vector (names)
    std: np.ndarray  # cluster-robust (clusters: sighting_runs), 0 for fixed
    std_iid: np.ndarray
    free: np.ndarray
    reference_marker: int
    residuals_px: np.ndarray  # (N, 2) of the corners kept, px (not divided by their noise)
    sightings: Sightings  # the corners kept
    outliers: Sightings  # corners set aside
    rms_px: float
    success: bool
    message: str
    iterations: int
    condition_number: float
    weak_directions: list
    anchor_t_s: float
    warnings: list = field(default_factory=list)
    covariance: np.ndarray | None = field(default=None, repr=False)  # cluster-robust, names' order (0: fixed)
    pwm_driver: bool = False  # fitted through Duckietown's wheel driver (Drive.pwm_driver)
    anchors: dict = field(default_factory=dict)  # {segment: its anchor's time} of the segments fitted
    # {nuisance (STD_PARTS): the std it adds to each parameter (names' order)}, carried into covariance and std
    considered: dict = field(default_factory=dict)

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def stdev(self, name: str) -> float:
        return float(self.std[self.names.index(name)])

    @property
    def T_base_camera(self) -> np.ndarray:
        return camera_transform(self.x[[self.names.index(n) for n in CAMERA]])

    def std_parts(self) -> dict:
        """{STATISTICAL: the cluster-robust std, then each considered nuisance's} (names' order): std is their root
        sum of squares."""
        considered = sum((part ** 2 for part in self.considered.values()), np.zeros(len(self.x)))
        return {STATISTICAL: np.sqrt(np.clip(self.std ** 2 - considered, 0.0, None)), **self.considered}

    def parameters_dict(self) -> dict:
        return {n: {"value": float(v), "std": float(s)} for n, v, s in zip(self.names, self.x, self.std)}


def _segments_kept(drive: Drive, sightings: Sightings, rows) -> tuple[np.ndarray, list]:
    """(rows without those of segments seen in fewer than MIN_SEGMENT_FRAMES frames, a warning for each left out).
    SolveError when none is left."""
    rows = np.asarray(rows, dtype=bool).copy()
    segment = drive.segment_of(drive.frame_t_s[sightings.frame])
    warnings = []
    for s in np.unique(segment[rows]):
        mine = rows & (segment == s)
        seen = len(np.unique(sightings.frame[mine]))
        if seen < MIN_SEGMENT_FRAMES:
            rows &= ~mine
            part = "before the first break" if s == 0 else f"after break {int(s)}"
            warnings.append(f"segment {int(s)} of the drive ({part}) left out: markers seen in {seen} "
                            f"frame{'s' * (seen != 1)}, fewer than {MIN_SEGMENT_FRAMES} (its start pose and its "
                            "motion cannot both be told)")
    if not rows.any():
        raise SolveError(f"no segment of the drive has markers seen in {MIN_SEGMENT_FRAMES} frames or more: the drive "
                         "cannot be fitted")
    return rows, warnings


def _reference_marker(obs: Sightings) -> int:
    pairs = np.unique(np.column_stack([obs.frame, obs.marker]), axis=0)
    ids, counts = np.unique(pairs[:, 1], return_counts=True)
    return int(ids[np.argmax(counts)])  # argmax takes the first of the ties: the smallest id


def effect_parameters(effects) -> tuple:
    """The parameters of the named effects (EFFECTS; PWM_DRIVER has none), in EFFECTS' order; ValueError naming an
    unknown effect."""
    for e in effects:
        if e not in ALL_EFFECTS:
            raise ValueError(f"unknown effect {e!r} (expected one of {', '.join(ALL_EFFECTS)})")
    return tuple(n for e, names in EFFECTS.items() if e in effects for n in names)


def fit_drive(drive: Drive, sightings: Sightings, K, marker_size_m: float, T_base_camera_start, *,
              fixed=(), start=None, loss: str = "linear", loss_scale_px: float = 1.0, robust: bool = False,
              effects=()) -> DriveFit:
    """The joint fit (module docstring) of the rectified corners `sightings` seen through camera matrix K, from the
    nominal camera pose `T_base_camera_start`. `effects`: wheel effects added to the model (EFFECTS), each from 0
    (the base model), and PWM_DRIVER: the duties through Duckietown's driver (as Drive.pwm_driver). `fixed`: names kept at their start values. `start`: {name: value} start values instead of
    the detections' (e.g. a known calibration's gain and trim). `robust`: set aside the corners no model explains
    (solver.identify.trimmed: OUTLIER_SCALES robust scales, the worst of a frame each round, those the final fit
    explains taken back). Off by default: on rendered logs it set aside 11-18 % of the corners (before the
    re-admission), all of small markers (their errors are heavy-tailed, not mis-detections), and the stds left were
    optimistic (z up to 4 where all stay below 2.1 without).
    SolveError when the data cannot determine something (the core's one policy, 1e-6)."""
    if len(sightings.frame) == 0:
        raise SolveError("no marker was seen in any frame: the drive cannot be fitted")
    if PWM_DRIVER in effects:
        drive = replace(drive, pwm_driver=True)
    lags = tuple(e for e in effects if e in LAG_EFFECTS)
    if lags and not any(n in (start or {}) for e in lags for n in EFFECTS[e]):
        # the lags from the fit without them: from the detections' start values the first steps took wheel_lag_s
        # below 0, where a lag has no gradient, and stayed (realistic mock, seed 4: 4.2 px RMS, lag -0.23 s)
        base = fit_drive(drive, sightings, K, marker_size_m, T_base_camera_start, fixed=fixed, start=start,
                         loss=loss, loss_scale_px=loss_scale_px, robust=robust,
                         effects=tuple(e for e in effects if e not in LAG_EFFECTS))
        start = {**dict(zip(base.names, base.x)), **(start or {})}
    reference = _reference_marker(sightings)
    K = np.asarray(K, dtype=float)
    frames, markers, gain0 = start_values(drive, sightings, K, marker_size_m, np.asarray(T_base_camera_start),
                                          reference)
    # a marker seen only in frames that see no marker tied to the reference has no start value (start_values chains
    # them through shared frames): its corners are set aside (with the outliers), as are such frames'
    connected = np.isin(sightings.frame, list(frames)) & np.isin(sightings.marker, list(markers))
    connected, left_out = _segments_kept(drive, sightings, connected)
    seen_frames = set(sightings.frame[connected].tolist())
    frames = {f: pose for f, pose in frames.items() if f in seen_frames}
    ids = sorted({int(m) for m in sightings.marker[connected]} - {reference})
    anchors = anchor_times(drive, sorted(frames))
    added = effect_parameters(effects)
    names = list(KINEMATIC + CAMERA) + [n for s in anchors for n in anchor_names(s)] + [BIAS] + list(added) + [
        f"marker{m}.{a}" for m in ids for a in ("x_m", "y_m", "yaw_rad")]
    firsts = [min(f for f in frames if drive.segment_of(drive.frame_t_s[f]) == s) for s in anchors]
    x0 = np.concatenate([[gain0, 0.0, drive.baseline_m], pose_parameters(T_base_camera_start)]
                        + [frames[f] for f in firsts] + [[0.0], [EFFECT_START.get(n, 0.0) for n in added]]
                        + [markers[m] for m in ids])
    if not start:  # a start given (the fit without the lags, a known calibration) is closer than the poses'
        x0 = drive_start(drive, frames, names, x0, np.array([n not in fixed for n in names]))
    for name in fixed:
        if name not in names:
            raise ValueError(f"unknown parameter {name!r} to fix")
    for name, value in (start or {}).items():
        if name not in names:
            raise ValueError(f"unknown parameter {name!r} to start from")
        x0[names.index(name)] = value
    free = np.array([n not in fixed for n in names])
    all_obs, connected_rows = sightings, np.flatnonzero(connected)

    def fit_rows(keep, x):
        """(x, solution, equations, sightings) of the connected rows `keep`, from x."""
        obs = all_obs.subset(connected_rows[keep])
        equations = DriveEquations(drive, obs, K, marker_size_m, reference, names, x, free)
        if 2 * len(obs.frame) <= len(equations.index):
            raise SolveError(f"{len(equations.index)} parameters but only {2 * len(obs.frame)} corner coordinates")
        check_identifiable(equations(x[equations.index]).A, [names[i] for i in equations.index])
        solution = solve(equations, last_pass_cached(equations), x[equations.index], loss=loss,
                         loss_scale=loss_scale_px, max_iterations=MAX_ITERATIONS)
        return equations.values(solution.free), solution, equations, obs

    keep = np.ones(len(connected_rows), dtype=bool)
    fitted = fit_rows(keep, x0)
    if robust:
        every = all_obs.subset(connected_rows)

        def judge(fitted, keep):
            x, _, equations, _ = fitted
            judged = DriveEquations(drive, every, K, marker_size_m, reference, names, x, free)
            judged.anchors = equations.anchors  # the fit's anchor frames, should they have lost their corners
            r = judged(x[judged.index], jacobian=False).residuals
            scale = MAD_TO_SIGMA * float(np.median(np.abs(r[keep])))
            return np.linalg.norm(r, axis=1) / max(scale, 1e-12), OUTLIER_SCALES

        fitted, keep, _ = trimmed(fitted, lambda keep, fitted: fit_rows(keep, fitted[0]), judge, every.frame, keep)
    x, solution, equations, obs = fitted
    kept = connected_rows[keep]
    clusters = sighting_runs(obs.frame, obs.marker, drive.segment_of(drive.frame_t_s[obs.frame]))
    spread = solution.spread(clusters, [names[i] for i in equations.index])
    std, std_iid = np.zeros(len(x)), np.zeros(len(x))
    covariance = np.zeros((len(x), len(x)))
    covariance[np.ix_(free, free)] = spread.covariance
    std[free] = np.sqrt(np.clip(np.diag(spread.covariance), 0.0, None))
    std_iid[free] = np.sqrt(np.clip(np.diag(spread.covariance_iid), 0.0, None))
    residuals = solution.final.residuals * obs.sigma_px[:, None]
    outliers = all_obs.subset(np.setdiff1d(np.arange(len(all_obs.frame)), kept))
    return DriveFit(names, x, std, std_iid, free, reference, residuals, obs, outliers,
                    float(np.sqrt(np.mean(residuals ** 2))), solution.success, solution.message, solution.n_jac,
                    spread.condition_number, spread.weak_directions, equations.anchor_t_s, left_out + spread.warnings(),
                    covariance, drive.pwm_driver, dict(equations.anchors))


def duty_offset(fit: DriveFit) -> tuple[float, np.ndarray]:
    """(c, d c / d x): the duty a wheel loses before it turns, on average over the duties near any one: the fitted
    dead_zone (0 without it) plus, fitted with Duckietown's driver (DriveFit.pwm_driver), half a PWM step (its floor
    drops 0-1 step, 0.5 on average over speeds)."""
    grad = np.zeros(len(fit.names))
    c = 0.5 / (PWM_MAX - PWM_MIN) if fit.pwm_driver else 0.0
    if "dead_zone" in fit.names:
        c += fit.value("dead_zone")
        grad[fit.names.index("dead_zone")] = 1.0
    return c, grad


def secant_gain(drive: Drive, fit: DriveFit, speed_mps: float) -> tuple[float, float]:
    """(gain, std) with which Duckietown's dead-zone-free inverse kinematics drives the fitted robot at `speed_mps`
    straight: a wheel turning at w needs the duty c + (gain -+ trim) w / k (c: duty_offset), i.e. the secant
    gain + c k r / v at w = v / r; the trim is the slope's (c is the same on both wheels). Its std from the fit's
    covariance."""
    c, grad = duty_offset(fit)
    scale = drive.k * drive.radius_m / speed_mps
    grad = grad * scale
    grad[fit.names.index("gain")] += 1.0
    variance = float(grad @ fit.covariance @ grad) if fit.covariance is not None else float("nan")
    return fit.value("gain") + c * scale, math.sqrt(max(variance, 0.0))
