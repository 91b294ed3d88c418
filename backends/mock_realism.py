"""How real the mock robot is: `Realism` settings, the presets `IDEAL` and `REALISTIC`, and their validation.

`MockBackend(realism="ideal")` is the robot the solver was built on (exact commands, 0.1 deg readings, a global
shutter, grey images, offsets of a degree or two); `realism="realistic"` is a NAO V6 as teams meet it (LoLA's 12 ms
joint cycle, 12-bit encoders, a servo that only sees its steps and sags under load, a rolling-shutter YUYV camera
stamped like a V4L2 buffer, offsets as large as real robots carry, and a detector that now and then gets a corner
wrong). docs/MOCK.md gives every figure with its source.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from naocal.solver.errors import NaocalError

SERVO_REST_MODES = ("command", "centre", "uniform", "load")
REALISM_NAMES = ("ideal", "realistic")


@dataclass(frozen=True)
class Realism:
    """Every knob that separates the realistic mock from the ideal one (SI units inside, as everywhere).

    Joints
        encoder_step_rad : readings are multiples of this (0: unquantised).
        sensor_period_s, sensor_lag_cycles : a reading is the sample `sensor_lag_cycles` periods old.
        servo_rest : where a still joint truly stands, in sensor space, relative to its command c and the
            commanded step's cell [k - 1/2, k + 1/2] * step, k = round(c / step):
            'command' at c; 'centre' at k * step; 'uniform' anywhere in the cell (drawn per joint and command);
            'load' at c + tau / K (a P-gain without deadband: off by a load-dependent error, also across cells).
            In the first three the gravity load tau pulls the joint by tau / K but the servo, which sees only its
            steps, keeps it inside the commanded cell (its deadband is the cell).
        servo_stiffness_nm_per_rad : K above (None: infinitely stiff, no sag).
        servo_time_constant_s, servo_damping : the joint follows the interpolated command like a second-order
            system with this decay time constant 1 / (zeta * omega_n) and damping ratio zeta (None: exactly).
    Camera
        prior_focal_px : the camera's prior fx = fy (the intrinsics the agent is given); None: the robot
            description's (solver/data/nao.json, 600 px: the camera the solver was built on).
        focal_error_px, principal_error_px : the true fx, fy (cx, cy) differ from the prior by up to this.
        readout_s : rows are exposed one after another over this long (0: a global shutter).
        stamp_delay_s : B-Human's imageRecordingDelay d: the first row is exposed at stamp - readout - d.
            None: the stamp is the middle of the exposure (the ideal mock's convention).
        yuyv : capture in YUYV 4:2:2 (chroma at half horizontal resolution), converted to BGR for the agent.
        luma_noise_std, chroma_noise_std : Gaussian sensor noise, grey levels (Y in 16..235 when yuyv).
        defocus_sigma_px : a small Gaussian blur (0: sharp).
    Hidden errors
        large_offsets : draw offsets as large as real robots carry (else the ideal mock's 0.2-2 deg).
        hip_yaw_pitch_max_deg, leg_offset_max_deg : offset ranges (large_offsets only).
        camera_pitch_range_deg, camera_pitch_outlier_deg, camera_pitch_outlier_rate : camera pitch correction
            uniform in the range, or with this probability an outlier of the given size with random sign.
    Identity
        robot_model : the robot the preset plays, as `robot_identity()["model"]` names it (the ideal mock keeps
            the name it had before the presets: runs record it and a resume compares it).
    Detector
        corner_fault_rate : the share of detected corners the mock's fault model moves (see backends.mock_faults).
        glare_rate : the share of frames with a specular patch on a board.
    """

    name: str = "ideal"
    robot_model: str = "NAO H25 V5"
    encoder_step_rad: float = math.radians(0.1)
    sensor_period_s: float = 0.01
    sensor_lag_cycles: int = 3
    servo_rest: str = "command"
    servo_stiffness_nm_per_rad: float | None = None
    servo_time_constant_s: float | None = None
    servo_damping: float = 0.7
    prior_focal_px: float | None = None
    focal_error_px: float = 0.0
    principal_error_px: float = 0.0
    readout_s: float = 0.0
    stamp_delay_s: float | None = None
    yuyv: bool = False
    luma_noise_std: float = 1.0
    chroma_noise_std: float = 0.0
    defocus_sigma_px: float = 0.0
    large_offsets: bool = False
    hip_yaw_pitch_max_deg: float = 12.0
    leg_offset_max_deg: float = 3.0
    camera_pitch_range_deg: tuple = (-6.0, 2.0)
    camera_pitch_outlier_deg: tuple = (7.0, 14.0)
    camera_pitch_outlier_rate: float = 0.1
    corner_fault_rate: float = 0.0
    glare_rate: float = 0.0

    def __post_init__(self):
        check_realism(self)

    @property
    def is_ideal(self) -> bool:
        return self == IDEAL

    def stamp_offset_s(self) -> float:
        """Buffer timestamp minus the middle row's exposure time (0 for the ideal mock)."""
        if self.stamp_delay_s is None:
            return 0.0
        return self.stamp_delay_s + self.readout_s / 2.0

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def check_realism(r: Realism) -> None:
    """NaocalError naming the first bad field."""
    def bad(field: str, why: str):
        raise NaocalError(f"mock realism: {field} {why}")

    if r.servo_rest not in SERVO_REST_MODES:
        bad("servo_rest", f"must be one of {', '.join(SERVO_REST_MODES)}, got {r.servo_rest!r}")
    for f in fields(r):
        value = getattr(r, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            bad(f.name, f"must be finite, got {value}")
    for name in ("encoder_step_rad", "readout_s", "luma_noise_std", "chroma_noise_std", "defocus_sigma_px",
                 "focal_error_px", "principal_error_px", "corner_fault_rate", "glare_rate",
                 "camera_pitch_outlier_rate"):
        if getattr(r, name) < 0:
            bad(name, f"must not be negative, got {getattr(r, name)}")
    if r.sensor_period_s <= 0 or r.sensor_lag_cycles < 0:
        bad("sensor_period_s", "must be positive (and sensor_lag_cycles >= 0)")
    if r.servo_stiffness_nm_per_rad is not None and not r.servo_stiffness_nm_per_rad > 0:
        bad("servo_stiffness_nm_per_rad", f"must be positive or None, got {r.servo_stiffness_nm_per_rad}")
    if r.servo_time_constant_s is not None and not r.servo_time_constant_s > 0:
        bad("servo_time_constant_s", f"must be positive or None, got {r.servo_time_constant_s}")
    if not 0.0 < r.servo_damping < 1.0:
        bad("servo_damping", f"must be within (0, 1) (an underdamped servo), got {r.servo_damping}")
    if r.servo_rest != "command" and r.encoder_step_rad <= 0:
        bad("servo_rest", f"{r.servo_rest!r} needs a positive encoder_step_rad")
    if r.prior_focal_px is not None and not r.prior_focal_px > 0:
        bad("prior_focal_px", f"must be positive, got {r.prior_focal_px}")
    for name in ("corner_fault_rate", "glare_rate", "camera_pitch_outlier_rate"):
        if getattr(r, name) > 1:
            bad(name, f"must be within 0..1, got {getattr(r, name)}")


# The ideal mock: what MockBackend was before it had a realism setting (the whole test suite relies on it).
IDEAL = Realism()

# A NAO V6 as real robots are (figures and sources: docs/MOCK.md).
REALISTIC = Realism(
    name="realistic",
    robot_model="NAO H25 V6",
    encoder_step_rad=2.0 * math.pi / 4096,  # 12-bit magnetic rotary encoder
    sensor_period_s=0.012,  # LoLA: 83.3 Hz
    sensor_lag_cycles=3,  # B-Human motionDelay = 3 frames
    servo_rest="uniform",
    servo_stiffness_nm_per_rad=1300.0,  # not published: the largest lying-leg load (1.4 N m) pulls ~0.7 step
    servo_time_constant_s=0.025,
    servo_damping=0.7,  # 4.6 % overshoot to a step, settled (2 %) within about 0.1 s
    prior_focal_px=618.0,  # B-Human / HULKs: fx 618.7, fy 617.2 at 640 x 480
    focal_error_px=1.5,
    principal_error_px=2.0,
    readout_s=0.045,  # B-Human cameraTimings, lower camera: imageRecordingTime 0.045 s
    stamp_delay_s=-0.036,  # ... imageRecordingDelay -0.036 s
    yuyv=True,
    luma_noise_std=2.0,
    chroma_noise_std=1.5,
    defocus_sigma_px=0.6,
    large_offsets=True,
    corner_fault_rate=0.015,
    glare_rate=0.05,
)

PRESETS = {"ideal": IDEAL, "realistic": REALISTIC}


def as_realism(realism) -> Realism:
    """A Realism from a preset name, a Realism, or a dict {"preset": name, field: value, ...}."""
    if isinstance(realism, Realism):
        return realism
    if realism is None:
        return IDEAL
    if isinstance(realism, str):
        if realism not in PRESETS:
            raise NaocalError(f"mock realism {realism!r}: expected one of {', '.join(REALISM_NAMES)}")
        return PRESETS[realism]
    if isinstance(realism, dict):
        settings = dict(realism)
        base = as_realism(settings.pop("preset", "ideal"))
        known = {f.name for f in fields(Realism)}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise NaocalError(f"mock realism: unknown field {unknown[0]!r}")
        return replace(base, **settings)
    raise NaocalError(f"mock realism must be 'ideal', 'realistic' or a Realism, got {type(realism).__name__}")
