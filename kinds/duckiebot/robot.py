"""The Duckiebot described: wheels, encoders, camera prior and its mount on the body (docs/DUCKIEBOT.md).

Frames (right-handed, SI):
- `base`: on the floor below the midpoint of the wheel axle; x forward, y left, z up. Duckietown's ground
  homography maps to this frame's (x, y) ("x forward from the wheel axle, y left").
- `camera`: naocal's camera frame (docs/CONVENTIONS.md): x along the optical axis, y left, z up, so that
  solver.camera projects with it unchanged. `T_base_camera` is its pose in `base`.

Sources of the numbers (public): Duckietown's dt-car-interface kinematics node (defaults), dt-duckiebot-interface
(encoders: 135 ticks per revolution on the DB21; the DB18 has none), gym-duckietown (camera about 0.108 m above
the floor, 0.066 m ahead of the axle, pitched down about 19 deg), and the medians of about 170 real Duckiebots'
calibration files (camera prior: fx 336.5 px, cx 316, cy 233, k1 -0.283, k2 0.058).
"""

from __future__ import annotations

import functools
import logging
import math
import re
from dataclasses import dataclass, field

import numpy as np

from naocal.solver import fields
from naocal.solver.camera import CameraIntrinsics
from naocal.solver.errors import NaocalError
from naocal.solver.transforms import make_transform, rot_x, rot_y, rot_z

# Duckietown's kinematics defaults (dt-car-interface kinematics_node).
DEFAULT_GAIN = 1.0
DEFAULT_TRIM = 0.0
DEFAULT_K = 27.0  # rad/s of wheel speed per unit duty (nominal; real robots are 30-40 % off, docs/DUCKIEBOT.md)
DEFAULT_LIMIT = 1.0
DEFAULT_V_MAX_MPS = 1.0
DEFAULT_OMEGA_MAX_RADPS = 8.0
WHEEL_RADIUS_M = 0.0318
BASELINE_M = 0.1
DB21_TICKS_PER_REVOLUTION = 135

# The camera: 640 x 480, wide lens calibrated as plumb_bob; prior = the real robots' medians.
IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX = 640, 480
PRIOR_FX_PX = PRIOR_FY_PX = 336.5  # fy/fx is 0.985-1.010 on real robots: equal as the prior
PRIOR_CX_PX, PRIOR_CY_PX = 316.0, 233.0
PRIOR_DISTORTION = (-0.283, 0.058, 0.0, 0.0, 0.0)  # (k1, k2, p1, p2, k3); k3 is 0 on every real robot
CAMERA_AHEAD_M = 0.066  # of the wheel axle
CAMERA_HEIGHT_M = 0.108  # above the floor
CAMERA_PITCH_RAD = math.radians(19.0)  # down


KINEMATICS = "kinematics"  # what Kinematics' refusals name in place of a file
POSITIVE_KINEMATICS = ("baseline_m", "radius_m", "k", "limit", "v_max_mps", "omega_max_radps")


@dataclass(frozen=True)
class Kinematics:
    """Duckietown's kinematics parameters (the keys of its kinematics/<robot>.yaml), SI.

    Duty u in [-limit, limit] drives a wheel at w = u k / (gain +- trim) rad/s (+ right wheel, - left);
    v_max_mps and omega_max_radps bound the commanded body velocity before inverse kinematics."""

    baseline_m: float = BASELINE_M
    radius_m: float = WHEEL_RADIUS_M
    gain: float = DEFAULT_GAIN
    trim: float = DEFAULT_TRIM
    k: float = DEFAULT_K
    limit: float = DEFAULT_LIMIT
    v_max_mps: float = DEFAULT_V_MAX_MPS
    omega_max_radps: float = DEFAULT_OMEGA_MAX_RADPS

    def __post_init__(self):
        """Each value checked by solver.fields: DataError naming the field ("kinematics, field 'limit': ..."); a
        reader re-raises it naming its file and its own key for the field."""
        for name in ("baseline_m", "radius_m", "gain", "trim", "k", "limit", "v_max_mps", "omega_max_radps"):
            fields.number(getattr(self, name), KINEMATICS, name, positive=name in POSITIVE_KINEMATICS,
                          high=1.0 if name == "limit" else math.inf)  # the largest duty is 1
        if self.gain + self.trim == 0 or self.gain - self.trim == 0:
            fields.fail(KINEMATICS, f"gain +- trim must not be 0 (gain {self.gain!r}, trim {self.trim!r}): a wheel "
                                    "would need an infinite duty", "trim")


@dataclass(frozen=True)
class Duckiebot:
    """A Duckiebot model's description: nominal wheel geometry, encoders, camera prior and camera mount."""

    model: str
    radius_m: float
    baseline_m: float
    ticks_per_revolution: int | None  # None: no wheel encoders (DB18)
    camera: CameraIntrinsics
    T_base_camera: np.ndarray = field(repr=False)

    def nominal_kinematics(self) -> Kinematics:
        """Duckietown's defaults for this robot (gain 1, trim 0, k 27, limit 1): what an uncalibrated robot runs."""
        return Kinematics(baseline_m=self.baseline_m, radius_m=self.radius_m)


def camera_mount(ahead_m: float = CAMERA_AHEAD_M, height_m: float = CAMERA_HEIGHT_M,
                 pitch_down_rad: float = CAMERA_PITCH_RAD, lateral_m: float = 0.0, roll_rad: float = 0.0,
                 yaw_rad: float = 0.0) -> np.ndarray:
    """T_base_camera (4, 4) of a camera `ahead_m` in front of the axle, `height_m` above the floor, pitched down by
    `pitch_down_rad` (a positive rot_y turns the optical axis x towards -z), then yawed and rolled
    (R = Rz(yaw) Ry(pitch) Rx(roll), the URDF order)."""
    R = rot_z(yaw_rad) @ rot_y(pitch_down_rad) @ rot_x(roll_rad)
    return make_transform(R, (ahead_m, lateral_m, height_m))


def prior_camera() -> CameraIntrinsics:
    """The camera prior: 640 x 480, the real robots' median intrinsics and plumb_bob distortion."""
    return CameraIntrinsics(IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX, PRIOR_FX_PX, PRIOR_FY_PX, PRIOR_CX_PX, PRIOR_CY_PX,
                            PRIOR_DISTORTION)


# The DB21 as Duckietown sells it is the DB21M or DB21J (the same chassis, wheels, encoders and camera); the DB19 is
# the DB18's successor without encoders. A log recorded elsewhere names its robot's model as its maker does.
ENCODER_MODELS = ("DB21", "DB21M", "DB21J")
MODELS = ENCODER_MODELS + ("DB19", "DB18")


def nominal_for(model: str) -> Duckiebot:
    """The nominal robot of a log's `robot.model`: the model's own description; a model naocal does not know (a
    lab's own build, a newer name) is taken as a DB21 body (its camera mount, its lens prior: the start values of
    the fit, which fits both), with a warning. The wheels are the log's own (radius, baseline, k, ticks), whatever
    the model."""
    if model in MODELS:
        return duckiebot(model)
    warn_unknown_model(model)
    return duckiebot("DB21")


@functools.lru_cache(maxsize=None)
def warn_unknown_model(model: str) -> None:
    """Once per model and process: identify and diagnose ask for the nominal robot at every step."""
    logging.getLogger(__name__).warning(
        "robot.model %s is not a model naocal knows (%s): the DB21's camera mount and lens prior start the fit",
        fields.shown(model), ", ".join(MODELS))


def duckiebot(model: str = "DB21") -> Duckiebot:
    """The description of a Duckiebot model: the DB21 and its variants (ENCODER_MODELS: wheel encoders, 135 ticks per
    revolution) or the DB18 / DB19 (none). NaocalError for any other name."""
    if model not in MODELS:
        raise NaocalError(f"unknown Duckiebot model {model!r}: expected one of {', '.join(MODELS)}")
    ticks = DB21_TICKS_PER_REVOLUTION if model in ENCODER_MODELS else None
    return Duckiebot(model, WHEEL_RADIUS_M, BASELINE_M, ticks, prior_camera(), camera_mount())


# A Duckiebot's name is its hostname and its ROS namespace, and becomes a file name (<robot>.yaml) and a YAML
# value: letters, digits and underscores, a letter first (a ROS name), at most 63 characters (a hostname label).
ROBOT_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")


def robot_name_problem(name) -> str | None:
    """Why `name` cannot be a Duckiebot's name (a file name and a YAML value), or None when it can."""
    if not isinstance(name, str):
        return f"expected a robot name (text), got {type(name).__name__}"
    if not ROBOT_NAME.fullmatch(name):
        return (f"robot name {name[:40]!r} is not a Duckiebot name: letters, digits and underscores, a letter "
                "first, at most 63 characters")
    return None


def raw_pixels(flags: int) -> int:
    """`flags` for cv2.imdecode that keep the pixels as the sensor gave them: OpenCV turns a JPEG by its EXIF
    orientation tag unless told not to (IMREAD_UNCHANGED never turns it), and a turned frame is another camera."""
    import cv2  # here: the description itself needs no OpenCV

    return flags if flags < 0 else flags | cv2.IMREAD_IGNORE_ORIENTATION


def decoded_frame(data, width_px: int = IMAGE_WIDTH_PX, height_px: int = IMAGE_HEIGHT_PX):
    """The 8-bit grey image a compressed camera frame (PNG or JPEG bytes) holds, checked before it is used or echoed
    (the ROS driver's frames, the bridge client's): (image, None), or (None, why not) when it does not decode or is
    not `width_px` x `height_px`."""
    import cv2  # here: the description itself needs no OpenCV

    if not isinstance(data, (bytes, bytearray)) or not data:
        return None, f"no image bytes (got {type(data).__name__} of {len(data) if hasattr(data, '__len__') else '?'})"
    image = cv2.imdecode(np.frombuffer(data, np.uint8), raw_pixels(cv2.IMREAD_GRAYSCALE))
    if image is None or image.size == 0:
        return None, f"does not decode as an image ({len(data)} bytes)"
    if image.shape != (height_px, width_px):
        return None, f"is {image.shape[1]} x {image.shape[0]}, expected {width_px} x {height_px}"
    return image, None
