"""The `naocal.offsets/1` file: a robot's calibration result, as robot code and the tools use it.

Sign convention (the one of B-Human, HULKs and the paper): a stored joint offset `c` is ADDED to every commanded
angle and SUBTRACTED from every measured angle. The model says q_true = theta_measured + alpha, so c = -alpha.
`camera_rotation_rad` and `board_mount` hold the model's alphas as they are (Eq. 3 and Eq. 4).
Build files from model alphas with `offsets_from_alpha` or `offsets_from_parameters`, never by hand-negating.

Body results (joint offsets, board mount) and head results (camera rotation) are kept apart so that they can be
reused when heads and bodies are swapped between robots.
"""

from __future__ import annotations

import copy
import datetime as dt
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from solver.dataset import find_non_finite, parse_json_text, read_text
from solver.errors import DataError
from solver.fileio import atomic_write_text
from solver.joints import HEAD_JOINTS, JOINTS, LEG_JOINTS, LEGS

SCHEMA = "naocal.offsets/1"
BACKUP_SUFFIX = ".bak"

# Plausible sizes: anything beyond is a damaged file, a unit mix-up (degrees written as radians) or a broken robot.
MAX_JOINT_OFFSET_RAD = math.radians(20.0)  # real robots: HipYawPitch up to 11.5 deg (HULKs body configs)
MAX_CAMERA_ROTATION_RAD = math.radians(15.0)
MAX_BOARD_TRANS_M = 0.03
MAX_BOARD_ROT_Z_RAD = math.radians(15.0)

OFFSET_JOINTS = LEG_JOINTS + HEAD_JOINTS  # the order joint_offsets_rad is written in; the 12 leg joints are required
CAMERA_ANGLES = ("roll", "pitch", "yaw")
CAMERAS = ("bottom", "top")  # bottom is required; top is accepted for completeness
BOARD_KEYS = ("rot_z_rad", "trans_x_m", "trans_y_m")
BOARD_LIMITS = {"rot_z_rad": MAX_BOARD_ROT_Z_RAD, "trans_x_m": MAX_BOARD_TRANS_M, "trans_y_m": MAX_BOARD_TRANS_M}
TOP_LEVEL_KEYS = ("schema", "robot", "created", "joint_offsets_rad", "camera_rotation_rad", "board_mount", "model",
                  "fit", "source")
ROBOT_KEYS = ("id", "body_id", "head_id")
PARAMETER_KEYS = ("value", "std", "unit")
PARAMETER_UNITS = ("rad", "m", "px", "s", "rad/(N m)", "1")

# Model parameter names of the registry (solver/registry.py): group -> (unit, allowed members).
# A member of None means "any identifier" (e.g. link_length.L.thigh).
_JOINT_GROUPS = {"joint_offset": "rad", "elasticity": "rad/(N m)", "backlash": "rad"}
_SIMPLE_GROUPS = {
    "head_offset": ("rad", HEAD_JOINTS),
    "camera": ("rad", CAMERA_ANGLES),
    "intrinsics": ("px", ("fx", "fy", "cx", "cy")),
    "distortion": ("1", ("k1", "k2", "p1", "p2", "k3")),
    "time_lag": ("s", ("dt",)),
}
_BOARD_MEMBERS = {"rot_z": "rad", "trans_x": "m", "trans_y": "m"}
_IDENTIFIER = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def parameter_unit(name: str) -> str:
    """The unit a model parameter of this name must carry; ValueError for names outside the registry's scheme."""
    parts = name.split(".")
    group = parts[0]
    if group in _JOINT_GROUPS and len(parts) == 2:
        if parts[1] not in JOINTS:
            raise ValueError(f"unknown joint {parts[1]!r}")
        return _JOINT_GROUPS[group]
    if group in _SIMPLE_GROUPS and len(parts) == 2:
        unit, members = _SIMPLE_GROUPS[group]
        if parts[1] not in members:
            raise ValueError(f"unknown {group} parameter {parts[1]!r} (expected one of {', '.join(members)})")
        return unit
    if group in ("board", "link_length") and len(parts) == 3:
        if parts[1] not in LEGS:
            raise ValueError(f"unknown leg {parts[1]!r} (expected L or R)")
        if group == "board":
            if parts[2] not in _BOARD_MEMBERS:
                raise ValueError(f"unknown board parameter {parts[2]!r}")
            return _BOARD_MEMBERS[parts[2]]
        if not _IDENTIFIER.match(parts[2]):
            raise ValueError(f"bad link name {parts[2]!r}")
        return "m"
    known = sorted(set(_JOINT_GROUPS) | set(_SIMPLE_GROUPS) | {"board", "link_length"})
    raise ValueError(f"unknown model parameter name (groups: {', '.join(known)})")


@dataclass
class Offsets:
    """A `naocal.offsets/1` document. Angles in rad, lengths in m.

    joint_offsets_rad : {joint: c}, c added to commands and subtracted from readings (c = -alpha).
    camera_rotation_rad : {"bottom": {"roll", "pitch", "yaw"}}, the model's alpha of Eq. 3.
    board_mount : {"L"/"R": {"rot_z_rad", "trans_x_m", "trans_y_m"}}, the model's alpha of Eq. 4.
    model : {"effects": [str], "parameters": {name: {"value", "std", "unit"}}} (values are model values: alphas).
    fit : {"rms_px": [x, y], "n_vertices": int, "n_images": int, ...}.
    """

    robot: dict
    created: str
    joint_offsets_rad: dict
    camera_rotation_rad: dict
    board_mount: dict
    fit: dict
    model: dict = field(default_factory=lambda: {"effects": [], "parameters": {}})
    source: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The JSON document, keys in their canonical order."""
        return {
            "schema": SCHEMA,
            "robot": {k: self.robot.get(k) for k in ROBOT_KEYS},
            "created": self.created,
            "joint_offsets_rad": {j: self.joint_offsets_rad[j] for j in OFFSET_JOINTS if j in self.joint_offsets_rad},
            "camera_rotation_rad": {cam: {a: self.camera_rotation_rad[cam][a] for a in CAMERA_ANGLES}
                                    for cam in CAMERAS if cam in self.camera_rotation_rad},
            "board_mount": {leg: {k: self.board_mount[leg][k] for k in BOARD_KEYS} for leg in LEGS},
            "model": copy.deepcopy(self.model),
            "fit": copy.deepcopy(self.fit),
            "source": copy.deepcopy(self.source),
        }

    @classmethod
    def from_dict(cls, doc, path="<offsets>") -> Offsets:
        """Validate a JSON document (see `validate`) and build the Offsets."""
        return cls(**_validated_fields(doc, path))

    def joint_offset(self, joint: str) -> float:
        """c of `joint`, 0.0 for a joint the file does not calibrate."""
        return float(self.joint_offsets_rad.get(joint, 0.0))

    def parameter(self, name: str) -> dict | None:
        """model.parameters[name] ({"value", "std", "unit"}) or None."""
        return self.model.get("parameters", {}).get(name)

    def std(self, name: str) -> float | None:
        entry = self.parameter(name)
        return None if entry is None else float(entry["std"])

    def camera_rpy(self, camera: str = "bottom") -> tuple[float, float, float]:
        """(alpha_roll, alpha_pitch, alpha_yaw) of the camera, rad (zeros if absent)."""
        angles = self.camera_rotation_rad.get(camera, {})
        return tuple(float(angles.get(a, 0.0)) for a in CAMERA_ANGLES)


# --------------------------------------------------------------------------------------------- validation


def _fail(path, problem, field_path):
    raise DataError(path, problem, field=field_path)


def _object(value, path, where) -> dict:
    if not isinstance(value, dict):
        _fail(path, f"expected a JSON object, got {json.dumps(value)[:40]}", where)
    return value


def _keys(obj: dict, required, optional, path, where):
    for key in obj:
        if key not in required and key not in optional:
            _fail(path, f"unknown field (expected {', '.join(list(required) + list(optional))})",
                  f"{where}.{key}" if where else key)
    for key in required:
        if key not in obj:
            _fail(path, "missing required field", f"{where}.{key}" if where else key)


def _number(value, path, where, *, limit=None, unit="rad", non_negative=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _fail(path, f"expected a number, got {json.dumps(value)[:40]}", where)
    value = float(value)
    if not math.isfinite(value):
        _fail(path, "non-finite value (NaN or infinity)", where)
    if non_negative and value < 0:
        _fail(path, f"must not be negative, got {value!r}", where)
    if limit is not None and abs(value) > limit:
        if unit == "rad":
            _fail(path, f"implausible size {math.degrees(value):.3f} deg (limit +-{math.degrees(limit):g} deg); "
                        "is it in degrees instead of radians?", where)
        _fail(path, f"implausible size {value:g} m (limit +-{limit:g} m); is it in mm instead of m?", where)
    return value


def _integer(value, path, where) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if not (isinstance(value, float) and value.is_integer()):
            _fail(path, f"expected a non-negative integer, got {json.dumps(value)[:40]}", where)
    if value < 0:
        _fail(path, f"expected a non-negative integer, got {value}", where)
    return int(value)


def _created(value, path) -> str:
    if not isinstance(value, str):
        _fail(path, "expected an ISO-8601 UTC time string", "created")
    try:
        when = dt.datetime.fromisoformat(value)
    except ValueError:
        _fail(path, f"not an ISO-8601 time: {value!r}", "created")
    if when.utcoffset() not in (None, dt.timedelta(0)):
        _fail(path, f"expected a UTC time, got offset {when.utcoffset()}", "created")
    return value


def _validated_fields(doc, path) -> dict:
    doc = _object(doc, path, "(top level)")
    if "schema" not in doc:
        _fail(path, "missing required field", "schema")
    if doc["schema"] != SCHEMA:
        _fail(path, f"wrong schema {doc['schema']!r}, expected {SCHEMA!r}", "schema")
    bad = find_non_finite(doc)
    if bad:
        _fail(path, "non-finite value (NaN or infinity)", bad)
    _keys(doc, TOP_LEVEL_KEYS, (), path, "")

    robot = _object(doc["robot"], path, "robot")
    _keys(robot, ROBOT_KEYS, (), path, "robot")
    for key in ROBOT_KEYS:
        if robot[key] is not None and not isinstance(robot[key], str):
            _fail(path, "expected a string (or null when unknown)", f"robot.{key}")

    joints = _object(doc["joint_offsets_rad"], path, "joint_offsets_rad")
    for joint in joints:
        if joint not in OFFSET_JOINTS:
            _fail(path, "unknown joint name (allowed: the 12 leg joints, HeadYaw, HeadPitch)",
                  f"joint_offsets_rad.{joint}")
    _keys(joints, LEG_JOINTS, HEAD_JOINTS, path, "joint_offsets_rad")
    joint_offsets = {j: _number(joints[j], path, f"joint_offsets_rad.{j}", limit=MAX_JOINT_OFFSET_RAD)
                     for j in OFFSET_JOINTS if j in joints}

    cameras = _object(doc["camera_rotation_rad"], path, "camera_rotation_rad")
    _keys(cameras, ("bottom",), ("top",), path, "camera_rotation_rad")
    camera_rotation = {}
    for cam in CAMERAS:
        if cam in cameras:
            where = f"camera_rotation_rad.{cam}"
            angles = _object(cameras[cam], path, where)
            _keys(angles, CAMERA_ANGLES, (), path, where)
            camera_rotation[cam] = {a: _number(angles[a], path, f"{where}.{a}", limit=MAX_CAMERA_ROTATION_RAD)
                                    for a in CAMERA_ANGLES}

    boards = _object(doc["board_mount"], path, "board_mount")
    _keys(boards, LEGS, (), path, "board_mount")
    board_mount = {}
    for leg in LEGS:
        where = f"board_mount.{leg}"
        mount = _object(boards[leg], path, where)
        _keys(mount, BOARD_KEYS, (), path, where)
        board_mount[leg] = {k: _number(mount[k], path, f"{where}.{k}", limit=BOARD_LIMITS[k],
                                       unit="rad" if k.endswith("_rad") else "m") for k in BOARD_KEYS}

    return {
        "robot": dict(robot),
        "created": _created(doc["created"], path),
        "joint_offsets_rad": joint_offsets,
        "camera_rotation_rad": camera_rotation,
        "board_mount": board_mount,
        "model": _validated_model(doc["model"], path),
        "fit": _validated_fit(doc["fit"], path),
        "source": copy.deepcopy(_object(doc["source"], path, "source")),
    }


def _validated_model(model, path) -> dict:
    model = _object(model, path, "model")
    _keys(model, ("effects", "parameters"), (), path, "model")
    effects = model["effects"]
    if not isinstance(effects, list) or not all(isinstance(e, str) and e for e in effects):
        _fail(path, "expected a list of effect names", "model.effects")
    if len(set(effects)) != len(effects):
        _fail(path, "an effect is listed twice", "model.effects")
    parameters = _object(model["parameters"], path, "model.parameters")
    checked = {}
    for name, entry in parameters.items():
        where = f"model.parameters.{name}"
        try:
            expected_unit = parameter_unit(name)
        except ValueError as err:
            _fail(path, str(err), where)
        entry = _object(entry, path, where)
        _keys(entry, PARAMETER_KEYS, (), path, where)
        unit = entry["unit"]
        if unit not in PARAMETER_UNITS:
            _fail(path, f"unknown unit {unit!r} (allowed: {', '.join(repr(u) for u in PARAMETER_UNITS)})",
                  f"{where}.unit")
        if unit != expected_unit:
            _fail(path, f"wrong unit {unit!r}, {name} is in {expected_unit!r}", f"{where}.unit")
        checked[name] = {"value": _number(entry["value"], path, f"{where}.value"),
                         "std": _number(entry["std"], path, f"{where}.std", non_negative=True),
                         "unit": unit}
    return {"effects": list(effects), "parameters": checked}


def _validated_fit(fit, path) -> dict:
    fit = copy.deepcopy(_object(fit, path, "fit"))
    for key in ("rms_px", "n_vertices", "n_images"):
        if key not in fit:
            _fail(path, "missing required field", f"fit.{key}")
    rms = fit["rms_px"]
    if not isinstance(rms, list) or len(rms) != 2:
        _fail(path, "expected [rms_x, rms_y] in px", "fit.rms_px")
    fit["rms_px"] = [_number(v, path, f"fit.rms_px[{i}]", non_negative=True) for i, v in enumerate(rms)]
    fit["n_vertices"] = _integer(fit["n_vertices"], path, "fit.n_vertices")
    fit["n_images"] = _integer(fit["n_images"], path, "fit.n_images")
    return fit


def validate(doc, path="<offsets>") -> None:
    """Raise DataError (naming the field path, e.g. joint_offsets_rad.LHipPitch) if `doc` is not a valid file."""
    _validated_fields(doc, path)


# ------------------------------------------------------------------------------------------ read / write


def read_offsets(path) -> Offsets:
    """Read and validate a `naocal.offsets/1` file."""
    return Offsets.from_dict(parse_json_text(read_text(path), path), path)


def format_offsets(offsets: Offsets) -> str:
    """The file's text: validated, canonical key order, floats as repr (exact round trip)."""
    doc = offsets.to_dict()
    validate(doc, "<offsets being written>")
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def write_offsets(offsets: Offsets, path, backup: bool = True) -> Path:
    """Validate and write atomically; with `backup`, an existing file is kept as `<name>.bak`."""
    text = format_offsets(offsets)
    return atomic_write_text(path, text, backup_suffix=BACKUP_SUFFIX if backup else None)


def utc_now_iso() -> str:
    return dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z")


# ------------------------------------------------------------------------------- building from the model


def _rpy_dict(camera_rpy) -> dict:
    if isinstance(camera_rpy, dict):
        return {a: float(camera_rpy[a]) for a in CAMERA_ANGLES}
    roll, pitch, yaw = camera_rpy
    return {"roll": float(roll), "pitch": float(pitch), "yaw": float(yaw)}


def _mount_dict(mount) -> dict:
    if isinstance(mount, dict):
        return {k: float(mount[k]) for k in BOARD_KEYS}
    rot_z, trans_x, trans_y = mount
    return {"rot_z_rad": float(rot_z), "trans_x_m": float(trans_x), "trans_y_m": float(trans_y)}


def offsets_from_alpha(alpha_joints: dict, camera_rpy, board_mount: dict, *, robot: dict, fit: dict,
                       model: dict | None = None, source: dict | None = None, created: str | None = None,
                       top_camera_rpy=None) -> Offsets:
    """Build an Offsets from the model's alphas (q_true = theta + alpha), doing the sign flip c = -alpha here.

    Parameters
    ----------
    alpha_joints : {joint: alpha} in rad for all 12 leg joints (RHipYawPitch may be left out: it then follows
        LHipYawPitch, both being one motor), optionally HeadYaw and HeadPitch.
    camera_rpy : (alpha_roll, alpha_pitch, alpha_yaw) in rad, or a dict with those keys (Eq. 3).
    board_mount : {"L": (alpha_rotz rad, alpha_x m, alpha_y m), "R": ...} or dicts with the file's keys (Eq. 4).
    robot : {"id", "body_id", "head_id"}; fit : {"rms_px": [x, y], "n_vertices", "n_images"}.
    """
    alpha = dict(alpha_joints)
    if "RHipYawPitch" not in alpha and "LHipYawPitch" in alpha:
        alpha["RHipYawPitch"] = alpha["LHipYawPitch"]
    missing = [j for j in LEG_JOINTS if j not in alpha]
    if missing:
        raise ValueError(f"alpha_joints lacks {', '.join(missing)} (pass 0.0 for joints the model keeps nominal)")
    unknown = [j for j in alpha if j not in OFFSET_JOINTS]
    if unknown:
        raise ValueError(f"alpha_joints has unknown joints {', '.join(unknown)}")
    cameras = {"bottom": _rpy_dict(camera_rpy)}
    if top_camera_rpy is not None:
        cameras["top"] = _rpy_dict(top_camera_rpy)
    return Offsets(
        robot={k: robot.get(k) for k in ROBOT_KEYS},
        created=created or utc_now_iso(),
        joint_offsets_rad={j: -float(alpha[j]) for j in OFFSET_JOINTS if j in alpha},  # c = -alpha
        camera_rotation_rad=cameras,
        board_mount={leg: _mount_dict(board_mount[leg]) for leg in LEGS},
        fit=copy.deepcopy(fit),
        model=copy.deepcopy(model) if model is not None else {"effects": [], "parameters": {}},
        source=copy.deepcopy(source) if source is not None else {},
    )


def offsets_from_parameters(parameters: dict, *, robot: dict, fit: dict, effects=(), source: dict | None = None,
                            created: str | None = None) -> Offsets:
    """Build an Offsets from registry-named model parameters {name: {"value", "std", "unit"}} (values = alphas).

    joint_offset.<J> and head_offset.<J> give c = -value; camera.<roll|pitch|yaw> and board.<leg>.<rot_z|trans_x|
    trans_y> are copied. Leg joints, camera angles and board terms that are not estimated stay nominal (0);
    RHipYawPitch follows LHipYawPitch when only the latter is estimated. All parameters are kept in model.parameters.
    """
    value = {name: float(entry["value"]) for name, entry in parameters.items()}
    alpha = {j: value.get(f"joint_offset.{j}", 0.0) for j in LEG_JOINTS}
    if "joint_offset.RHipYawPitch" not in value:
        alpha["RHipYawPitch"] = alpha["LHipYawPitch"]
    for j in HEAD_JOINTS:
        for name in (f"head_offset.{j}", f"joint_offset.{j}"):
            if name in value:
                alpha[j] = value[name]
    camera = {a: value.get(f"camera.{a}", 0.0) for a in CAMERA_ANGLES}
    mount = {leg: (value.get(f"board.{leg}.rot_z", 0.0), value.get(f"board.{leg}.trans_x", 0.0),
                   value.get(f"board.{leg}.trans_y", 0.0)) for leg in LEGS}
    model = {"effects": list(effects),
             "parameters": {name: {"value": float(e["value"]), "std": float(e["std"]), "unit": e["unit"]}
                            for name, e in parameters.items()}}
    return offsets_from_alpha(alpha, camera, mount, robot=robot, fit=fit, model=model, source=source,
                              created=created)


def alpha_from_offsets(offsets: Offsets) -> dict:
    """The model's alphas a file stands for: {"joints": {joint: alpha = -c}, "camera": (roll, pitch, yaw),
    "board": {leg: (rot_z, x, y)}}, rad and m."""
    return {
        "joints": {j: -c for j, c in offsets.joint_offsets_rad.items()},
        "camera": offsets.camera_rpy("bottom"),
        "board": {leg: tuple(offsets.board_mount[leg][k] for k in BOARD_KEYS) for leg in LEGS},
    }
