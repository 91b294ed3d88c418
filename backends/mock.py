"""A simulated NAO with hidden, known errors: the `Backend` that naocal is tested and learned on.

The robot lies on its back (body.nao_body); its bottom camera is rendered (backends.mock_render); time is
simulated (`now()` and `sleep()` advance a counter, nothing waits on the wall clock). docs/MOCK.md describes the
model; in short:

Hidden truth, drawn from the seed (each part from its own random stream, so adding an effect does not change the
others): leg encoder offsets alpha (0.2-2 deg, random sign; RHipYawPitch = LHipYawPitch, one motor), the camera's
rotation offsets (pitch -3..-8.5 deg, roll and yaw 1-3 deg of random sign, applied as in the model:
T_torso_cam = T_torso_cam(q) @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw)), the sandals' mounting errors (rot_z
0.2-1.2 deg, trans_x/trans_y 0.5-3 mm; p_sole = Rot_z(rot_z) @ (p + [trans_x, trans_y, 0])).

Joints: each motor drives its own (biased) sensor to the command, so a still joint commanded to c reads c
(quantised to `encoder_resolution_deg`) and truly stands at c + alpha (+ the effects below). A command moves its
joints together along a straight line in joint space, starting `command_delay_s` after it is given, at
`speed_fraction` of the slowest joint's maximum speed (the URDF's velocity) so that no joint exceeds its own.
Sensors are sampled every `sensor_period_s` (100 Hz) and a reading is the sample `sensor_lag_cycles` periods old,
stamped with its own sampling time. The single HipYawPitch motor follows LHipYawPitch when a command names it (as
NAOqi does), else RHipYawPitch; both joints read its sensor.

Camera: frames are exposed every 1/30 s (the exposure time is the middle of the frame) and arrive
`camera_delay_s` later; `capture()` returns the newest frame that has arrived, rendered on demand (frames nobody
asks for are never rendered) and showing the robot at its exposure time, with the boards motion-blurred over
`exposure_s` if they move.

Injectable effects (off by default): every effect of solver/effects/ with a `mock_size_unit`. Each effect's module
draws what a robot with it has (`Effect.mock_perturbation`, from the effect's own random stream, a
`solver.effect.MockPerturbation`) and this mock applies it: encoder offsets, compliance (q_true = servo + alpha +
c_j * tau_j(q_true), tau_j the gravity torque from PyBullet's inverse dynamics of the simulated masses and the
sandal, fixed-point iteration), half play (+ b_j * dir_j, dir_j the sign of the last change of that joint's
command), longer links (the PyBullet body and the kinematics), the cameras' true intrinsics and distortion, their
mounts' translation, late image stamps. docs/MOCK.md lists the effects and their sizes.

Realism (`realism="ideal"`, this class's default, is all of the above; `realism="realistic"`, the default of
naocal's commands, a NAO V6 as teams meet it, backends.mock_realism, docs/MOCK.md): readings in 12-bit encoder steps
every 12 ms (LoLA); a servo that follows the interpolated command as a damped second-order system and rests
somewhere in its commanded step, pulled by the gravity load (backends.mock_servo); a rolling-shutter camera (rows
over 45 ms, boards rendered per band of rows when they move) stamped as B-Human relates V4L2 buffer stamps, YUYV
4:2:2 capture, noise, slight defocus, prior fx = fy = 618 px with true intrinsics a little off; offsets as large as
real robots carry; glare spots and a corner fault model (backends.mock_faults, applied to the agent's detector
through `faulty`).

Safety: `command` refuses with SafetyError a non-finite or unknown target, a speed outside (0, 1], a target outside
the joint limits (solver.limits, HeadPitch against HeadYaw included) and a motion whose end or any of the points
sampled along its way brings two parts of the true body, or a part and the ground, closer than `safety_margin_m`.
Every command received is kept in `command_log`, refused or not.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from naocal.backends.base import Backend, JointTables, CameraImage, CameraIntrinsics, JointReading, checked_reading
from naocal.solver.errors import SafetyError
from naocal.backends.mock_realism import IDEAL, Realism, as_realism
from naocal.backends.mock_render import RowBand, SceneRenderer, add_glare, board_outline_board_m, form_image
from naocal.backends.mock_servo import SecondOrder, rest_offset, servo_positions
from naocal.body.nao_body import T_WORLD_TORSO, BodyGeometry, BoardMount, CollisionChecker, NaoBody, T_sole_board
from naocal.solver.effect import MockPerturbation, Setup, signed_uniform
from naocal.solver.effects import EFFECTS as MODEL_EFFECTS
from naocal.solver.errors import NaocalError
from naocal.solver.joints import HEAD_JOINTS, JOINT_INDEX, JOINTS, LEG_JOINTS, LEGS, leg_joints
from naocal.solver.kinematics import chain_frames, leg_fk
from naocal.solver.limits import check_speed_fraction, check_targets, head_pitch_problem, joint_limits, max_speeds
from naocal.solver.nao_model import BOARD_CENTER_X_M, N_VERTICES, board_vertices_sole, head_chain
from naocal.solver.transforms import invert_transform, rot_x, rot_y, rot_z

# The effects the mock simulates (solver/effects/ modules with a mock injection) and the unit of their size.
EFFECT_UNITS = {name: e.mock_size_unit for name, e in MODEL_EFFECTS.items() if e.mock_size_unit is not None}
EFFECTS = tuple(EFFECT_UNITS)
from naocal.solver.offsets import TRUTH_EFFECTS_SCHEMA, TRUTH_SCHEMAS  # noqa: E402 (their reader's home)

TRUTH_SCHEMA = TRUTH_SCHEMAS[0]  # /1 had one camera_rotation_rad {roll, pitch, yaw}: the bottom camera's
CAMERAS = ("bottom", "top")
MOCK_SETUP = Setup.everything()  # what the effects' injections are drawn for: the NAO, both cameras, its targets
FRAME_PERIOD_S = 1.0 / 30.0
FRAME_PHASE_S = 0.004  # exposure times are FRAME_PHASE_S + k * FRAME_PERIOD_S
START_TIME_S = 10.0  # the simulated clock at start (the robot has been up for a while)
SHARED_MOTOR = ("LHipYawPitch", "RHipYawPitch")  # one motor; its track is kept under the L name

# Lying on the back, legs a little raised and apart so that the sandals clear each other, head looking down
# towards the feet.
DEFAULT_POSTURE = {
    "HeadYaw": 0.0, "HeadPitch": 0.3,
    "LHipYawPitch": 0.0, "LHipRoll": 0.3, "LHipPitch": -0.5, "LKneePitch": 0.5, "LAnklePitch": -0.3, "LAnkleRoll": 0.0,
    "RHipYawPitch": 0.0, "RHipRoll": -0.3, "RHipPitch": -0.5, "RKneePitch": 0.5, "RAnklePitch": -0.3, "RAnkleRoll": 0.0,
}

# A robot with real-size offsets (HipYawPitch up to 12 deg turns both feet) starts with its legs spread wider, so
# that its sandals clear each other whatever its offsets.
SPREAD_POSTURE = {**DEFAULT_POSTURE, "LHipRoll": 0.6, "RHipRoll": -0.6, "LAnkleRoll": 0.2, "RAnkleRoll": -0.2}


def parse_effect_sizes(items) -> dict[str, float]:
    """{name: size} from strings 'NAME=SIZE' (the `--effect` arguments of the mock); NaocalError naming the bad one.
    (solver.effects.parse_effect_names parses the other format: the names of model terms, 'E1,E2'.)"""
    effects = {}
    for item in items or ():
        name, sep, size_text = str(item).partition("=")
        name = name.strip()
        if not sep:
            raise NaocalError(f"effect {item!r}: expected NAME=SIZE, e.g. elasticity=0.02")
        try:
            size = float(size_text)
        except ValueError:
            raise NaocalError(f"effect {item!r}: size {size_text!r} is not a number") from None
        effects[name] = size
    return check_effects(effects)


def check_effects(effects) -> dict[str, float]:
    """A validated copy of {name: size}: known names, finite sizes within the effect's plausible range
    (mock_size_range)."""
    checked = {}
    for name, size in dict(effects or {}).items():
        if name not in EFFECT_UNITS:
            raise NaocalError(f"unknown effect {name!r}: expected one of {', '.join(EFFECTS)}")
        size = float(size)
        if not math.isfinite(size):
            raise NaocalError(f"effect {name!r}: size must be finite, got {size}")
        low, high = mock_size_range(name)
        if not low <= size <= high:
            unit = EFFECT_UNITS[name]
            bound = f"at least {low:g} {unit}" if size < low else f"at most {high:g} {unit}"
            raise NaocalError(f"effect {name!r}: size must be {bound}, got {size:g} (its plausible range: "
                              f"{low:g}..{high:g} {unit}; beyond it no offsets file holds the result)")
        checked[name] = size
    return checked


def mock_size_range(name: str) -> tuple[float, float]:
    """The sizes `--effect NAME=SIZE` takes: from the effect's mock_size_min (or minus its offsets file's limit) up
    to that limit: an effect larger than any calibration file holds is no robot's (1e308 ran 33 s, then crashed)."""
    effect = MODEL_EFFECTS[name]
    low = effect.mock_size_min if math.isfinite(effect.mock_size_min) else -effect.offsets_limit
    return low, effect.offsets_limit


@dataclass(frozen=True)
class MockTruth:
    """Everything hidden in a mock. Angles in rad, lengths in m; per-joint dicts use solver.joints names."""

    seed: int
    alpha_rad: dict  # 14 joints: encoder offsets (head joints: the head_offsets effect, else 0)
    camera_rotation_rad: dict  # roll, pitch, yaw of the bottom camera
    board_mount: dict  # leg -> BoardMount
    effects: dict  # name -> size
    compliance_rad_per_nm: dict  # leg joints (0 without elasticity)
    backlash_rad: dict  # leg joints (0 without backlash)
    thigh_delta_m: dict  # leg -> m
    tibia_delta_m: dict  # leg -> m
    camera: CameraIntrinsics  # the true intrinsics and distortion (radial k1 only)
    time_lag_s: float
    top_camera_rotation_rad: dict = field(default_factory=lambda: {"roll": 0.0, "pitch": 0.0, "yaw": 0.0})
    camera_translation_m: dict = field(default_factory=dict)  # camera -> (x, y, z) mount shift in the head frame, m
    effect_records: dict = field(default_factory=dict)  # effect -> what it drew (truth_effects.json)

    def camera_rotations(self) -> dict:
        """{camera: {roll, pitch, yaw}} of both cameras, rad."""
        return {"bottom": dict(self.camera_rotation_rad), "top": dict(self.top_camera_rotation_rad)}

    def geometry(self) -> BodyGeometry:
        return BodyGeometry(thigh_delta_m=dict(self.thigh_delta_m), tibia_delta_m=dict(self.tibia_delta_m),
                            board_mount=dict(self.board_mount))

    def R_cam_offset(self, camera: str = "bottom") -> np.ndarray:
        """Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw), the camera's rotation error (Eq. 3)."""
        r = self.camera_rotations()[camera]
        return rot_y(r["pitch"]) @ rot_x(r["roll"]) @ rot_z(r["yaw"])


def draw_truth(seed: int, effects=None, nominal: CameraIntrinsics | None = None,
               realism: Realism | str = IDEAL) -> MockTruth:
    """The hidden truth of a mock with this seed and these effects (see the module docstring); a realistic mock
    (Realism.large_offsets) draws its offsets and true intrinsics from streams of their own."""
    effects = check_effects(effects)
    realism = as_realism(realism)
    nominal = nominal or default_intrinsics(realism)
    rng = np.random.default_rng([int(seed), 0])  # the base truth's stream
    alpha = {j: 0.0 for j in JOINTS}
    for joint in LEG_JOINTS:
        alpha[joint] = float(np.deg2rad(signed_uniform(rng, 0.2, 2.0)))
    alpha["RHipYawPitch"] = alpha["LHipYawPitch"]
    camera_rotation = {"roll": float(np.deg2rad(signed_uniform(rng, 1.0, 3.0))),
                       "pitch": float(np.deg2rad(-rng.uniform(3.0, 8.5))),
                       "yaw": float(np.deg2rad(signed_uniform(rng, 1.0, 3.0)))}
    mounts = {leg: BoardMount(rot_z_rad=float(np.deg2rad(signed_uniform(rng, 0.2, 1.2))),
                              trans_x_m=float(signed_uniform(rng, 0.0005, 0.003)),
                              trans_y_m=float(signed_uniform(rng, 0.0005, 0.003))) for leg in LEGS}
    if realism.large_offsets:
        alpha, camera_rotation = _large_offsets(np.random.default_rng([int(seed), 104729]), realism, alpha)
    # The top camera's rotation from a stream of its own (the bottom camera's truth stays what it was): the same
    # ranges as the bottom camera's (B-Human's upper corrections are of the same size; docs/MOCK.md).
    top_rng = np.random.default_rng([int(seed), 27183])
    if realism.large_offsets:
        top_rotation = _large_offsets(top_rng, realism, alpha)[1]
    else:
        top_rotation = {"roll": float(np.deg2rad(signed_uniform(top_rng, 1.0, 3.0))),
                        "pitch": float(np.deg2rad(-top_rng.uniform(3.0, 8.5))),
                        "yaw": float(np.deg2rad(signed_uniform(top_rng, 1.0, 3.0)))}

    # Each effect draws what it perturbs from its own stream (solver/effects/<name>.py, mock_perturbation).
    perturbations = {name: MODEL_EFFECTS[name].mock_perturbation(
        np.random.default_rng([int(seed), MODEL_EFFECTS[name].mock_stream_id()]), size, MOCK_SETUP)
        for name, size in effects.items()}
    total = MockPerturbation()
    for p in perturbations.values():
        _add_perturbation(total, p)
    for joint, a in total.alpha_rad.items():
        alpha[joint] += a
    lengths = {"thigh": {leg: 0.0 for leg in LEGS}, "tibia": {leg: 0.0 for leg in LEGS}}
    for label, delta in total.link_deltas_m.items():  # the NAO's labels: '<leg>.<thigh|tibia>'
        leg, _, kind = label.partition(".")
        lengths[kind][leg] += delta
    d = {k: total.intrinsics_px.get(k, 0.0) for k in ("fx", "fy", "cx", "cy")}
    # A real camera's intrinsics differ a little from the prior (independent of the intrinsics effect's stream).
    lens = np.random.default_rng([int(seed), 130363]).uniform(-1.0, 1.0, 4)
    lens *= [realism.focal_error_px] * 2 + [realism.principal_error_px] * 2
    unknown = set(total.distortion) - {"k1"}
    if unknown:
        raise NaocalError(f"the mock's cameras have radial distortion k1 only, not {', '.join(sorted(unknown))}")
    off_legs = (set(total.compliance_rad_per_nm) | set(total.half_play_rad)) - set(LEG_JOINTS)
    if off_legs:
        raise NaocalError(f"the mock simulates compliance and play on the leg joints only, not {sorted(off_legs)}")
    camera = CameraIntrinsics(
        width_px=nominal.width_px, height_px=nominal.height_px,
        fx_px=float(nominal.fx_px + d["fx"] + lens[0]), fy_px=float(nominal.fy_px + d["fy"] + lens[1]),
        cx_px=float(nominal.cx_px + d["cx"] + lens[2]), cy_px=float(nominal.cy_px + d["cy"] + lens[3]),
        distortion=(float(total.distortion.get("k1", 0.0)), 0.0, 0.0, 0.0, 0.0))
    return MockTruth(
        seed=int(seed), alpha_rad=alpha, camera_rotation_rad=camera_rotation, board_mount=mounts,
        effects=dict(effects),
        compliance_rad_per_nm={j: float(total.compliance_rad_per_nm.get(j, 0.0)) for j in LEG_JOINTS},
        backlash_rad={j: float(total.half_play_rad.get(j, 0.0)) for j in LEG_JOINTS},
        thigh_delta_m=lengths["thigh"], tibia_delta_m=lengths["tibia"],
        camera=camera, time_lag_s=float(total.image_stamp_late_s), top_camera_rotation_rad=top_rotation,
        camera_translation_m={cam: tuple(float(v) for v in total.camera_translation_m.get(cam, (0.0, 0.0, 0.0)))
                              for cam in CAMERAS},
        effect_records={name: p.record for name, p in perturbations.items()})


def _add_perturbation(total: MockPerturbation, p: MockPerturbation) -> None:
    """Add one effect's perturbation to the sum of those before it (per-key sums; k1 and the like add too)."""
    for name in ("alpha_rad", "compliance_rad_per_nm", "half_play_rad", "link_deltas_m", "intrinsics_px",
                 "distortion"):
        into = getattr(total, name)
        for key, value in getattr(p, name).items():
            into[key] = into.get(key, 0.0) + float(value)
    for cam, shift in p.camera_translation_m.items():
        total.camera_translation_m[cam] = np.asarray(total.camera_translation_m.get(cam, np.zeros(3))) + shift
    total.image_stamp_late_s += float(p.image_stamp_late_s)


def _large_offsets(rng, realism: Realism, alpha: dict) -> tuple[dict, dict]:
    """Offsets as large as real robots carry (docs/MOCK.md): HipYawPitch up to hip_yaw_pitch_max_deg, the other
    leg joints up to leg_offset_max_deg, camera pitch in camera_pitch_range_deg or now and then an outlier,
    roll and yaw 1-3 deg. Head joints keep theirs (the head_offsets effect)."""
    alpha = dict(alpha)
    for joint in LEG_JOINTS:
        alpha[joint] = float(np.deg2rad(signed_uniform(rng, 0.2, realism.leg_offset_max_deg)))
    alpha["LHipYawPitch"] = alpha["RHipYawPitch"] = float(np.deg2rad(signed_uniform(rng, 0.5, realism.hip_yaw_pitch_max_deg)))
    outlier = rng.uniform() < realism.camera_pitch_outlier_rate
    pitch_deg = signed_uniform(rng, *realism.camera_pitch_outlier_deg) if outlier else rng.uniform(
        *realism.camera_pitch_range_deg)
    camera_rotation = {"roll": float(np.deg2rad(signed_uniform(rng, 1.0, 3.0))), "pitch": float(np.deg2rad(pitch_deg)),
                       "yaw": float(np.deg2rad(signed_uniform(rng, 1.0, 3.0)))}
    return alpha, camera_rotation


def default_intrinsics(realism: Realism | str = IDEAL) -> CameraIntrinsics:
    """The bottom camera's prior intrinsics the mock reports: the robot description's (solver/data/nao.json: fx =
    fy = 600 px, centre (320, 240)) with the realism's prior focal length if it has one (realistic: a real NAO
    head's 618 px)."""
    from naocal.solver.robot import default_intrinsics as prior

    d = prior("bottom")
    f = as_realism(realism).prior_focal_px
    fx, fy = (d["fx_px"], d["fy_px"]) if f is None else (f, f)
    return CameraIntrinsics(width_px=d["width_px"], height_px=d["height_px"], fx_px=fx, fy_px=fy,
                            cx_px=d["cx_px"], cy_px=d["cy_px"])


@dataclass(frozen=True)
class CommandRecord:
    """One command as the mock received it (robot clock), and whether it was carried out."""

    t_s: float
    targets_rad: dict
    speed_fraction: float
    accepted: bool
    reason: str = ""


@dataclass
class _Track:
    """The servo (command-space) position of one motor over time: straight segments toward targets."""

    t0: list = field(default_factory=list)  # segment start times, increasing
    q0: list = field(default_factory=list)
    target: list = field(default_factory=list)
    duration: list = field(default_factory=list)
    dir_t: list = field(default_factory=list)  # times at which the commanded direction changed
    dirs: list = field(default_factory=list)

    def at(self, t: float) -> float:
        i = bisect.bisect_right(self.t0, t) - 1
        if i < 0:
            i = 0
        if self.duration[i] <= 0.0 or t >= self.t0[i] + self.duration[i]:
            return self.target[i]
        return self.q0[i] + (self.target[i] - self.q0[i]) * max(t - self.t0[i], 0.0) / self.duration[i]

    def end_time(self) -> float:
        return self.t0[-1] + self.duration[-1]

    def slope_at(self, t: float) -> float:
        """The reference's speed at t (rad/s; right-continuous)."""
        i = max(bisect.bisect_right(self.t0, t) - 1, 0)
        if self.duration[i] <= 0.0 or t >= self.t0[i] + self.duration[i]:
            return 0.0
        return (self.target[i] - self.q0[i]) / self.duration[i]

    def slope_changes(self) -> tuple[list, list]:
        """([t_k], [ds_k]): the instants at which the reference's slope changes, and by how much."""
        n = len(self.t0)
        if getattr(self, "_changes_for", None) != n:
            times, changes, current, last_stop = [], [], 0.0, -math.inf
            for i in range(1, n):
                start = self.t0[i]
                stop = min(start + self.duration[i], self.t0[i + 1] if i + 1 < n else math.inf)
                if stop <= start:
                    continue  # replaced by a command given at the same instant
                slope = (self.target[i] - self.q0[i]) / self.duration[i] if self.duration[i] > 0.0 else 0.0
                if last_stop < start and current != 0.0:  # the previous motion ended before this one began
                    times.append(last_stop)
                    changes.append(-current)
                    current = 0.0
                if slope != current:
                    times.append(start)
                    changes.append(slope - current)
                current, last_stop = slope, stop
            if current != 0.0 and math.isfinite(last_stop):
                times.append(last_stop)
                changes.append(-current)
            self._slope_changes, self._changes_for = (times, changes), n
        return self._slope_changes

    def direction(self, t: float) -> float:
        i = bisect.bisect_right(self.dir_t, t) - 1
        return self.dirs[i] if i >= 0 else 0.0


class _LazyImage(CameraImage):
    """A CameraImage whose pixels are rendered when first read: a frame nobody looks at costs nothing (an agent
    polling `capture()` until a new enough frame arrives only reads `t_exposure_s` of the others)."""

    def __init__(self, render, t_exposure_s: float, camera: str = "bottom"):
        object.__setattr__(self, "_render", render)
        object.__setattr__(self, "_pixels", None)
        object.__setattr__(self, "t_exposure_s", t_exposure_s)
        object.__setattr__(self, "camera", camera)

    @property
    def pixels(self) -> np.ndarray:
        if self._pixels is None:
            object.__setattr__(self, "_pixels", self._render())
        return self._pixels

    def __reduce__(self):  # pickles as a plain CameraImage
        return CameraImage, (self.pixels, self.t_exposure_s, self.camera)


@dataclass
class _Frame:
    index: int
    t_true_s: float  # true exposure time (middle of the frame)
    camera: str = "bottom"
    image: CameraImage | None = None
    seg: np.ndarray | None = None  # segmentation mask, once rendered
    q_true: np.ndarray | None = None  # true angles at the exposure, once rendered
    glare: tuple | None = None  # (leg, centre px, sigma px, amplitude) of a rendered specular patch


class MockBackend(JointTables, Backend):
    """A simulated NAO (PyBullet, simulated clock) with hidden truth `truth` / `truth_dict()`.

    Parameters
    ----------
    seed : draws the hidden truth (and the image noise).
    effects : {name: size} of injected physical effects (see the module docstring for names and units).
    realism : 'ideal' (default: the robot the solver was built on), 'realistic' (a NAO V6 as teams meet it:
        backends.mock_realism, docs/MOCK.md), a `Realism`, or a dict {"preset": name, field: value}.
    encoder_resolution_deg : joint readings are quantised to this step (default: the realism's).
    image_noise_std : Gaussian noise on the images, grey levels (0-255) (default: the realism's).
    camera_delay_s : an image arrives this long after its exposure.
    exposure_s : exposure duration (motion blur of moving boards).
    sensor_period_s, sensor_lag_cycles : joint sampling period and how many samples old a reading is (default:
        the realism's: 10 ms ideal, 12 ms realistic, 3 cycles).
    command_delay_s : a command starts moving the joints this long after it is given.
    safety_margin_m : parts of the true body (and the ground) closer than this make a motion unsafe.
    supersample : anti-aliasing of the boards (sub-pixels per pixel and axis).
    nominal_intrinsics : the camera's prior intrinsics (default: `default_intrinsics(realism)`, the robot
        description's fx = fy = 600 px ideal, 618 px realistic; cx, cy = 320, 240).
    posture : starting joint angles (command space) replacing those of DEFAULT_POSTURE.
    """

    name = "mock"

    def __init__(self, seed: int = 0, effects=None, *, realism: Realism | str | dict = "ideal",
                 encoder_resolution_deg: float | None = None, image_noise_std: float | None = None,
                 camera_delay_s: float = 0.1, exposure_s: float = 0.015, sensor_period_s: float | None = None,
                 sensor_lag_cycles: int | None = None, command_delay_s: float = 0.01,
                 safety_margin_m: float = 0.003, supersample: int = 4,
                 nominal_intrinsics: CameraIntrinsics | None = None, posture: dict | None = None):
        self.seed = int(seed)
        self.realism = as_realism(realism)
        r = self.realism
        self._nominal = nominal_intrinsics or default_intrinsics(r)
        self.truth = draw_truth(self.seed, effects, self._nominal, r)
        if self.truth.time_lag_s >= camera_delay_s:
            raise NaocalError(f"time_lag {self.truth.time_lag_s} s must stay below camera_delay_s {camera_delay_s} s: "
                              "an image cannot be stamped later than it arrives")
        self.encoder_resolution_rad = (r.encoder_step_rad if encoder_resolution_deg is None
                                       else math.radians(encoder_resolution_deg))
        self.image_noise_std = float(r.luma_noise_std if image_noise_std is None else image_noise_std)
        self.camera_delay_s = float(camera_delay_s)
        self.exposure_s = float(exposure_s)
        self.sensor_period_s = float(r.sensor_period_s if sensor_period_s is None else sensor_period_s)
        lag_cycles = r.sensor_lag_cycles if sensor_lag_cycles is None else sensor_lag_cycles
        self.sensor_lag_s = int(lag_cycles) * self.sensor_period_s
        self.command_delay_s = float(command_delay_s)
        # The servo: exact (ideal) or second-order with rest offsets inside the commanded step (realistic).
        self._dynamics = (None if r.servo_time_constant_s is None
                          else SecondOrder(r.servo_time_constant_s, r.servo_damping))
        self._exact_servo = (self._dynamics is None and r.servo_rest == "command"
                             and r.servo_stiffness_nm_per_rad is None)
        self._rest_times: list[float] = []  # when each command's motion ends and its rest offsets apply
        self._rest_offsets: list[np.ndarray] = []  # (14,) sensor-space rest position minus command, rad
        self._cell_draws = np.zeros(len(JOINTS))  # 'uniform' servo_rest: where in its cell each joint rests
        self._n_commands_applied = 0
        self._rest_commanded = np.full(len(JOINTS), np.nan)  # the targets the cell draws were made for
        self._limits = {j: joint_limits()[j] for j in JOINTS}
        self._speeds = {j: max_speeds()[j] for j in JOINTS}
        self._stiffness = {j: 1.0 for j in JOINTS}
        self.command_log: list[CommandRecord] = []
        self._t = START_TIME_S
        self._frames: dict[tuple, _Frame] = {}  # (camera, k) -> frame
        self.frames_rendered = 0  # how many frames were rendered (only those whose pixels someone read)
        self._closed = False
        self.body = NaoBody(self.truth.geometry())
        self.checker = CollisionChecker(self.body, margin_m=safety_margin_m, ground_margin_m=safety_margin_m)
        self.renderer = SceneRenderer(self.body, self.truth.camera, supersample=supersample)
        self._renderers = {"bottom": self.renderer}  # the top camera's is made when first asked for
        self._supersample = int(supersample)
        self._vertices_board = board_vertices_sole() - np.array([BOARD_CENTER_X_M, 0.0, 0.0])
        self._T_sole_board = {leg: T_sole_board(self.truth.board_mount[leg]) for leg in LEGS}
        start = {**(SPREAD_POSTURE if r.large_offsets else DEFAULT_POSTURE), **(posture or {})}
        for joint in JOINTS:
            lower, upper = self._limits[joint]
            if not lower <= start[joint] <= upper:
                raise SafetyError(f"mock starting posture: {joint} = {start[joint]} rad outside its limits")
        self._tracks = {j: _Track([-math.inf], [start[j]], [start[j]], [0.0]) for j in JOINTS if j != SHARED_MOTOR[1]}
        problem = self._unsafe_reason(self._stance_now(), [])
        if problem:
            self.close()
            raise SafetyError(f"mock starting posture is unsafe: {problem}")

    # --- Backend --------------------------------------------------------------------------------------------------
    def robot_identity(self) -> dict:
        return {"id": f"mock-{self.seed}", "model": f"{self.realism.robot_model} (naocal PyBullet mock)",
                "body_id": f"mock-body-{self.seed}", "head_id": f"mock-head-{self.seed}"}

    def intrinsics(self) -> CameraIntrinsics:
        return self._nominal

    def now(self) -> float:
        return self._t

    def sleep(self, duration_s: float) -> None:
        duration_s = float(duration_s)
        if not math.isfinite(duration_s) or duration_s < 0:
            raise NaocalError(f"sleep: duration must be finite and >= 0, got {duration_s}")
        self._t += duration_s

    def set_stiffness(self, names, stiffness: float) -> None:
        """Stiffness 0 leaves a joint where it is: it ignores commands (it does not fall; a simplification)."""
        self._check_open()
        names = [names] if isinstance(names, str) else list(names)
        stiffness = float(stiffness)
        if not 0.0 <= stiffness <= 1.0:
            raise NaocalError(f"stiffness must be within 0..1, got {stiffness}")
        for name in names:
            if name not in self._stiffness:
                raise NaocalError(f"set_stiffness: unknown joint {name!r}")
            self._stiffness[name] = stiffness

    def read_joints(self) -> JointReading:
        self._check_open()
        period = self.sensor_period_s
        t_sample = math.floor((self._t - self.sensor_lag_s) / period + 1e-9) * period
        step = self.encoder_resolution_rad
        angles = {}
        for joint, servo in zip(JOINTS, self._servo_q(t_sample)):
            angles[joint] = round(servo / step) * step if math.isfinite(servo) and step > 0 else float(servo)
        return checked_reading(angles, t_sample, self._limits)  # as every driver: never serve what a robot could not read

    def command(self, targets_rad: dict, speed_fraction: float) -> None:
        self._check_open()
        record = dict(targets_rad) if isinstance(targets_rad, dict) else targets_rad
        try:
            targets, speed = self._validate(targets_rad, speed_fraction)
            start = self._t + self.command_delay_s
            plan = self._plan(targets, speed, start)
            problem = self._unsafe_reason(plan[-1][1], plan)
            if problem:
                raise SafetyError(f"refused: {problem}")
        except SafetyError as err:
            self.command_log.append(CommandRecord(self._t, record, _as_float(speed_fraction), False, str(err)))
            raise
        self.command_log.append(CommandRecord(self._t, record, speed, True))
        self._apply(targets, speed, start)
        if not self._exact_servo:
            self._add_rest_offsets(targets, start)

    def capture(self, camera: str = "bottom") -> CameraImage | None:
        """The newest frame of `camera` ('bottom' or 'top'; both run at 30 fps in phase, with the same lens)."""
        self._check_open()
        if camera not in CAMERAS:
            raise NaocalError(f"unknown camera {camera!r}: expected one of {', '.join(CAMERAS)}")
        k = math.floor((self._t - self.camera_delay_s - FRAME_PHASE_S) / FRAME_PERIOD_S + 1e-9)
        if k * FRAME_PERIOD_S + FRAME_PHASE_S < START_TIME_S - 1.0:
            return None  # nothing exposed yet since the camera started
        return self._frame(k, camera).image

    def _renderer(self, camera: str) -> SceneRenderer:
        if camera not in self._renderers:
            self._renderers[camera] = SceneRenderer(self.body, self.truth.camera, supersample=self._supersample)
        return self._renderers[camera]

    def close(self) -> None:
        if getattr(self, "_closed", True):
            return
        self._closed = True
        self._frames.clear()
        self.body.close()

    def faulty(self, detector):
        """`detector` with this mock's corner fault model (Realism.corner_fault_rate; backends.mock_faults), or
        `detector` itself when the rate is 0 (the ideal mock)."""
        from naocal.backends.mock_faults import FaultyDetector

        rate = self.realism.corner_fault_rate
        return FaultyDetector(detector, rate, self.seed) if rate > 0 else detector

    # --- Truth, for tests -------------------------------------------------------------------------------------------
    def truth_dict(self) -> dict:
        """The hidden truth in the `naocal.truth/1` format."""
        t = self.truth
        return {
            "schema": TRUTH_SCHEMA,
            "alpha_rad": {j: float(t.alpha_rad[j]) for j in JOINTS},
            "camera_rotation_rad": {cam: {k: float(r[k]) for k in ("roll", "pitch", "yaw")}
                                    for cam, r in t.camera_rotations().items()},
            "board_mount": {leg: {"rot_z_rad": float(m.rot_z_rad), "trans_x_m": float(m.trans_x_m),
                                  "trans_y_m": float(m.trans_y_m)} for leg, m in t.board_mount.items()},
            "effects": {name: float(size) for name, size in t.effects.items()},
        }

    def effect_values_dict(self) -> dict:
        """What each injected effect drew from the seed, per joint or per leg (only the effects present), in the
        `naocal.truth_effects/1` format (truth_effects.json beside truth.json, whose format stays as specified)."""
        t = self.truth
        out = {"schema": TRUTH_EFFECTS_SCHEMA, "effects": {name: t.effect_records[name] for name in t.effects}}
        if "intrinsics" in t.effects:  # beside what the effect added, the true intrinsics themselves
            out["effects"]["intrinsics"] = {**t.effect_records["intrinsics"], **{
                k: float(getattr(t.camera, k)) for k in ("fx_px", "fy_px", "cx_px", "cy_px")}}
        if not self.realism.is_ideal:  # what a realistic robot has besides the effects
            out["realism"] = {"settings": self.realism.to_dict(),
                              "intrinsics": {k: float(getattr(t.camera, k)) for k in ("fx_px", "fy_px", "cx_px",
                                                                                     "cy_px")}}
        return out

    def true_angles(self, t_s: float | None = None) -> dict[str, float]:
        """The true joint angles (rad) at robot time t_s (default now)."""
        q = self._true_q(self._t if t_s is None else float(t_s))
        return {j: float(q[i]) for i, j in enumerate(JOINTS)}

    def servo_angles(self, t_s: float | None = None) -> dict[str, float]:
        """The motors' own (unquantised) sensor positions at robot time t_s (default now): the interpolated
        command itself on the ideal mock; its second-order response plus the rest offset on a realistic one."""
        t = self._t if t_s is None else float(t_s)
        return {j: float(a) for j, a in zip(JOINTS, self._servo_q(t))}

    def reference_angles(self, t_s: float | None = None) -> dict[str, float]:
        """The interpolated commands at robot time t_s (default now): straight lines from command to command."""
        t = self._t if t_s is None else float(t_s)
        return {j: self._track(j).at(t) for j in JOINTS}

    def exposure_time(self, image: CameraImage) -> float:
        """The true exposure time (of the middle row) of an image this mock returned: its stamp minus the time_lag
        effect and, on a realistic mock, minus the V4L2 stamp's offset (Realism.stamp_offset_s)."""
        return image.t_exposure_s - self.truth.time_lag_s - self.realism.stamp_offset_s()

    def row_time(self, t_mid_s: float, v_px) -> np.ndarray:
        """When row v of a frame whose middle row was exposed at t_mid_s was exposed (rolling shutter: rows one
        after another over Realism.readout_s; all at t_mid_s with a global shutter)."""
        h = self.truth.camera.height_px
        return t_mid_s + (np.asarray(v_px, dtype=float) - (h - 1) / 2.0) * (self.realism.readout_s / h)

    def vertex_pixels_at(self, t_s: float) -> dict:
        """{leg: (24, 2)} where the true camera sees both boards' vertices with the robot as it truly is at robot
        time t_s (whether or not they are visible)."""
        return {leg: uv for leg, (uv, _) in self._vertex_pixels(self._true_q(float(t_s))).items()}

    def true_vertex_pixels(self, image: CameraImage, *, clearance_px: float = 4.0) -> dict:
        """Exact pixel positions of both boards' vertices in an image this mock returned.

        Returns {leg: (pixels (24, 2), visible (24,) bool)}: the true kinematics at the image's true exposure
        time (the middle of the exposure), the true camera (rotation, intrinsics, distortion). A vertex is visible
        when it lies inside the image, its board faces the camera and no other part of the robot covers any pixel
        within `clearance_px` of it in the image's segmentation mask.
        """
        frame = self._frame(self._frame_index(image), image.camera)
        if frame.seg is None:
            frame.image.pixels  # renders it
        out = {}
        for leg, (uv, facing) in self._rolling_vertex_pixels(frame).items():
            cam = self.truth.camera
            visible = np.zeros(N_VERTICES, dtype=bool)
            if facing:
                covered = self._renderer(frame.camera).occluders(frame.seg, self.body.link_index[f"{leg}Sandal"])
                r = int(math.ceil(clearance_px))
                for i, (u, v) in enumerate(uv):
                    if not (0 <= u <= cam.width_px - 1 and 0 <= v <= cam.height_px - 1):
                        continue
                    u0, v0 = int(round(u)), int(round(v))
                    visible[i] = not covered[max(v0 - r, 0):v0 + r + 1, max(u0 - r, 0):u0 + r + 1].any()
            out[leg] = (uv, visible)
        return out

    def _rolling_vertex_pixels(self, frame: _Frame) -> dict:
        """_vertex_pixels of a frame, each vertex at the time its row was exposed: v = v(q(row_time(v))), solved by
        fixed-point iteration on the vertices' paths sampled every readout / 32 (linear in between; a row's time
        moves a vertex by a small fraction of a pixel per pixel). Exact for a still robot."""
        out = self._vertex_pixels(frame.q_true, frame.camera)
        h = self.truth.camera.height_px
        t0, t1 = (float(t) for t in self.row_time(frame.t_true_s, [0.0, h - 1.0]))
        moving = [leg for leg in LEGS if self.realism.readout_s > 0.0 and out[leg][1]
                  and self._board_motion_px(t0, t1, leg, frame.camera) > 1e-3]
        if not moving:  # boards out of view, or still to a thousandth of a pixel
            return out
        times = np.linspace(t0, t1, 33)
        paths = [self._vertex_pixels(self._true_q(float(t)), frame.camera) for t in times]
        for leg in moving:
            uv, facing = out[leg]
            track = np.array([p[leg][0] for p in paths])  # (33, 24, 2)
            for _ in range(8):
                t_rows = self.row_time(frame.t_true_s, np.clip(np.nan_to_num(uv[:, 1]), 0.0, h - 1.0))
                uv = np.array([[np.interp(t, times, track[:, i, c]) for c in (0, 1)] for i, t in enumerate(t_rows)])
            out[leg] = (uv, facing)
        return out

    def _vertex_pixels(self, q_true: np.ndarray, camera: str = "bottom") -> dict:
        """{leg: (pixels (24, 2) through the true camera, whether the board faces the camera)}."""
        T_cam_world = invert_transform(self._T_world_cam(q_true, camera))
        out = {}
        for leg in LEGS:
            T_cam_board = T_cam_world @ self._T_world_board(q_true, leg)
            p_cam = self._vertices_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            in_front = bool(np.all(p_cam[:, 0] > 1e-3))
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = self.truth.camera.project(p_cam)
            facing = in_front and T_cam_board[:3, 2] @ T_cam_board[:3, 3] < 0
            out[leg] = (uv, facing)
        return out

    # --- Internals ------------------------------------------------------------------------------------------------
    def _check_open(self):
        if self._closed:
            raise NaocalError("the mock robot is closed")

    def _track(self, joint: str) -> _Track:
        return self._tracks[SHARED_MOTOR[0] if joint == SHARED_MOTOR[1] else joint]

    def _validate(self, targets_rad, speed_fraction) -> tuple[dict, float]:
        if not isinstance(targets_rad, dict) or not targets_rad:
            raise SafetyError("targets must be a non-empty {joint: angle} dict")
        speed = check_speed_fraction(speed_fraction)
        # The head's path is checked against the HeadPitch table point by point in _unsafe_reason.
        head_now = {j: [self._track(j).at(self._t), self._track(j).target[-1]] for j in HEAD_JOINTS}
        targets = check_targets(targets_rad, self._limits, head_angles=head_now)
        # One motor drives both HipYawPitch joints; as in NAOqi the left one's command wins.
        if SHARED_MOTOR[0] in targets:
            targets.pop(SHARED_MOTOR[1], None)
        elif SHARED_MOTOR[1] in targets:
            targets[SHARED_MOTOR[0]] = targets.pop(SHARED_MOTOR[1])
        return {j: v for j, v in targets.items() if self._stiffness[j] > 0.0}, speed

    def _durations(self, targets: dict, speed: float, start: float) -> tuple[dict, float]:
        starts = {j: self._tracks[j].at(start) for j in targets}
        duration = max((abs(targets[j] - starts[j]) / (speed * self._speeds[j]) for j in targets), default=0.0)
        return starts, duration

    def _plan(self, targets: dict, speed: float, start: float) -> list[tuple[float, np.ndarray]]:
        """(time, servo stance (14,)) points along the motion this command would cause, ending at rest."""
        starts, duration = self._durations(targets, speed, start)
        end = max([start + duration] + [self._tracks[j].end_time() for j in self._tracks if j not in targets])
        end = max(end, start)
        servo_now = np.array([self._track(j).at(start) for j in JOINTS])
        final = servo_now.copy()
        for joint in JOINTS:
            motor = SHARED_MOTOR[0] if joint == SHARED_MOTOR[1] else joint
            final[JOINT_INDEX[joint]] = targets[motor] if motor in targets else self._tracks[motor].target[-1]
        n = int(np.clip(np.ceil(np.max(np.abs(final - servo_now)) / 0.05), 1, 40))
        points = []
        for t in np.linspace(start, end, n + 1)[1:]:
            stance = np.empty(len(JOINTS))
            for i, joint in enumerate(JOINTS):
                motor = SHARED_MOTOR[0] if joint == SHARED_MOTOR[1] else joint
                if motor in targets:
                    frac = 1.0 if duration <= 0 else min(max((t - start) / duration, 0.0), 1.0)
                    stance[i] = starts[motor] + (targets[motor] - starts[motor]) * frac
                else:
                    stance[i] = self._tracks[motor].at(t)
            points.append((float(t), stance))
        return points

    def _stance_now(self) -> np.ndarray:
        return np.array([self._track(j).at(self._t) for j in JOINTS])

    def _unsafe_reason(self, final_servo: np.ndarray, path) -> str:
        """Why a motion through `path` [(t, servo stance)] to `final_servo` is unsafe, or '' if it is safe."""
        for _, servo in list(path) + [(None, final_servo)]:
            problem = head_pitch_problem(servo[JOINT_INDEX["HeadYaw"]], servo[JOINT_INDEX["HeadPitch"]],
                                         margin_rad=-1e-9)
            if problem:
                return problem
            q_true = self._true_static(servo)
            if not self.checker.is_safe(q_true):  # stops at the first contact; name it only then
                c = self.checker.contacts(q_true)[0]
                return f"{c.link_a} and {c.link_b} would come within {c.distance_m * 1000:.1f} mm"
        return ""

    def _true_static(self, servo: np.ndarray, directions: np.ndarray | None = None) -> np.ndarray:
        """True angles (14,) of a still robot whose motors stand at `servo` (command space)."""
        t = self.truth
        q = servo + np.array([t.alpha_rad[j] for j in JOINTS])
        if directions is not None:
            q = q + np.array([t.backlash_rad.get(j, 0.0) for j in JOINTS]) * directions
        compliance = np.array([t.compliance_rad_per_nm.get(j, 0.0) for j in JOINTS])
        if np.any(compliance):
            base = q.copy()
            for _ in range(50):  # q = base + c * tau(q): a contraction, c * dtau/dq << 1
                updated = base + compliance * self.body.gravity_torques(q)
                if np.max(np.abs(updated - q)) < 1e-13:
                    q = updated
                    break
                q = updated
        return q

    def _servo_q(self, t: float) -> np.ndarray:
        """Sensor-space positions (14,) at t: the reference (ideal), or its second-order response plus the
        rest offsets in force (realistic; backends.mock_servo)."""
        if self._exact_servo:
            return np.array([self._track(j).at(t) for j in JOINTS])
        tracks = [self._track(j) for j in JOINTS]
        return servo_positions(t, [tr.at(t) for tr in tracks], [tr.slope_at(t) for tr in tracks],
                               [tr.slope_changes() for tr in tracks], self._dynamics, self._rest_times,
                               self._rest_offsets)

    def _add_rest_offsets(self, targets: dict, start: float) -> None:
        """Where each joint will stand once this command's motion ends (Realism.servo_rest, sag under the
        gravity load of the posture it ends in), as a step of the rest offsets at that instant."""
        r = self.realism
        commanded = np.array([self._track(j).target[-1] for j in JOINTS])
        t_end = max(self._track(j).end_time() for j in JOINTS)
        self._n_commands_applied += 1
        if r.servo_rest == "uniform":
            rng = np.random.default_rng([self.seed, 15485863, self._n_commands_applied])
            draws = rng.uniform(-0.5, 0.5, len(JOINTS))
            for i, joint in enumerate(JOINTS):
                motor = SHARED_MOTOR[0] if joint == SHARED_MOTOR[1] else joint
                # A joint sent the target it already holds does not move (its reading stays in the commanded
                # cell), so it keeps where it stands: only a changed command finds a new place in its cell.
                if motor in targets and commanded[JOINT_INDEX[motor]] != self._rest_commanded[JOINT_INDEX[motor]]:
                    self._cell_draws[i] = draws[JOINT_INDEX[motor]]
            self._rest_commanded = commanded
        tau = np.zeros(len(JOINTS))
        if r.servo_stiffness_nm_per_rad is not None:
            tau = self.body.gravity_torques(self._true_static(commanded))
        offsets = np.array([rest_offset(c, t, r.servo_rest, self.encoder_resolution_rad,
                                        r.servo_stiffness_nm_per_rad, u)
                            for c, t, u in zip(commanded, tau, self._cell_draws)])
        # One motor, one sensor: both HipYawPitch joints stand where the left one does.
        offsets[JOINT_INDEX[SHARED_MOTOR[1]]] = offsets[JOINT_INDEX[SHARED_MOTOR[0]]]
        while self._rest_times and self._rest_times[-1] > start:  # superseded before they took effect
            self._rest_times.pop()
            self._rest_offsets.pop()
        self._rest_times.append(t_end)
        self._rest_offsets.append(offsets)

    def _true_q(self, t: float) -> np.ndarray:
        servo = self._servo_q(t)
        directions = np.array([self._track(j).direction(t) for j in JOINTS])
        return self._true_static(servo, directions)

    def _apply(self, targets: dict, speed: float, start: float) -> None:
        starts, duration = self._durations(targets, speed, start)
        for joint, target in targets.items():
            track = self._tracks[joint]
            previous = track.target[-1]
            if target != previous:
                track.dir_t.append(start)
                track.dirs.append(1.0 if target > previous else -1.0)
            track.t0.append(start)
            track.q0.append(starts[joint])
            track.target.append(target)
            track.duration.append(duration)

    def _T_world_cam(self, q_true: np.ndarray, camera: str = "bottom") -> np.ndarray:
        head = q_true[[JOINT_INDEX[j] for j in HEAD_JOINTS]]
        # the camera's mount, moved in the head frame by camera_translation (Trans(t) @ T_head_cam0)
        T_torso_cam = chain_frames(head_chain(camera), head[None],
                                   end_shift_m=self.truth.camera_translation_m[camera])[1][0].copy()
        T_torso_cam[:3, :3] = T_torso_cam[:3, :3] @ self.truth.R_cam_offset(camera)
        return T_WORLD_TORSO @ T_torso_cam

    def _T_world_board(self, q_true: np.ndarray, leg: str) -> np.ndarray:
        q_leg = q_true[[JOINT_INDEX[j] for j in leg_joints(leg)]]
        T_torso_sole = leg_fk(q_leg[None], leg, thigh_delta_m=self.truth.thigh_delta_m[leg],
                              tibia_delta_m=self.truth.tibia_delta_m[leg])[0]
        return T_WORLD_TORSO @ T_torso_sole @ self._T_sole_board[leg]

    def _frame_index(self, image: CameraImage) -> int:
        for (_, k), frame in self._frames.items():
            if frame.image is image:
                return k
        return int(round((self.exposure_time(image) - FRAME_PHASE_S) / FRAME_PERIOD_S))

    def _frame(self, k: int, camera: str = "bottom") -> _Frame:
        """Frame k of `camera` (exposed at FRAME_PHASE_S + k / 30 s), its image not yet rendered."""
        if (camera, k) in self._frames:
            return self._frames[(camera, k)]
        frame = _Frame(k, FRAME_PHASE_S + k * FRAME_PERIOD_S, camera)
        stamp = frame.t_true_s + self.truth.time_lag_s + self.realism.stamp_offset_s()
        frame.image = _LazyImage(lambda: self._render(frame), stamp, camera)
        self._frames[(camera, k)] = frame
        while len(self._frames) > 8:
            del self._frames[min(self._frames, key=lambda key: key[1])]
        return frame

    def _render(self, frame: _Frame) -> np.ndarray:
        """Render a frame: (h, w, 3) uint8 BGR pixels; keeps its mask and true angles for the truth."""
        self._check_open()
        k, t_true = frame.index, frame.t_true_s
        q_true = self._true_q(t_true)
        cam = frame.camera
        boards = {self.body.link_index[f"{leg}Sandal"]: self._board_poses(t_true, leg, cam) for leg in LEGS}
        grey, seg = self._renderer(cam).render(q_true, self._T_world_cam(q_true, cam), boards)
        rng = np.random.default_rng([self.seed, 7919, k])
        frame.seg, frame.q_true = seg, q_true
        if self.realism.glare_rate > 0:
            grey = self._glare(frame, grey)
        self.frames_rendered += 1
        if self.realism.is_ideal:
            pixels = grey * 255.0
            if self.image_noise_std > 0:
                pixels = pixels + rng.standard_normal(pixels.shape, dtype=np.float32) * self.image_noise_std
            grey_u8 = np.clip(np.rint(pixels), 0, 255).astype(np.uint8)
            return np.repeat(grey_u8[:, :, None], 3, axis=2)
        r = self.realism
        return form_image(grey, rng, luma_noise_std=self.image_noise_std, chroma_noise_std=r.chroma_noise_std,
                          defocus_sigma_px=r.defocus_sigma_px, yuyv=r.yuyv)

    def _glare_stream(self, frame_index: int):
        """The random stream of frame k's glare: its first draw decides whether there is one."""
        return np.random.default_rng([self.seed, 4243, frame_index])

    def _glare(self, frame: _Frame, grey: np.ndarray) -> np.ndarray:
        """With probability Realism.glare_rate, a specular patch on one of the boards in view (frame.glare says
        which: (leg, centre px, sigma px, amplitude))."""
        rng = self._glare_stream(frame.index)
        if rng.uniform() >= self.realism.glare_rate:
            return grey
        in_view = []
        for leg, (uv, facing) in self._vertex_pixels(frame.q_true, frame.camera).items():
            if facing and np.all(np.isfinite(uv)) and np.any((uv[:, 0] >= 0) & (uv[:, 0] < grey.shape[1])
                                                              & (uv[:, 1] >= 0) & (uv[:, 1] < grey.shape[0])):
                in_view.append(leg)
        if not in_view:
            return grey
        leg = in_view[int(rng.integers(len(in_view)))]
        T = self._seen_board(frame.t_true_s, leg, frame.camera)
        outline = self.truth.camera.project(board_outline_board_m() @ T[:3, :3].T + T[:3, 3])
        inner = self._vertices_board[[0, 5, 23, 18]]
        corners = self.truth.camera.project(inner @ T[:3, :3].T + T[:3, 3])
        h, w = grey.shape
        for _ in range(20):  # a point of the inner grid's quadrilateral (bilinear) that is in the image
            a, b = rng.uniform(0.0, 1.0, 2)
            centre = ((1 - a) * (1 - b) * corners[0] + a * (1 - b) * corners[1] + a * b * corners[2]
                      + (1 - a) * b * corners[3])
            if 0 <= centre[0] < w and 0 <= centre[1] < h:
                break
        else:
            return grey
        sigma, amplitude = float(rng.uniform(3.0, 10.0)), float(rng.uniform(0.3, 0.8))
        frame.glare = (leg, (float(centre[0]), float(centre[1])), sigma, amplitude)
        hidden = self._renderer(frame.camera).occluders(frame.seg, self.body.link_index[f"{leg}Sandal"])
        return add_glare(grey, outline, centre, sigma, amplitude, hidden)

    def _board_poses(self, t_mid: float, leg: str, camera: str = "bottom"):
        """A board's poses for rendering: [T_world_board, ...] over the exposure (global shutter), or, when the
        board moves while a rolling shutter reads the rows out, [RowBand] each with the poses of its rows' time."""
        readout = self.realism.readout_s
        if readout == 0.0:
            return self._blurred_board_poses(t_mid, leg, camera=camera)
        h = self.truth.camera.height_px
        t_first, t_last = self.row_time(t_mid, [0.0, h - 1.0])
        T = self._seen_board(t_mid, leg, camera)
        in_view = T[:3, 2] @ T[:3, 3] < 0 and np.all(board_outline_board_m() @ T[:3, 0] + T[0, 3] > 0.02)
        moved_px = self._board_motion_px(t_first - self.exposure_s / 2, t_last + self.exposure_s / 2, leg, camera)
        if not in_view or moved_px < 0.05:  # not drawn, or still (to 0.05 px): every row shows the same pose
            return [self._T_world_board(self._true_q(t_mid), leg)]
        n_bands = int(np.clip(np.ceil(moved_px / 0.5), 2, 48))  # rows of a band differ by < 0.5 px of motion
        edges = np.linspace(0, h, n_bands + 1).round().astype(int)
        T_world_cam_mid = self._T_world_cam(self._true_q(t_mid), camera)
        bands = []
        for v0, v1 in zip(edges[:-1], edges[1:]):
            t_band = float(self.row_time(t_mid, (v0 + v1 - 1) / 2.0))
            poses = self._blurred_board_poses(t_band, leg, T_world_cam_ref=T_world_cam_mid, camera=camera)
            bands.append(RowBand(int(v0), int(v1), poses))
        return bands

    def _seen_board(self, t: float, leg: str, camera: str = "bottom") -> np.ndarray:
        """T_cam_board at t: the board as the camera sees it (head motion included)."""
        q = self._true_q(t)
        return invert_transform(self._T_world_cam(q, camera)) @ self._T_world_board(q, leg)

    def _board_motion_px(self, t0: float, t1: float, leg: str, camera: str = "bottom") -> float:
        """How far (px) the board's outer vertices move in the image between t0 and t1."""
        corners = self._vertices_board[[0, 5, 18, 23]]
        uv = [self.truth.camera.project(corners @ T[:3, :3].T + T[:3, 3])
              for T in (self._seen_board(t0, leg, camera), self._seen_board(t1, leg, camera))]
        return float(np.nan_to_num(np.max(np.linalg.norm(uv[0] - uv[1], axis=1)), nan=0.0))

    def _blurred_board_poses(self, t_mid: float, leg: str, T_world_cam_ref: np.ndarray | None = None,
                             camera: str = "bottom") -> list[np.ndarray]:
        """Board poses spread over the exposure, as seen from the camera (head motion included) but expressed
        in the world through the camera's pose at mid-exposure (or T_world_cam_ref); a single pose if the board's
        image moves by less than 0.3 px during the exposure."""
        half = self.exposure_s / 2
        moved_px = self._board_motion_px(t_mid - half, t_mid + half, leg, camera)
        steps = int(np.clip(np.ceil(moved_px / 0.3), 1, 16))
        T_world_cam_mid = (self._T_world_cam(self._true_q(t_mid), camera) if T_world_cam_ref is None
                           else T_world_cam_ref)
        if steps == 1:
            return [T_world_cam_mid @ self._seen_board(t_mid, leg, camera)] if T_world_cam_ref is not None else [
                self._T_world_board(self._true_q(t_mid), leg)]
        times = t_mid - half + (np.arange(steps) + 0.5) * self.exposure_s / steps
        return [T_world_cam_mid @ self._seen_board(float(t), leg, camera) for t in times]


def _as_float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")
