"""Duckietown's three calibration files: a writer, a strict reader and plausibility checks (docs/DUCKIEBOT.md).

What a Duckietown user drops into the robot's /data/config/calibrations/ (the keys are Duckietown's, public in its
dt-car-interface, dt-core and docs-opmanual_duckiebot; no Duckietown code or file is copied here):

    kinematics/<robot>.yaml        baseline, calibration_time, gain, k, limit, radius, trim (+ v_max, omega_max)
    camera_intrinsic/<robot>.yaml  ROS camera_info: image_width, image_height, camera_name, camera_matrix,
                                   distortion_model (plumb_bob), distortion_coefficients, rectification_matrix,
                                   projection_matrix ({rows, cols, data} each)
    camera_extrinsic/<robot>.yaml  homography: 9 floats, row-major: rectified pixels (the projection_matrix's
                                   camera) -> ground (m, x forward from the wheel axle, y left), H[2][2] = 1

YAML without PyYAML: the writer emits a fixed layout by hand (floats always with a '.', so that PyYAML, which
Duckietown reads them with, sees floats: it reads '1e-05' as a string); the reader parses the subset such files use
(mappings, flow lists possibly over several lines, block lists, comments) and refuses anything else (tabs, anchors,
tags, duplicate keys) naming the file and line.

Plausibility (`check_calibration`): about 4 % of real robots' files are broken (fx 11454, k1 -5.4, homographies
with H[1][2] > 0) and went unnoticed. Values beyond any working Duckiebot are refused (the writer writes nothing,
the reader raises); values outside the real robots' usual ranges are warnings the caller must show.
"""

from __future__ import annotations

import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from naocal.kinds.duckiebot.robot import Kinematics, robot_name_problem
from naocal.solver.camera import plane_homography
from naocal.solver import fields
from naocal.solver.errors import DataError, NaocalError
from naocal.solver.fileio import atomic_write_text, check_output_file, read_text
from naocal.solver.transforms import invert_transform

KINEMATICS_DIR, INTRINSIC_DIR, EXTRINSIC_DIR = "kinematics", "camera_intrinsic", "camera_extrinsic"
DISTORTION_MODEL = "plumb_bob"  # what Duckietown's files hold and its rectification assumes
KINEMATICS_KEYS = ("baseline", "calibration_time", "gain", "k", "limit", "radius", "trim")
KINEMATICS_OPTIONAL_KEYS = ("v_max", "omega_max")
# each number's key in the file -> its Kinematics field
KINEMATICS_FIELDS = {"baseline": "baseline_m", "gain": "gain", "k": "k", "limit": "limit",
                     "omega_max": "omega_max_radps", "radius": "radius_m", "trim": "trim", "v_max": "v_max_mps"}
INTRINSIC_KEYS = ("image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                  "distortion_coefficients", "rectification_matrix", "projection_matrix")
MATRIX_SHAPES = {"camera_matrix": (3, 3), "distortion_coefficients": (1, 5), "rectification_matrix": (3, 3),
                 "projection_matrix": (3, 4)}
CALIBRATION_TIME = re.compile(r"\d{4}-\d\d-\d\d-\d\d-\d\d-\d\d")  # Duckietown's %Y-%m-%d-%H-%M-%S
# Where a Duckiebot's own software reads its calibration (`naocal verify LOG` looks there without --offsets); the
# environment variable moves it (a copy of a robot's files on a laptop; the tests).
DEFAULT_CALIBRATIONS_DIR = "/data/config/calibrations"
CALIBRATIONS_DIR_VARIABLE = "NAOCAL_DUCKIETOWN_CALIBRATIONS"


@dataclass(frozen=True)
class CameraCalibration:
    """A camera_intrinsic file's content: K (3, 3), plumb_bob (k1, k2, p1, p2, k3), the rectification R (3, 3) and
    the rectified camera P (3, 4), whose pixels the ground homography takes."""

    width_px: int
    height_px: int
    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: np.ndarray | None = None  # None: [K | 0], the undistorted image with the same camera matrix

    def projection(self) -> np.ndarray:
        return np.hstack([self.K, np.zeros((3, 1))]) if self.P is None else np.asarray(self.P, dtype=float)


@dataclass(frozen=True)
class DuckietownCalibration:
    """The three files' content for one robot. `homography` (3, 3), H[2][2] = 1."""

    robot: str
    kinematics: Kinematics
    camera: CameraCalibration
    homography: np.ndarray
    calibration_time: str = ""  # Duckietown's YYYY-MM-DD-HH-MM-SS; empty: now, when written


@dataclass(frozen=True)
class Finding:
    """One plausibility finding: `refuse` (beyond any working Duckiebot) or `warn` (unusual on real robots)."""

    level: str
    field: str
    message: str

    def __str__(self) -> str:
        return f"{self.field}: {self.message}"


def ground_homography(T_base_camera, P) -> np.ndarray:
    """Duckietown's homography for a camera at T_base_camera (naocal's camera frame, docs/CONVENTIONS.md) whose
    rectified image is P (3, 3 or 4): rectified pixels (u, v, 1) -> ground (x, y, 1) in the base frame, H[2][2] = 1.
    """
    P = np.asarray(P, dtype=float)
    pinhole = {"fx_px": P[0, 0], "fy_px": P[1, 1], "cx_px": P[0, 2], "cy_px": P[1, 2]}
    if abs(P[0, 1]) > 1e-9 or np.any(np.abs(P[:, 3:]) > 1e-9):
        raise ValueError("only a rectified camera without skew or stereo baseline is supported")
    ground_to_pixel = plane_homography(invert_transform(np.asarray(T_base_camera, dtype=float)), pinhole)
    H = np.linalg.inv(ground_to_pixel)
    return H / H[2, 2]


# naocal's camera frame (x optical axis, y left, z up; docs/CONVENTIONS.md) -> OpenCV's (x right, y down, z optical)
NAOCAL_TO_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def camera_pose_from_homography(H, P, R=None) -> np.ndarray:
    """T_base_camera (4, 4) of the camera whose ground homography is H (rectified pixels -> ground, any scale), the
    rectified camera being P (3, 4) after the rectification R (3, 3; the identity of a monocular camera): the inverse
    of ground_homography. inv(H) ~ A [r0 r1 t] with A = P[:, :3] R (optical <- naocal camera frame) and [r0 r1 t] the
    base's x and y axes and origin in the camera frame; of the two signs of the scale the one that puts the camera
    above the floor (the other sees the floor from below). ValueError for a P with a stereo baseline or an H that no
    camera gives."""
    P = np.asarray(P, dtype=float)
    if P.shape != (3, 4) or np.any(np.abs(P[:, 3]) > 1e-9):
        raise ValueError("only a rectified camera without stereo baseline is supported")
    A = P[:, :3] @ (np.eye(3) if R is None else np.asarray(R, dtype=float)) @ NAOCAL_TO_OPTICAL
    M = np.linalg.solve(A, np.linalg.inv(np.asarray(H, dtype=float)))
    norms = np.linalg.norm(M[:, :2], axis=0)
    if not np.all(np.isfinite(norms)) or norms.min() <= 0 or abs(norms[0] / norms[1] - 1.0) > 0.05:
        raise ValueError(f"no camera gives it (its ground axes scale {norms[0]:.4g} and {norms[1]:.4g} differ)")
    r0, r1, t = M.T / norms.mean()
    R_cam_base = np.column_stack([r0, r1, np.cross(r0, r1)])
    U, _, Vt = np.linalg.svd(R_cam_base)  # the nearest rotation (exact data: already one, to rounding)
    R_cam_base = U @ Vt
    T_base_camera = invert_transform(np.vstack([np.column_stack([R_cam_base, t]), [0.0, 0.0, 0.0, 1.0]]))
    if T_base_camera[2, 3] < 0:  # the other sign: R's first two columns and t negated, the height flips
        R_cam_base = R_cam_base @ np.diag([-1.0, -1.0, 1.0])
        T_base_camera = invert_transform(np.vstack([np.column_stack([R_cam_base, -t]), [0.0, 0.0, 0.0, 1.0]]))
    return T_base_camera


def duckietown_calibration(robot: str, kinematics: Kinematics, camera, T_base_camera,
                           calibration_time: str = "") -> DuckietownCalibration:
    """The three files' content from a calibrated robot: its kinematics, its camera (solver.camera.CameraIntrinsics,
    plumb_bob) and the camera's pose on the body. The rectified camera is [K | 0] (the undistorted image with the
    same camera matrix), and the homography is that camera's view of the floor."""
    K = np.array([[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]])
    calibration = CameraCalibration(int(camera.width_px), int(camera.height_px), K,
                                    np.asarray(camera.distortion, dtype=float))
    return DuckietownCalibration(robot, kinematics, calibration, ground_homography(T_base_camera, K),
                                 calibration_time)


def apply_homography(H, uv) -> np.ndarray:
    """(..., 2) ground points of pixels (..., 2) under H."""
    uv = np.asarray(uv, dtype=float)
    p = np.einsum("ij,...j->...i", H, np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1))
    return p[..., :2] / p[..., 2:]


# ------------------------------------------------------------------------------------------------ plausibility
# Real robots (about 170 files, 640 x 480, 2017-2018; docs/DUCKIEBOT.md): fx median 336.5 px (5-95 % 319-360),
# fy/fx 0.985-1.010, cx 300-336, cy 212-257, k1 -0.322..-0.250, k2 0.043..0.094, |p1|, |p2| <= 0.005, k3 0;
# trim 5-95 % -0.095..+0.102 (outliers 0.4), gain 0.3-1.5 (three at -1: a motor wired backwards), baseline 0.1,
# radius 0.0318. "Usual" ranges widen those a little (a warning); "possible" ones hold any working Duckiebot
# camera and drive (beyond: refused). Pixel ranges scale with the image width (640 px).
USUAL = {"fx": (300.0, 380.0), "fy/fx": (0.97, 1.03), "cx": (290.0, 345.0), "cy": (200.0, 270.0),
         "k1": (-0.36, -0.20), "k2": (0.02, 0.13), "p": (-0.01, 0.01), "k3": (-0.05, 0.05),
         "gain": (0.3, 1.5), "trim": (-0.2, 0.2), "baseline": (0.09, 0.11), "radius": (0.030, 0.034),
         "k": (15.0, 45.0), "ahead": (0.05, 0.30)}
POSSIBLE = {"fx": (150.0, 1000.0), "fy/fx": (0.8, 1.25), "cx": (160.0, 480.0), "cy": (120.0, 360.0),
            "k1": (-1.0, 0.5), "k2": (-1.0, 1.0), "p": (-0.05, 0.05), "k3": (-1.0, 1.0),
            "gain": (-3.0, 3.0), "trim": (-0.5, 0.5), "baseline": (0.05, 0.3), "radius": (0.01, 0.1),
            "k": (1.0, 200.0), "ahead": (0.0, 1.0)}
REFERENCE_WIDTH_PX = 640.0
PIXEL_QUANTITIES = ("fx", "cx", "cy")


def _judge(findings, name, field_name, value, scale=1.0, what=""):
    low, high = (b * scale for b in POSSIBLE[name])
    if not low <= value <= high:
        findings.append(Finding("refuse", field_name, f"{value:.6g}{what} is beyond any working Duckiebot's "
                                                      f"({low:.4g}..{high:.4g}): a broken calibration"))
        return
    low, high = (b * scale for b in USUAL[name])
    if not low <= value <= high:
        findings.append(Finding("warn", field_name, f"{value:.6g}{what} is unusual for a Duckiebot (real robots: "
                                                    f"{low:.4g}..{high:.4g}); check it"))


def check_kinematics(kin: Kinematics) -> list[Finding]:
    """Plausibility findings for a kinematics calibration."""
    findings = []
    for name, key, value in (("gain", "gain", kin.gain), ("trim", "trim", kin.trim), ("k", "k", kin.k),
                             ("baseline", "baseline", kin.baseline_m), ("radius", "radius", kin.radius_m)):
        _judge(findings, name, f"kinematics.{key}", value)
    if abs(kin.gain) < 0.05:
        findings.append(Finding("refuse", "kinematics.gain", f"{kin.gain:.6g}: the wheels would need a "
                                                             "near-infinite duty"))
    elif abs(kin.trim) >= abs(kin.gain):
        findings.append(Finding("refuse", "kinematics.trim", f"|trim| {abs(kin.trim):.6g} >= |gain| "
                                                             f"{abs(kin.gain):.6g}: one wheel would turn backwards"))
    if kin.gain < 0:
        findings.append(Finding("warn", "kinematics.gain", f"{kin.gain:.6g} is negative: both motors wired "
                                                           "backwards? Check the wiring"))
    return findings


def check_camera(camera: CameraCalibration) -> list[Finding]:
    """Plausibility findings for a camera_intrinsic calibration (plumb_bob)."""
    findings = []
    scale = camera.width_px / REFERENCE_WIDTH_PX
    K = camera.K
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    _judge(findings, "fx", "camera_matrix.fx", fx, scale, " px")
    if fx > 0:
        _judge(findings, "fy/fx", "camera_matrix.fy", fy / fx, what=" (fy/fx)")
    _judge(findings, "cx", "camera_matrix.cx", cx, scale, " px")
    _judge(findings, "cy", "camera_matrix.cy", cy, camera.height_px / 480.0, " px")
    if abs(K[0, 1]) > 1e-9 or np.any(K[2] != (0.0, 0.0, 1.0)) or abs(K[1, 0]) > 0:
        findings.append(Finding("refuse", "camera_matrix", "not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]"))
    k1, k2, p1, p2, k3 = camera.distortion
    for name, key, value in (("k1", "k1", k1), ("k2", "k2", k2), ("p", "p1", p1), ("p", "p2", p2),
                             ("k3", "k3", k3)):
        _judge(findings, name, f"distortion_coefficients.{key}", value)
    if not np.allclose(camera.R, np.eye(3), atol=1e-9):
        findings.append(Finding("warn", "rectification_matrix", "not the identity (a monocular camera's is)"))
    P = camera.projection()
    if P[0, 0] <= 0 or P[1, 1] <= 0 or np.any(P[2] != (0.0, 0.0, 1.0, 0.0)):
        findings.append(Finding("refuse", "projection_matrix", "not a rectified camera [fx' 0 cx' 0; 0 fy' cy' 0; "
                                                               "0 0 1 0]"))
    return findings


def check_homography(H, width_px: int, height_px: int) -> list[Finding]:
    """Plausibility findings for a ground homography (rectified pixels -> ground, H[2][2] = 1)."""
    H = np.asarray(H, dtype=float)
    if abs(H[2, 2] - 1.0) > 1e-9:
        return [Finding("refuse", "homography[8]", f"H[2][2] is {H[2, 2]:.6g}, expected 1")]
    if abs(np.linalg.det(H)) < 1e-15:
        return [Finding("refuse", "homography", "singular: it maps the image to a line")]
    findings = []
    if H[1, 2] > 0:  # Duckietown's own check ("homography could be corrupt"): a board's corner order flipped
        findings.append(Finding("refuse", "homography[5]", f"H[1][2] = {H[1, 2]:.6g} > 0: a corrupt homography "
                                                           "(e.g. a symmetric board's corner order flipped)"))
    bottom = apply_homography(H, [[(width_px - 1) / 2.0, height_px - 1.0]])[0]
    left, right = apply_homography(H, [[0.0, height_px - 1.0], [width_px - 1.0, height_px - 1.0]])
    if not left[1] > right[1]:
        findings.append(Finding("refuse", "homography", "mirrored: the image's left edge is not to the robot's "
                                                        "left on the ground"))
    _judge(findings, "ahead", "homography", float(bottom[0]), what=" m (ground ahead of the axle at the image's "
                                                                   "bottom centre)")
    return findings


def check_calibration(cal: DuckietownCalibration) -> list[Finding]:
    """Every plausibility finding of a calibration (refusals and warnings)."""
    return (check_kinematics(cal.kinematics) + check_camera(cal.camera) +
            check_homography(cal.homography, cal.camera.width_px, cal.camera.height_px))


# ------------------------------------------------------------------------------------------------ writing

def yaml_float(value: float) -> str:
    """A finite float as YAML that PyYAML (YAML 1.1) also reads as a float: always a '.' before any exponent."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"not a finite number: {value!r}")
    text = repr(value)
    if "e" in text and "." not in text.split("e")[0]:
        text = text.replace("e", ".0e")
    return text


def _flow(values) -> str:
    return "[" + ", ".join(yaml_float(v) for v in np.asarray(values, dtype=float).ravel()) + "]"


def _matrix(name: str, values) -> str:
    rows, cols = MATRIX_SHAPES[name]
    return f"{name}:\n  rows: {rows}\n  cols: {cols}\n  data: {_flow(values)}\n"


def kinematics_yaml(kin: Kinematics, calibration_time: str) -> str:
    values = {key: getattr(kin, name) for key, name in KINEMATICS_FIELDS.items()}
    lines = {key: f"{key}: {yaml_float(value)}" for key, value in values.items()}
    lines["calibration_time"] = f"calibration_time: {calibration_time}"
    return "".join(lines[key] + "\n" for key in sorted(lines))  # sorted keys, as Duckietown's saves


def intrinsic_yaml(robot: str, camera: CameraCalibration) -> str:
    return (f"image_width: {int(camera.width_px)}\nimage_height: {int(camera.height_px)}\n"
            f"camera_name: /{robot}/camera_node\n" + _matrix("camera_matrix", camera.K) +
            f"distortion_model: {DISTORTION_MODEL}\n" + _matrix("distortion_coefficients", camera.distortion) +
            _matrix("rectification_matrix", camera.R) + _matrix("projection_matrix", camera.projection()))


def extrinsic_yaml(H, calibration_time: str) -> str:
    return f"homography: {_flow(H)}\n# Calibrated on {calibration_time} by naocal\n"


def default_calibrations_dir() -> Path:
    """Duckietown's calibrations directory: $NAOCAL_DUCKIETOWN_CALIBRATIONS, else /data/config/calibrations."""
    return Path(os.environ.get(CALIBRATIONS_DIR_VARIABLE) or DEFAULT_CALIBRATIONS_DIR)


DEFAULT_ROBOT = "default"  # Duckietown's fallback files (<kind>/default.yaml): what a robot without its own reads


def robots_in(directory) -> list[str]:
    """The robots with a file (<kind>/<robot>.yaml) in the calibrations `directory`, sorted; Duckietown's fallback
    'default' only when no robot has one."""
    directory = Path(directory)
    names = {path.stem for kind in (KINEMATICS_DIR, INTRINSIC_DIR, EXTRINSIC_DIR)
             for path in (directory / kind).glob("*.yaml") if path.is_file()}
    return sorted(names - {DEFAULT_ROBOT} or names)


def calibration_paths(directory, robot: str) -> dict:
    """{'kinematics', 'camera_intrinsic', 'camera_extrinsic'} -> DIR/<kind>/<robot>.yaml (robot name checked)."""
    problem = robot_name_problem(robot)
    if problem:
        raise NaocalError(problem)
    directory = Path(directory)
    return {kind: directory / kind / f"{robot}.yaml" for kind in (KINEMATICS_DIR, INTRINSIC_DIR, EXTRINSIC_DIR)}


def write_calibration(directory, cal: DuckietownCalibration) -> list[Finding]:
    """Write the three files under `directory` (each atomically); return the warnings the caller must show.

    Refused before anything is written (NaocalError, one line): a robot name that cannot be a file name, a value
    beyond any working Duckiebot (check_calibration), an output path that cannot be written."""
    paths = calibration_paths(directory, cal.robot)
    findings = check_calibration(cal)
    refusals = [f for f in findings if f.level == "refuse"]
    if refusals:
        more = f" (and {len(refusals) - 1} more)" if len(refusals) > 1 else ""
        raise NaocalError(f"calibration of {cal.robot} not written: {refusals[0]}{more}")
    stamp = cal.calibration_time or time.strftime("%Y-%m-%d-%H-%M-%S")
    if not CALIBRATION_TIME.fullmatch(stamp):
        raise NaocalError(f"calibration time {stamp[:40]!r} is not YYYY-MM-DD-HH-MM-SS")
    texts = {paths[KINEMATICS_DIR]: kinematics_yaml(cal.kinematics, stamp),
             paths[INTRINSIC_DIR]: intrinsic_yaml(cal.robot, cal.camera),
             paths[EXTRINSIC_DIR]: extrinsic_yaml(cal.homography, stamp)}
    for path in texts:
        check_output_file(path)
    for path, text in texts.items():
        atomic_write_text(path, text)
    return [f for f in findings if f.level == "warn"]


# ------------------------------------------------------------------------------------------------ reading

def _strip_comment(line: str) -> str:
    """The line without a comment ('#' at the start or after a space, outside quotes)."""
    quote = None
    for i, char in enumerate(line):
        if quote:
            if char == quote:
                quote = None
        elif char in "'\"":
            quote = char
        elif char == "#" and (i == 0 or line[i - 1] in " \t"):
            return line[:i].rstrip()
    return line.rstrip()


def _scalar(text: str, path, line: int) -> str:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        inner = text[1:-1]
        if "\\" in inner or (text[0] == "'" and "'" in inner) or (text[0] == '"' and '"' in inner):
            raise DataError(path, "quoted text with escapes is not supported here", line=line)
        return inner
    if text and text[0] in "&*!|>%@`{":
        raise DataError(path, f"unsupported YAML ({text[:20]!r}: anchors, aliases, tags, block text and flow "
                              "mappings are not used by these files)", line=line)
    return text


def parse_simple_yaml(text: str, path) -> dict:
    """The subset of YAML Duckietown's calibration files use, scalars as strings: a top-level mapping whose values
    are scalars, flow lists (over one or more lines), block lists ('- x'), or one level of nested mapping of those.
    DataError naming the file and line for anything else."""
    lines = text.splitlines()
    entries = []  # (line number, indent, content)
    for number, raw in enumerate(lines, 1):
        if "\t" in raw[:len(raw) - len(raw.lstrip())]:
            raise DataError(path, "a tab in the indentation (YAML forbids it)", line=number)
        content = _strip_comment(raw)
        if not content.strip() or (number == 1 and content.strip() == "---"):
            continue
        if content.strip() in ("---", "..."):
            raise DataError(path, "more than one YAML document", line=number)
        entries.append((number, len(content) - len(content.lstrip()), content.strip()))
    position = 0

    def block(indent: int) -> dict:
        nonlocal position
        mapping = {}
        while position < len(entries):
            number, level, content = entries[position]
            if level < indent:
                break
            if level > indent:
                raise DataError(path, "unexpected indentation", line=number)
            if content.startswith("- ") or content == "-":
                raise DataError(path, "a list item where a key was expected", line=number)
            key, sep, rest = content.partition(":")
            key = key.strip()
            if not sep or not key or (rest and not rest.startswith(" ")):
                raise DataError(path, "expected 'key: value'", line=number)
            if key in mapping:
                raise DataError(path, "the same key twice", line=number, field=key)
            position += 1
            rest = rest.strip()
            if rest.startswith("["):
                mapping[key] = flow(rest, number)
            elif rest:
                mapping[key] = _scalar(rest, path, number)
            elif position < len(entries) and entries[position][2].startswith("-") and entries[position][1] >= level:
                mapping[key] = block_list(entries[position][1])
            elif position < len(entries) and entries[position][1] > level:
                if indent > 0:
                    raise DataError(path, "nested deeper than these files ever are", line=entries[position][0])
                mapping[key] = block(entries[position][1])
            else:
                raise DataError(path, "no value", line=number, field=key)
        return mapping

    def flow(rest: str, number: int) -> list:
        nonlocal position
        text = rest
        while "]" not in text:
            if position >= len(entries):
                raise DataError(path, "a list '[' never closed", line=number)
            text += " " + entries[position][2]
            position += 1
        inner, _, after = text[1:].partition("]")
        if after.strip() or "[" in inner:
            raise DataError(path, "unexpected text after a list, or a nested list", line=number)
        items = [item.strip() for item in inner.split(",")]
        if items == [""]:
            return []
        if "" in items:
            raise DataError(path, "an empty list item", line=number)
        return [_scalar(item, path, number) for item in items]

    def block_list(indent: int) -> list:
        nonlocal position
        items = []
        while position < len(entries) and entries[position][1] == indent and entries[position][2].startswith("-"):
            number, _, content = entries[position]
            item = content[1:].strip()
            if not item or item.startswith(("[", "-")) or re.match(r"[^'\"]*:\s", item + " "):
                raise DataError(path, "only plain values are supported in a list", line=number)
            items.append(_scalar(item, path, number))
            position += 1
        return items

    doc = block(0)
    if position < len(entries):
        raise DataError(path, "unexpected indentation", line=entries[position][0])
    if not doc:
        raise DataError(path, "empty file: expected Duckietown's calibration keys")
    return doc


def _refuse_findings(findings, path, strict: bool) -> list[Finding]:
    refusals = [f for f in findings if f.level == "refuse"]
    if strict and refusals:
        raise DataError(path, f"implausible calibration: {refusals[0].message}", field=refusals[0].field)
    return findings


def read_kinematics(path, *, strict: bool = True) -> tuple[Kinematics, str, list[Finding]]:
    """(Kinematics, calibration_time, findings) of a kinematics/<robot>.yaml. DataError for a malformed file and,
    when `strict`, for a value beyond any working Duckiebot."""
    doc = parse_simple_yaml(read_text(path, max_bytes=1 << 16), path)
    fields.json_object(doc, path, "", KINEMATICS_KEYS, KINEMATICS_OPTIONAL_KEYS)
    stamp = doc["calibration_time"]
    if not isinstance(stamp, str) or not CALIBRATION_TIME.fullmatch(stamp):
        raise DataError(path, "expected YYYY-MM-DD-HH-MM-SS", field="calibration_time")
    numbers = {key: fields.number_text(doc[key], path, key) for key in KINEMATICS_KEYS + KINEMATICS_OPTIONAL_KEYS
               if key != "calibration_time" and key in doc}
    try:
        kin = Kinematics(**{name: numbers[key] for key, name in KINEMATICS_FIELDS.items() if key in numbers})
    except DataError as err:  # Kinematics' own check of a field (solver.fields): named by this file's key
        key = next(key for key, name in KINEMATICS_FIELDS.items() if name == err.field)
        raise DataError(path, err.problem, field=key) from None
    return kin, stamp, _refuse_findings(check_kinematics(kin), path, strict)


def read_intrinsic(path, *, strict: bool = True) -> tuple[CameraCalibration, str, list[Finding]]:
    """(CameraCalibration, camera_name, findings) of a camera_intrinsic/<robot>.yaml (plumb_bob)."""
    doc = parse_simple_yaml(read_text(path, max_bytes=1 << 16), path)
    fields.json_object(doc, path, "", INTRINSIC_KEYS, ())
    if doc["distortion_model"] != DISTORTION_MODEL:
        raise DataError(path, f"distortion model {str(doc['distortion_model'])[:40]!r} is not supported (expected "
                              f"{DISTORTION_MODEL}, what Duckietown's rectification uses)", field="distortion_model")
    matrices = {}
    for name, (rows, cols) in MATRIX_SHAPES.items():
        value = doc[name]
        if not isinstance(value, dict):
            raise DataError(path, "expected rows, cols and data", field=name)
        fields.json_object(value, path, name, ("rows", "cols", "data"), ())
        if fields.count_text(value["rows"], path, name + ".rows", 0, 99) != rows or \
                fields.count_text(value["cols"], path, name + ".cols", 0, 99) != cols:
            raise DataError(path, f"expected rows {rows}, cols {cols}", field=name)
        data = fields.vector(value["data"], rows * cols, path, name + ".data", from_text=True)
        matrices[name] = np.array(data).reshape(rows, cols)
    camera_name = fields.text(doc["camera_name"], path, "camera_name")
    camera = CameraCalibration(width_px=fields.count_text(doc["image_width"], path, "image_width", 16, 10000),
                               height_px=fields.count_text(doc["image_height"], path, "image_height", 16, 10000),
                               K=matrices["camera_matrix"], distortion=matrices["distortion_coefficients"].ravel(),
                               R=matrices["rectification_matrix"], P=matrices["projection_matrix"])
    return camera, camera_name, _refuse_findings(check_camera(camera), path, strict)


def read_extrinsic(path, width_px: int = 640, height_px: int = 480, *, strict: bool = True):
    """(H (3, 3), findings) of a camera_extrinsic/<robot>.yaml; the image size judges where the ground is seen."""
    doc = parse_simple_yaml(read_text(path, max_bytes=1 << 16), path)
    fields.json_object(doc, path, "", ("homography",), ())
    H = np.array(fields.vector(doc["homography"], 9, path, "homography", from_text=True)).reshape(3, 3)
    return H, _refuse_findings(check_homography(H, width_px, height_px), path, strict)


def read_calibration(directory, robot: str, *, strict: bool = True) -> tuple[DuckietownCalibration, list[Finding]]:
    """The three files of `robot` under `directory` read back, with every plausibility finding."""
    paths = calibration_paths(directory, robot)
    kin, stamp, k_findings = read_kinematics(paths[KINEMATICS_DIR], strict=strict)
    camera, camera_name, c_findings = read_intrinsic(paths[INTRINSIC_DIR], strict=strict)
    if camera_name != f"/{robot}/camera_node":
        c_findings = c_findings + [Finding("warn", "camera_name", f"{camera_name[:60]!r} is not this robot's "
                                                                  f"(/{robot}/camera_node)")]
    H, h_findings = read_extrinsic(paths[EXTRINSIC_DIR], camera.width_px, camera.height_px, strict=strict)
    return DuckietownCalibration(robot, kin, camera, H, stamp), k_findings + c_findings + h_findings
