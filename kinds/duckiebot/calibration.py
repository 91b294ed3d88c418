"""`naocal.duckiebot_calibration/1`: a Duckiebot's calibration file, as `naocal identify LOG --out CAL.json` (and
`naocal calibrate --robot duckiebot`'s RUN/offsets.json) writes it (docs/DUCKIEBOT.md).

    {"schema": "naocal.duckiebot_calibration/1",
     "robot": {"id"},
     "camera": {"width_px", "height_px", "lens_model": the lens chosen by held-out error,
                "lenses": {MODEL: {"K": 3 x 3, "distortion": [...], "train_rms_px", "held_out_rms_px", "views"}}},
                (plumb_bob always: Duckietown's files hold it)
     "kinematics": {"gain", "trim", "baseline_m", "k", "radius_m", "limit"},
     "parameters": {NAME: {"value", "std", "fixed", "std_parts"}}   the joint fit (kinds.duckiebot.fit), SI; std:
            the cluster-robust std with the considered model errors carried in; std_parts (optional): its parts,
            {"fit": statistical, "lens": the intrinsics', "corner_window": the detector's corner error} (fit.STD_PARTS;
            std is their root sum of squares)
     "fit": {"rms_px", "corners", "outliers", "reference_marker", "converged", "warnings", "pwm_driver"},
            (pwm_driver: fitted through Duckietown's wheel driver, identify --effects pwm_driver; absent: false)
     "source", "created"}

`parameters` is the file's truth: `kinematics` repeats gain, trim and baseline_m from it (for people and other
programs) and must agree; the camera's pose on the body is parameters' camera.*. The reader is strict: every
problem is one DataError naming the file and the field, and a calibration beyond any working Duckiebot
(calibration_files.check_calibration on the Duckietown files it would export) is refused. The writer validates the
document with the same reader before writing it atomically: it never writes what the reader would refuse.
"""

from __future__ import annotations

import json
import math
import re
import time
from dataclasses import dataclass, replace

import numpy as np

from naocal.kinds.duckiebot.calibration_files import DuckietownCalibration, Finding, check_calibration, \
    duckietown_calibration
from naocal.kinds.duckiebot.fit import (ANCHOR, BIAS, CAMERA, EFFECTS, KINEMATIC, SEGMENT_ANCHOR, STD_PARTS,
                                        camera_transform)
from naocal.kinds.duckiebot.intrinsics import LENS_MODELS, LensCamera
from naocal.kinds.duckiebot.robot import Kinematics, robot_name_problem
from naocal.solver.camera import CameraIntrinsics
from naocal.solver import fields
from naocal.solver.errors import DataError, SolveError
from naocal.solver.fields import fail
from naocal.solver.fileio import atomic_write_text, check_output_file, read_json

SCHEMA = "naocal.duckiebot_calibration/1"
DUCKIETOWN_LENS = "plumb_bob"  # the lens model Duckietown's camera_intrinsic file holds
DISTORTION_SIZES = {"plumb_bob": (5,), "rational": (8, 12, 14), "fisheye": (4,)}  # OpenCV's coefficient counts
MARKER_PARAMETER = re.compile(r"marker\d{1,9}\.(x_m|y_m|yaw_rad)")
REQUIRED_PARAMETERS = KINEMATIC + CAMERA
# the base model's and every optional wheel effect's (fit.EFFECTS, the registry's drive effects: identify --effects)
KNOWN_PARAMETERS = KINEMATIC + CAMERA + ANCHOR + (BIAS,) + tuple(n for names in EFFECTS.values() for n in names)
MAX_PARAMETER_SIZE = 1e3  # SI: metres, radians, gain; a marker 1 km away is a damaged file
MAX_PIXELS = 1e5
MAX_TEXT = 1000  # characters of a line of text
# The kinematics section repeats parameters' values; written from the same floats, so they agree to rounding.
AGREEMENT = 1e-9


@dataclass(frozen=True)
class CalibrationFile:
    """A Duckiebot calibration file read and checked. `findings`: the plausibility warnings to show (refusals raise)."""

    path: str
    robot_id: str
    width_px: int
    height_px: int
    lens_model: str
    lenses: dict  # model -> LensCamera
    lens_errors: dict  # model -> {"train_rms_px", "held_out_rms_px", "views"}
    kinematics: Kinematics
    parameters: dict  # name -> {"value", "std", "fixed"} (SI)
    fit: dict
    source: str
    created: str
    findings: tuple = ()

    def value(self, name: str) -> float:
        return self.parameters[name]["value"]

    def std(self, name: str) -> float:
        return self.parameters[name]["std"]

    @property
    def T_base_camera(self) -> np.ndarray:
        return camera_transform(np.array([self.value(n) for n in CAMERA]))

    @property
    def lens(self) -> LensCamera:
        return self.lenses[self.lens_model]

    @property
    def pwm_driver(self) -> bool:
        """Fitted through Duckietown's wheel driver (fit.PWM_DRIVER): a refit of it (verify, refine) must be too."""
        return bool(self.fit.get("pwm_driver", False))

    def duckietown(self, calibration_time: str = "") -> DuckietownCalibration:
        """Duckietown's three files' content (calibration_files.write_calibration writes them)."""
        return duckietown_calibration(self.robot_id, self.kinematics, plumb_bob_intrinsics(
            self.lenses[DUCKIETOWN_LENS], self.width_px, self.height_px), self.T_base_camera, calibration_time)


def plumb_bob_intrinsics(camera: LensCamera, width_px: int, height_px: int) -> CameraIntrinsics:
    K = camera.K
    return CameraIntrinsics(width_px, height_px, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                            tuple(float(d) for d in camera.distortion[:5]))


# ------------------------------------------------------------------------------------------------ writing

def calibration_document(calibration, *, width_px: int = 640, height_px: int = 480, source: str = "") -> dict:
    """The file's JSON document of a kinds.duckiebot.identify.DuckiebotCalibration (its camera's image size given:
    the calibration does not hold it)."""
    fit = calibration.drive_fit
    kin = calibration.kinematics
    parts = fit.std_parts() if fit.considered else {}
    return {
        "schema": SCHEMA,
        "robot": {"id": calibration.robot_id},
        "camera": {"width_px": int(width_px), "height_px": int(height_px),
                   "lens_model": calibration.lens.camera.model,
                   "lenses": {model: {"K": np.asarray(f.camera.K, float).tolist(),
                                      "distortion": np.asarray(f.camera.distortion, float).ravel().tolist(),
                                      "train_rms_px": float(f.train_rms_px),
                                      # inf (the model could not be judged) as null: JSON has no inf
                                      "held_out_rms_px": float(f.held_out_rms_px) if math.isfinite(
                                          f.held_out_rms_px) else None, "views": int(f.n_views)}
                              for model, f in calibration.lens_fits.items()}},
        "kinematics": {"gain": kin.gain, "trim": kin.trim, "baseline_m": kin.baseline_m, "k": kin.k,
                       "radius_m": kin.radius_m, "limit": kin.limit},
        "parameters": {n: {"value": float(v), "std": float(s), "fixed": not bool(free),
                           **({"std_parts": {part: float(stds[i]) for part, stds in parts.items()}} if free and parts else {})}
                       for i, (n, v, s, free) in enumerate(zip(fit.names, fit.x, fit.std, fit.free))},
        "fit": {"rms_px": float(fit.rms_px), "corners": int(len(fit.sightings.frame)),
                "outliers": int(len(fit.outliers.frame)), "reference_marker": int(fit.reference_marker),
                "converged": bool(fit.success), "warnings": [str(w) for w in fit.warnings],
                "pwm_driver": bool(fit.pwm_driver)},
        "source": source or "naocal identify",
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def checked_document(calibration, where, *, width_px: int = 640, height_px: int = 480,
                     source: str = "") -> tuple[dict, CalibrationFile]:
    """(document, what the reader makes of it) of a DuckiebotCalibration, to be written to `where`. SolveError (exit
    3: the fit's result is at fault), in one line, for a calibration the reader would refuse: a value beyond any
    working Duckiebot, a non-finite value or std."""
    doc = calibration_document(calibration, width_px=width_px, height_px=height_px, source=source)
    return doc, check_document(doc, where)


def check_document(doc: dict, where) -> CalibrationFile:
    """What the reader makes of a document naocal made (to be written to `where`); SolveError (exit 3: the result
    is at fault, not an input), in one line, for one the reader would refuse."""
    try:  # through JSON, as the reader will see it (a NaN or inf is refused there)
        return parse_calibration(json.loads(json.dumps(doc)), where)
    except DataError as err:
        raise SolveError(f"calibration not written to {where}: {err.problem}"
                         + (f" (field '{err.field}')" if err.field else "")) from None


def write_document(path, doc: dict, *, inputs=()) -> None:
    """Write a checked document (checked_document) to `path` atomically, never over one of `inputs` (DataError)."""
    check_output_file(path, inputs=inputs)
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")


def write_calibration_file(path, calibration, *, width_px: int = 640, height_px: int = 480, source: str = "",
                           inputs=()) -> list[Finding]:
    """Write `calibration` (a DuckiebotCalibration) to `path` atomically; return the plausibility warnings the caller
    must show. Nothing is written for a calibration the reader would refuse (checked_document) or a path that
    cannot be written or is one of `inputs`."""
    doc, result = checked_document(calibration, path, width_px=width_px, height_px=height_px, source=source)
    write_document(path, doc, inputs=inputs)
    return list(result.findings)


# ------------------------------------------------------------------------------------------------ reading

def _matrix(value, path, field, rows, cols=None):
    """`rows` lists of `cols` numbers, or (`cols` None) a list of any of the lengths `rows`; pixel-sized."""
    if cols is None:
        return np.array(fields.vector(value, rows, path, field, limit=MAX_PIXELS, unit="px"))
    if not isinstance(value, list) or len(value) != rows:
        fail(path, f"expected {rows} rows of {cols} numbers, got {fields.shown(value)}", field)
    return np.array([fields.vector(row, cols, path, f"{field}[{i}]", limit=MAX_PIXELS, unit="px")
                     for i, row in enumerate(value)])


def _lens(value, model, path, field):
    lens = fields.json_object(value, path, field, ("K", "distortion", "train_rms_px", "held_out_rms_px", "views"), ())
    K = _matrix(lens["K"], path, f"{field}.K", 3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[0, 1] != 0 or np.any(K[1:, 0] != 0) or K[2, 1] != 0 or K[2, 2] != 1:
        fail(path, "not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]", f"{field}.K")
    distortion = _matrix(lens["distortion"], path, f"{field}.distortion", DISTORTION_SIZES[model])
    held_out = lens["held_out_rms_px"]  # null: the model could not be judged (inf)
    errors = {"train_rms_px": fields.number(lens["train_rms_px"], path, f"{field}.train_rms_px", limit=MAX_PIXELS,
                                            unit="px"),
              "held_out_rms_px": math.inf if held_out is None else
              fields.number(held_out, path, f"{field}.held_out_rms_px", limit=MAX_PIXELS, unit="px"),
              "views": fields.count(lens["views"], path, f"{field}.views", 1)}
    return LensCamera(model, K, distortion), errors


def _parameters(value, path) -> dict:
    parameters = {}
    for name, entry in fields.json_object(value, path, "parameters").items():
        field = f"parameters.{name}"
        if name not in KNOWN_PARAMETERS and not MARKER_PARAMETER.fullmatch(name) and not SEGMENT_ANCHOR.fullmatch(name):
            fail(path, "unknown parameter (expected the joint fit's: gain, trim, baseline_m, camera.*, anchor.*, "
                 "anchor<segment>.*, "
                 f"{BIAS}, marker<id>.*, or an effect's: {', '.join(n for e in EFFECTS.values() for n in e)})",
                  field)
        entry = fields.json_object(entry, path, field, ("value", "std", "fixed"), ("std_parts",))
        parameters[name] = {"value": fields.number(entry["value"], path, f"{field}.value", limit=MAX_PARAMETER_SIZE),
                            "std": fields.number(entry["std"], path, f"{field}.std", limit=MAX_PARAMETER_SIZE,
                                                 non_negative=True),
                            "fixed": fields.flag(entry["fixed"], path, f"{field}.fixed")}
        if "std_parts" in entry:
            parameters[name]["std_parts"] = _std_parts(entry["std_parts"], parameters[name]["std"], path,
                                                       f"{field}.std_parts")
    for name in REQUIRED_PARAMETERS:
        if name not in parameters:
            fail(path, "missing parameter", f"parameters.{name}")
    return parameters


def _std_parts(value, std: float, path, field) -> dict:
    """A parameter's std_parts (fit.STD_PARTS' names, each a std) checked: their root sum of squares is its std."""
    parts = {part: fields.number(v, path, f"{field}.{part}", limit=MAX_PARAMETER_SIZE, non_negative=True)
             for part, v in fields.json_object(value, path, field, (STD_PARTS[0],), STD_PARTS[1:]).items()}
    total = math.sqrt(sum(v ** 2 for v in parts.values()))
    if abs(total - std) > 1e-6 * std + 1e-12:
        fail(path, f"the parts' root sum of squares is {total:.6g}, not the std {std:.6g}", field)
    return parts


def parse_calibration(doc, path, *, strict: bool = True) -> CalibrationFile:
    """The document `doc` of the file `path` checked (module docstring). DataError naming the field; with `strict`,
    also for a calibration beyond any working Duckiebot."""
    fields.json_object(doc, path, "", ("schema", "robot", "camera", "kinematics", "parameters", "fit", "source",
                                       "created"), ())
    if doc["schema"] != SCHEMA:
        fail(path, f"expected {SCHEMA!r}, got {str(doc['schema'])[:40]!r}", "schema")
    robot = fields.json_object(doc["robot"], path, "robot", ("id",), ())
    problem = robot_name_problem(robot["id"])
    if problem:
        fail(path, problem, "robot.id")
    camera = fields.json_object(doc["camera"], path, "camera", ("width_px", "height_px", "lens_model", "lenses"), ())
    width = fields.count(camera["width_px"], path, "camera.width_px", 16, 10000)
    height = fields.count(camera["height_px"], path, "camera.height_px", 16, 10000)
    lenses = fields.json_object(camera["lenses"], path, "camera.lenses", (DUCKIETOWN_LENS,), LENS_MODELS[1:])
    fitted = {m: _lens(lenses[m], m, path, f"camera.lenses.{m}") for m in LENS_MODELS if m in lenses}
    if camera["lens_model"] not in fitted:
        fail(path, f"{str(camera['lens_model'])[:40]!r} is not one of the lenses given ({', '.join(fitted)})",
             "camera.lens_model")
    parameters = _parameters(doc["parameters"], path)
    fit = fields.json_object(doc["fit"], path, "fit", ("rms_px", "corners", "outliers", "reference_marker", "converged",
                                                       "warnings"), ("pwm_driver",))
    fields.number(fit["rms_px"], path, "fit.rms_px", limit=MAX_PIXELS, unit="px")
    for key in ("corners", "outliers", "reference_marker"):
        fields.count(fit[key], path, f"fit.{key}")
    for key in ("converged", "pwm_driver"):
        if key in fit:
            fields.flag(fit[key], path, f"fit.{key}")
    if not isinstance(fit["warnings"], list):
        fail(path, f"expected a list of text, got {fields.shown(fit['warnings'])}", "fit.warnings")
    for i, warning in enumerate(fit["warnings"]):
        fields.text(warning, path, f"fit.warnings[{i}]", max_chars=MAX_TEXT)
    section = fields.json_object(doc["kinematics"], path, "kinematics",
                                 ("gain", "trim", "baseline_m", "k", "radius_m", "limit"), ())
    numbers = {key: fields.number(v, path, f"kinematics.{key}", limit=MAX_PARAMETER_SIZE) for key, v in section.items()}
    for name in KINEMATIC:
        if name == "gain" and ("dead_zone" in parameters or fit.get("pwm_driver")):
            # kinematics.gain is then the secant at the drive speed (fit.secant_gain: the dead zone and the driver's
            # floor folded in), parameters.gain the slope
            continue
        if abs(numbers[name] - parameters[name]["value"]) > AGREEMENT * max(1.0, abs(numbers[name])):
            fail(path, f"{numbers[name]!r} disagrees with parameters.{name} ({parameters[name]['value']!r})",
                 f"kinematics.{name}")
    try:
        kinematics = Kinematics(**numbers)
    except DataError as err:  # Kinematics' own check of a field (solver.fields): named as this file's
        fail(path, err.problem, f"kinematics.{err.field}")
    result = CalibrationFile(str(path), robot["id"], width, height, camera["lens_model"],
                             {m: lens for m, (lens, _) in fitted.items()},
                             {m: errors for m, (_, errors) in fitted.items()}, kinematics, parameters, fit,
                             fields.text(doc["source"], path, "source", max_chars=MAX_TEXT),
                             fields.text(doc["created"], path, "created", max_chars=40))
    try:
        findings = check_calibration(result.duckietown())
    except ValueError as err:  # e.g. a camera pose that sees no floor: no homography
        fail(path, f"no Duckietown calibration follows from it: {err}", "parameters")
    refusals = [f for f in findings if f.level == "refuse"]
    if strict and refusals:
        fail(path, f"implausible calibration: {refusals[0]}", file_field(refusals[0].field))
    return replace(result, findings=tuple(findings))


def file_field(duckietown_field: str) -> str:
    """The field of this file a finding on Duckietown's files (calibration_files.check_calibration) comes from."""
    for prefix, field in (("camera_matrix", f"camera.lenses.{DUCKIETOWN_LENS}.K"),
                          ("distortion_coefficients", f"camera.lenses.{DUCKIETOWN_LENS}.distortion"),
                          ("homography", "parameters.camera"),  # the homography follows from the camera's pose
                          ("kinematics", "kinematics")):
        if duckietown_field.startswith(prefix):
            return field + duckietown_field[len(prefix):] if prefix == "kinematics" else field
    return duckietown_field


def from_duckietown(files: DuckietownCalibration, where: str, findings=()) -> CalibrationFile:
    """Duckietown's three files (calibration_files.read_calibration) as the calibration naocal's verbs use: the
    kinematics as they are, the plumb_bob lens, the camera's pose on the body recovered from the homography
    (calibration_files.camera_pose_from_homography). What the files do not hold is absent: no stds (0, every value
    fixed), no lens errors, no fit (rms_px None), not fitted through Duckietown's wheel driver (pwm_driver false).
    DataError naming the extrinsic file when no camera pose gives its homography."""
    from naocal.kinds.duckiebot.calibration_files import EXTRINSIC_DIR, calibration_paths, camera_pose_from_homography
    from naocal.kinds.duckiebot.fit import pose_parameters

    camera = files.camera
    try:
        pose = pose_parameters(camera_pose_from_homography(files.homography, camera.projection(), camera.R))
    except ValueError as err:
        raise DataError(calibration_paths(where, files.robot)[EXTRINSIC_DIR], f"no camera pose on the body follows "
                        f"from it: {err}", field="homography") from None
    kin = files.kinematics
    values = {"gain": kin.gain, "trim": kin.trim, "baseline_m": kin.baseline_m, **dict(zip(CAMERA, pose))}
    return CalibrationFile(str(where), files.robot, camera.width_px, camera.height_px, DUCKIETOWN_LENS,
                           {DUCKIETOWN_LENS: LensCamera(DUCKIETOWN_LENS, camera.K, camera.distortion)}, {}, kin,
                           {n: {"value": float(v), "std": 0.0, "fixed": True} for n, v in values.items()},
                           {"rms_px": None, "pwm_driver": False}, "Duckietown's calibration files",
                           files.calibration_time, tuple(findings))


def read_calibration_file(path, *, strict: bool = True) -> CalibrationFile:
    """The Duckiebot calibration file at `path`, checked (parse_calibration). DataError naming the file and field."""
    return parse_calibration(read_json(path), path, strict=strict)

