"""The `naocal.offsets/2` file (and `naocal.offsets/1`, which still reads): a robot's calibration result, as robot
code and the tools use it (docs/FORMATS.md).

Sign convention (the one of B-Human, HULKs and the paper): a stored joint offset `c` is ADDED to every commanded
angle and SUBTRACTED from every measured angle: q_true = theta_measured - c. naocal's parameter
`joint_offset.<J>` is this c (the paper's alpha = -c). Camera rotations and translations and board mounts are
corrections as they are (Eq. 3 and Eq. 4).

Version 2 keeps body results (`body`: joint offsets and every other body effect), head results (`head`: each
camera's rotation and translation keyed by camera name, intrinsics) and the targets (`targets`: board mounts)
apart, so that they can be reused when heads and bodies are swapped between robots; each fitted effect writes its
own section (solver/effects/), and `model.parameters` holds every fitted parameter with its std. Build files from
an identification with `offsets_from_result` (or from parameters with `offsets_from_parameters`). A version 1
file reads into the same object: its model parameters renamed (camera.pitch -> camera.bottom.pitch,
intrinsics.fx -> intrinsics.bottom.fx, distortion.k1 -> distortion.bottom.k1) and its joint and head offset
parameters, which were alpha, turned into c.
"""

from __future__ import annotations

import copy
import datetime as dt
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from naocal.solver import fields
from naocal.solver.dataset import find_non_finite
from naocal.solver.effects import EFFECTS
from naocal.solver.errors import DataError
from naocal.solver.fileio import atomic_write_text, read_json
from naocal.solver.joints import HEAD_JOINTS, JOINTS, LEG_JOINTS, LEGS

SCHEMA_V1 = "naocal.offsets/1"
SCHEMA = SCHEMA_V2 = "naocal.offsets/2"  # what naocal writes
BACKUP_SUFFIX = ".bak"

# Plausible sizes: anything beyond is a damaged file, a unit mix-up (degrees written as radians) or a broken robot.
# Each effect keeps its own (solver/effects/); version 1 files are held to the same.
MAX_JOINT_OFFSET_RAD = EFFECTS["joint_offsets"].offsets_limit  # 20 deg
MAX_CAMERA_ROTATION_RAD = EFFECTS["camera_rotation"].offsets_limit  # 15 deg
MAX_CAMERA_TRANSLATION_M = EFFECTS["camera_translation"].offsets_limit  # 0.03 m
MAX_BOARD_TRANS_M = EFFECTS["board_mount"].limits["trans_x_m"]  # 0.03 m
MAX_BOARD_ROT_Z_RAD = EFFECTS["board_mount"].limits["rot_z_rad"]  # 15 deg

# model.parameters values by unit: beyond these no NAO parameter can be (a half turn, a metre, ...).
MAX_PARAMETER_SIZE = {"rad": math.pi, "m": 1.0, "px": 1e5, "s": 10.0, "rad/(N m)": 10.0, "1": 100.0}



def implausible_parameter(name: str, value: float, std: float, unit: str) -> str | None:
    """Why a fitted model parameter (registry name, model value) is beyond any NAO's, or None.

    The limits are the ones the file enforces (a result the file could not hold is no calibration); terms the file
    keeps only in model.parameters are bounded by MAX_PARAMETER_SIZE of their unit.
    """
    group, _, member = name.partition(".")
    if group in ("joint_offset", "head_offset"):
        limit = MAX_JOINT_OFFSET_RAD
    elif group == "camera" and unit == "rad":
        limit = MAX_CAMERA_ROTATION_RAD
    elif group == "camera":  # camera.<name>.trans_<axis>: the camera_translation effect's file limit
        limit = MAX_CAMERA_TRANSLATION_M
    elif group == "board":
        limit = MAX_BOARD_ROT_Z_RAD if member.endswith("rot_z") else MAX_BOARD_TRANS_M
    else:  # the file limit of the effect's section (what write_offsets would refuse), else the unit's
        owner = _owner(name)
        limit = MAX_PARAMETER_SIZE.get(unit, math.inf)
        if owner is not None and owner.offsets_section is not None:
            limit = min(limit, owner.offsets_limit)
    if not math.isfinite(value):
        return f"{name} is not a finite number"
    if not math.isfinite(std):
        return f"{name} is not determined by the data (its standard deviation is not finite)"
    if abs(value) > limit:
        if unit == "rad":
            return f"{name} = {math.degrees(value):.4g} deg is beyond any NAO's (at most {math.degrees(limit):g} deg)"
        return f"{name} = {value:.4g} {unit} is beyond any NAO's (at most {limit:g} {unit})"
    return None


def _owner(name: str):
    """The effect that owns a registry parameter name of the NAO (every camera and target), or None."""
    from naocal.solver.effect import Setup
    from naocal.solver.effects import owner_of
    from naocal.solver.robot import nao

    return owner_of(name, Setup.everything(nao()))


def implausible_parameters(parameters: dict) -> str | None:
    """The first implausible entry of {name: {"value", "std", "unit"}} (see implausible_parameter), or None."""
    for name, entry in parameters.items():
        why = implausible_parameter(name, float(entry["value"]), float(entry["std"]), entry["unit"])
        if why:
            return why
    return None


OFFSET_JOINTS = LEG_JOINTS + HEAD_JOINTS  # version 1: its joints, in the order written; the 12 leg joints required
CAMERA_ANGLES = ("roll", "pitch", "yaw")
CAMERAS = ("bottom", "top")  # version 1: bottom is required; top is accepted for completeness
BOARD_KEYS = ("rot_z_rad", "trans_x_m", "trans_y_m")
BOARD_LIMITS = {"rot_z_rad": MAX_BOARD_ROT_Z_RAD, "trans_x_m": MAX_BOARD_TRANS_M, "trans_y_m": MAX_BOARD_TRANS_M}
TOP_LEVEL_KEYS = ("schema", "robot", "created", "joint_offsets_rad", "camera_rotation_rad", "board_mount", "model",
                  "fit", "source")
ROBOT_KEYS = ("id", "body_id", "head_id")
PARAMETER_KEYS = ("value", "std", "unit")
PARAMETER_UNITS = ("rad", "m", "px", "s", "rad/(N m)", "1")

# Version 1: model parameter names of the registry of that time: group -> (unit, allowed members).
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
# Robot, body and head ids end up in other programs' config files and in file names (B-Human's
# Robots/<head>/<body>/, HULKs' body.<BodyId>.json): letters, digits, '.', '_', '-', starting with a letter or digit.
ROBOT_ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
ROBOT_ID_RULE = "letters, digits, '.', '_' or '-', starting with a letter or digit, at most 64 characters"


def parameter_unit(name: str) -> str:
    """The unit a version 1 model parameter of this name must carry; ValueError for names outside its scheme."""
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
    """An offsets document, version 2 in memory (a version 1 file reads into it). Angles in rad, lengths in m.

    body : {"joint_offsets_rad": {joint: c}, ...every other body effect's section} (c = the stored offset);
    head : {"camera_rotation_rad": {camera: {"roll", "pitch", "yaw"}}, ...every other head effect's section};
    targets : {"board_mount": {target: {"rot_z_rad", "trans_x_m", "trans_y_m"}}};
    model : {"effects": [str], "parameters": {name: {"value", "std", "unit"}}} (registry names and values);
    fit : {"rms_px": [x, y], "n_vertices": int, "n_images": int, ...}; robot : {"id", "body_id", "head_id",
    "description"}; read_schema : the version it was read from (written files are always version 2).
    """

    robot: dict
    created: str
    body: dict
    head: dict
    targets: dict
    fit: dict
    model: dict = field(default_factory=lambda: {"effects": [], "parameters": {}})
    source: dict = field(default_factory=dict)
    read_schema: str = SCHEMA

    # -- the sections robot code reads most

    @property
    def joint_offsets_rad(self) -> dict:
        """{joint: c}: c added to commands and subtracted from readings."""
        return self.body.setdefault("joint_offsets_rad", {})

    @property
    def camera_rotation_rad(self) -> dict:
        """{camera: {"roll", "pitch", "yaw"}}, the corrections of Eq. 3."""
        return self.head.setdefault("camera_rotation_rad", {})

    @property
    def board_mount(self) -> dict:
        """{target: {"rot_z_rad", "trans_x_m", "trans_y_m"}}, the corrections of Eq. 4."""
        return self.targets.setdefault("board_mount", {})

    def to_dict(self) -> dict:
        """The version 2 JSON document, keys in their canonical order."""
        return {
            "schema": SCHEMA,
            "robot": {k: self.robot.get(k) for k in ROBOT_KEYS_V2},
            "created": self.created,
            "body": _ordered_section("body", self.body),
            "head": _ordered_section("head", self.head),
            "targets": _ordered_section("targets", self.targets),
            "model": copy.deepcopy(self.model),
            "fit": copy.deepcopy(self.fit),
            "source": copy.deepcopy(self.source),
        }

    @classmethod
    def from_dict(cls, doc, path="<offsets>") -> Offsets:
        """Validate a JSON document of either version (see `validate`) and build the Offsets."""
        if isinstance(doc, dict) and doc.get("schema") == SCHEMA_V1:
            return _from_v1(_validated_fields(doc, path), path)
        return cls(**_validated_fields_v2(doc, path))

    def joint_offset(self, joint: str) -> float:
        """c of `joint`, 0.0 for a joint the file does not calibrate."""
        return float(self.joint_offsets_rad.get(joint, 0.0))

    def parameter(self, name: str) -> dict | None:
        """model.parameters[name] ({"value", "std", "unit"}) or None."""
        return self.model.get("parameters", {}).get(name)

    def std(self, name: str) -> float | None:
        entry = self.parameter(name)
        return None if entry is None else float(entry["std"])

    def camera_rpy(self, camera: str | None = None) -> tuple[float, float, float]:
        """(roll, pitch, yaw) correction of the camera (default: the robot description's first default camera, the
        NAO's bottom camera), rad (zeros if absent)."""
        if camera is None:
            from naocal.solver.robot import load_robot

            camera = load_robot(self.robot.get("description") or "nao").default_cameras[0]
        angles = self.camera_rotation_rad.get(camera, {})
        return tuple(float(angles.get(a, 0.0)) for a in CAMERA_ANGLES)



ROBOT_KEYS_V2 = ROBOT_KEYS + ("description",)
TOP_LEVEL_KEYS_V2 = ("schema", "robot", "created", "body", "head", "targets", "model", "fit", "source")


def _section_keys(section: str) -> dict:
    """{key: the effect that writes and checks it} of one section of a version 2 file, in the effects' order."""
    from naocal.solver.effects import EFFECTS

    keys = {}
    for effect in EFFECTS.values():
        if effect.offsets_section == section:
            keys.setdefault(effect.offsets_key, effect)
    return keys


def _ordered_section(section: str, content: dict) -> dict:
    known = _section_keys(section)
    out = {key: copy.deepcopy(content[key]) for key in known if key in content}
    out.update({k: copy.deepcopy(v) for k, v in content.items() if k not in known})
    return out


# --------------------------------------------------------------------------------------------- validation


def _created(value, path) -> str:
    if not isinstance(value, str):
        fields.fail(path, "expected an ISO-8601 UTC time string", "created")
    try:
        when = dt.datetime.fromisoformat(value)
    except ValueError:
        fields.fail(path, f"not an ISO-8601 time: {value!r}", "created")
    if when.utcoffset() not in (None, dt.timedelta(0)):
        fields.fail(path, f"expected a UTC time, got offset {when.utcoffset()}", "created")
    return value


def _document(doc, path, schema: str, expected: str, top_level_keys) -> dict:
    """The top level of an offsets document of `schema` (both versions): an object, its schema, no non-finite
    value anywhere, exactly `top_level_keys`; DataError naming the file and field otherwise."""
    doc = fields.json_object(doc, path, "(top level)")
    if "schema" not in doc:
        fields.fail(path, "missing required field", "schema")
    if doc["schema"] != schema:
        fields.fail(path, f"wrong schema {doc['schema']!r}, expected {expected}", "schema")
    bad = find_non_finite(doc)
    if bad:
        fields.fail(path, "non-finite value (NaN or infinity)", bad)
    fields.json_object(doc, path, "", top_level_keys, ())
    return doc


def _robot_ids(robot, path) -> None:
    """The robot's ids (both versions): each a valid id string, or null when unknown."""
    for key in ROBOT_KEYS:
        if robot[key] is not None and not isinstance(robot[key], str):
            fields.fail(path, "expected a string (or null when unknown)", f"robot.{key}")
        if isinstance(robot[key], str) and not ROBOT_ID_PATTERN.fullmatch(robot[key]):
            fields.fail(path, f"not a valid id {json.dumps(robot[key])[:40]}: {ROBOT_ID_RULE}", f"robot.{key}")


def _validated_fields(doc, path) -> dict:
    """The fields of a version 1 document (its own layout); DataError naming the file and field otherwise."""
    doc = _document(doc, path, SCHEMA_V1, repr(SCHEMA_V1), TOP_LEVEL_KEYS)
    robot = fields.json_object(doc["robot"], path, "robot", ROBOT_KEYS, ())
    _robot_ids(robot, path)

    joints = fields.json_object(doc["joint_offsets_rad"], path, "joint_offsets_rad", LEG_JOINTS, HEAD_JOINTS,
                                keys="joint name")
    joint_offsets = {j: fields.number(joints[j], path, f"joint_offsets_rad.{j}", limit=MAX_JOINT_OFFSET_RAD,
                                      unit="rad")
                     for j in OFFSET_JOINTS if j in joints}

    cameras = fields.json_object(doc["camera_rotation_rad"], path, "camera_rotation_rad", ("bottom",), ("top",))
    camera_rotation = {}
    for cam in CAMERAS:
        if cam in cameras:
            where = f"camera_rotation_rad.{cam}"
            angles = fields.json_object(cameras[cam], path, where, CAMERA_ANGLES, ())
            camera_rotation[cam] = {a: fields.number(angles[a], path, f"{where}.{a}", limit=MAX_CAMERA_ROTATION_RAD,
                                                     unit="rad") for a in CAMERA_ANGLES}

    boards = fields.json_object(doc["board_mount"], path, "board_mount", LEGS, ())
    board_mount = {}
    for leg in LEGS:
        where = f"board_mount.{leg}"
        mount = fields.json_object(boards[leg], path, where, BOARD_KEYS, ())
        board_mount[leg] = {k: fields.number(mount[k], path, f"{where}.{k}", limit=BOARD_LIMITS[k],
                                             unit="rad" if k.endswith("_rad") else "m") for k in BOARD_KEYS}

    return {
        "robot": dict(robot),
        "created": _created(doc["created"], path),
        "joint_offsets_rad": joint_offsets,
        "camera_rotation_rad": camera_rotation,
        "board_mount": board_mount,
        "model": _validated_model(doc["model"], path),
        "fit": _validated_fit(doc["fit"], path),
        "source": copy.deepcopy(fields.json_object(doc["source"], path, "source")),
    }


def _validated_model(model, path) -> dict:
    model = fields.json_object(model, path, "model", ("effects", "parameters"), ())
    effects = list(fields.names(model["effects"], path, "model.effects", what="effect names"))
    parameters = fields.json_object(model["parameters"], path, "model.parameters")
    checked = {}
    for name, entry in parameters.items():
        where = f"model.parameters.{name}"
        try:
            expected_unit = parameter_unit(name)
        except ValueError as err:
            fields.fail(path, str(err), where)
        checked[name] = _parameter_entry(entry, name, expected_unit, path, where)
    return {"effects": list(effects), "parameters": checked}


def _parameter_entry(entry, name: str, expected_unit: str, path, where) -> dict:
    """One model parameter's {value, std, unit} (both versions): the unit known and the parameter's, the value
    within the unit's plausible size, the std non-negative."""
    entry = fields.json_object(entry, path, where, PARAMETER_KEYS, ())
    unit = entry["unit"]
    if unit not in PARAMETER_UNITS:
        fields.fail(path, f"unknown unit {unit!r} (allowed: {', '.join(repr(u) for u in PARAMETER_UNITS)})",
                    f"{where}.unit")
    if unit != expected_unit:
        fields.fail(path, f"wrong unit {unit!r}, {name} is in {expected_unit!r}", f"{where}.unit")
    return {"value": fields.number(entry["value"], path, f"{where}.value", limit=MAX_PARAMETER_SIZE[unit], unit=unit),
            "std": fields.number(entry["std"], path, f"{where}.std", non_negative=True), "unit": unit}


def _validated_fit(fit, path) -> dict:
    fit = copy.deepcopy(fields.json_object(fit, path, "fit", ("rms_px", "n_vertices", "n_images")))
    rms = fit["rms_px"]
    if not isinstance(rms, list) or len(rms) != 2:
        fields.fail(path, "expected [rms_x, rms_y] in px", "fit.rms_px")
    fit["rms_px"] = [fields.number(v, path, f"fit.rms_px[{i}]", non_negative=True) for i, v in enumerate(rms)]
    fit["n_vertices"] = int(fields.number(fit["n_vertices"], path, "fit.n_vertices", non_negative=True, integer=True))
    fit["n_images"] = int(fields.number(fit["n_images"], path, "fit.n_images", non_negative=True, integer=True))
    return fit


def validate(doc, path="<offsets>") -> None:
    """Raise DataError (naming the field path, e.g. body.joint_offsets_rad.LHipPitch) if `doc` is not a valid file
    of either version."""
    if isinstance(doc, dict) and doc.get("schema") == SCHEMA_V1:
        _from_v1(_validated_fields(doc, path), path)
    else:
        _validated_fields_v2(doc, path)


def _validated_fields_v2(doc, path) -> dict:
    """The fields of Offsets from a version 2 document; DataError naming the file and field otherwise."""
    from naocal.solver.robot import load_robot

    doc = _document(doc, path, SCHEMA, f"{SCHEMA!r} (or {SCHEMA_V1!r})", TOP_LEVEL_KEYS_V2)
    robot_meta = fields.json_object(doc["robot"], path, "robot", ROBOT_KEYS_V2, ())
    _robot_ids(robot_meta, path)
    description = robot_meta["description"]
    if not isinstance(description, str) or not re.match(r"^[a-z0-9_]{1,64}$", description):
        fields.fail(path, "expected the name of a robot description (e.g. 'nao')", "robot.description")
    try:
        robot = load_robot(description)
    except DataError:
        fields.fail(path, f"unknown robot description {description!r}", "robot.description")

    sections = {}
    for section in ("body", "head", "targets"):
        known = _section_keys(section)
        content = fields.json_object(doc[section], path, section, optional=tuple(known))
        for key, value in content.items():
            known[key].read_offsets(value, path, f"{section}.{key}", robot)
        sections[section] = copy.deepcopy(content)
    for section, key in (("body", "joint_offsets_rad"), ("head", "camera_rotation_rad")):
        if key not in sections[section]:
            fields.fail(path, "missing required field", f"{section}.{key}")
    model = _validated_model_v2(doc["model"], path, robot)
    check_one_value(sections, model["parameters"], robot, path)
    return {
        "robot": dict(robot_meta),
        "created": _created(doc["created"], path),
        **sections,
        "model": model,
        "fit": _validated_fit(doc["fit"], path),
        "source": copy.deepcopy(fields.json_object(doc["source"], path, "source")),
    }


def _validated_model_v2(model, path, robot) -> dict:
    from naocal.solver.effect import Setup
    from naocal.solver.effects import ALL_EFFECTS, EFFECTS

    model = fields.json_object(model, path, "model", ("effects", "parameters"), ())
    effects = list(fields.names(model["effects"], path, "model.effects", what="effect names"))
    for i, name in enumerate(effects):
        if name not in ALL_EFFECTS:
            fields.fail(path, f"unknown effect {name!r} (known: {', '.join(ALL_EFFECTS)})", f"model.effects[{i}]")
    setup = Setup.everything(robot)
    units = {p.name: p.unit for e in EFFECTS.values() for p in e.parameters(setup)}
    parameters = fields.json_object(model["parameters"], path, "model.parameters")
    checked = {}
    for name, entry in parameters.items():
        where = f"model.parameters.{name}"
        if name not in units:
            fields.fail(path, f"unknown model parameter of robot {robot.name!r}", where)
        checked[name] = _parameter_entry(entry, name, units[name], path, where)
    return {"effects": list(effects), "parameters": checked}


def _v1_parameter_name(name: str) -> str:
    """A version 1 model parameter's name in version 2 (the one camera of version 1 was the bottom camera)."""
    group, _, rest = name.partition(".")
    if group in ("camera", "intrinsics", "distortion"):
        return f"{group}.bottom.{rest}"
    return name


def _from_v1(fields: dict, path=None) -> Offsets:
    """The Offsets a validated version 1 file stands for (its numbers unchanged; parameters renamed, alpha -> c);
    with `path`, DataError when its two copies of a value disagree (`check_one_value`)."""
    parameters = {}
    for name, entry in fields["model"]["parameters"].items():
        entry = dict(entry)
        if name.startswith(("joint_offset.", "head_offset.")):
            entry["value"] = -entry["value"]  # version 1 stored the model's alpha; the parameter is now c
        parameters[_v1_parameter_name(name)] = entry
    sections = {"body": {"joint_offsets_rad": fields["joint_offsets_rad"]},
                "head": {"camera_rotation_rad": fields["camera_rotation_rad"]},
                "targets": {"board_mount": fields["board_mount"]}}
    from naocal.solver.effect import Setup
    from naocal.solver.robot import load_robot

    robot = load_robot("nao")
    if path is not None:
        v1_names = {_v1_parameter_name(name): name for name in fields["model"]["parameters"]}
        check_one_value(sections, parameters, robot, path,
                        section_field=lambda section, keys: ".".join(keys),  # version 1: no section level
                        parameter_field=lambda name: v1_names.get(name, name), only_keys_held=True)
    # the sections version 1 did not have (the effects'), as version 2 writes them
    derived = sections_from_values({name: e["value"] for name, e in parameters.items()}, Setup.everything(robot))
    for section, content in derived.items():
        for key, value in content.items():
            sections[section].setdefault(key, value)
    return Offsets(
        robot={**fields["robot"], "description": "nao"}, created=fields["created"], **sections,
        fit=fields["fit"], model={"effects": fields["model"]["effects"], "parameters": parameters},
        source=fields["source"], read_schema=SCHEMA_V1)


# ------------------------------------------------------------------------------------------ read / write


def read_offsets(path) -> Offsets:
    """Read and validate a `naocal.offsets/2` (or /1) file."""
    return Offsets.from_dict(read_json(path), path)


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


def _robot(robot: dict, description: str) -> dict:
    return {**{k: robot.get(k) for k in ROBOT_KEYS}, "description": robot.get("description", description)}


def sections_from_values(values: dict, setup) -> dict:
    """{"body", "head", "targets"}: the sections each effect writes from registry-named values {name: value} (the
    one derivation of the people's sections from model.parameters: the writer uses it, the reader checks it)."""
    sections = {"body": {}, "head": {}, "targets": {}}
    for effect in EFFECTS.values():
        if effect.offsets_section is None:
            continue
        content = effect.write_offsets(values, setup)
        if content:
            sections[effect.offsets_section].setdefault(effect.offsets_key, {}).update(content)
    return sections


def _leaves(tree, prefix=()):
    """{(key, ...): number} of a nested section."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in _leaves(sub, prefix + (key,)).items()}
    return {prefix: tree}


def check_one_value(sections: dict, parameters: dict, robot, path, *, section_field=None, parameter_field=None,
                    only_keys_held: bool = False):
    """DataError unless every number the sections hold for a parameter of model.parameters is that parameter's value.

    A file holds each fitted value twice: in model.parameters (with its std) and in the people's sections (body,
    head, targets), which `sections_from_values` derives from it. An edited file whose two copies disagree (show,
    export and apply read the sections, verify the parameters) is refused naming both fields, as the arm's file is
    (kinds.arm.calibration). section_field(section, key path) and parameter_field(name) name a field as the
    file spells it (version 1: no section level, older parameter names); sections: {"body", "head", "targets"}.
    only_keys_held: compare only the keys the file's sections have (version 1 had no section for the effects).
    """
    from naocal.solver.effect import Setup

    section_field = section_field or (lambda section, keys: ".".join((section,) + keys))
    parameter_field = parameter_field or (lambda name: name)
    setup = Setup.everything(robot)
    values = {name: float(entry["value"]) for name, entry in parameters.items()}
    # which parameter each derived number comes from: its own (one number) before a partner it follows (two)
    source = {}
    for name in sorted(values, key=lambda n: len(_leaves(sections_from_values({n: 1.0}, setup)))):
        for section, content in sections_from_values({name: 1.0}, setup).items():
            for keys in _leaves(content):
                source.setdefault((section,) + keys, name)
    derived = sections_from_values(values, setup)
    for section in ("body", "head", "targets"):
        held = _leaves(sections.get(section, {}))
        for keys, value in _leaves(derived[section]).items():
            if only_keys_held and keys[0] not in sections.get(section, {}):
                continue
            name = source[(section,) + keys]
            where = section_field(section, keys)
            if keys not in held:
                fields.fail(path, f"missing, though model.parameters.{parameter_field(name)} holds its value "
                            f"({value!r}): the file contradicts itself", where)
            if abs(float(held[keys]) - value) > 1e-12 * max(1.0, abs(value)):
                fields.fail(path, f"{held[keys]!r} disagrees with model.parameters.{parameter_field(name)}.value = "
                            f"{value!r}: the file contradicts itself (edit both, or write it again with naocal)",
                      where)


def offsets_from_parameters(parameters: dict, *, robot: dict, fit: dict, effects=(), source: dict | None = None,
                            created: str | None = None, description: str = "nao") -> Offsets:
    """Build an Offsets from registry-named model parameters {name: {"value", "std", "unit"}}: each effect that owns
    some of them writes its section (joint_offset.<J> and head_offset.<J> are c, stored as they are; a joint on a
    shared motor follows its partner when only the partner is estimated). All parameters are kept in
    model.parameters; `effects` are the extra effects of the model.
    """
    from naocal.solver.effect import Setup
    from naocal.solver.robot import load_robot

    setup = Setup.everything(load_robot(description))
    sections = sections_from_values({name: float(entry["value"]) for name, entry in parameters.items()}, setup)
    sections["body"].setdefault("joint_offsets_rad", {})
    sections["head"].setdefault("camera_rotation_rad", {})
    model = {"effects": list(effects),
             "parameters": {name: {"value": float(e["value"]), "std": float(e["std"]), "unit": e["unit"]}
                            for name, e in parameters.items()}}
    return Offsets(robot=_robot(robot, description), created=created or utc_now_iso(), **sections,
                   fit=copy.deepcopy(fit), model=model, source=copy.deepcopy(source) if source is not None else {})


def offsets_from_result(result, *, robot: dict, source: dict | None = None, created: str | None = None) -> Offsets:
    """The offsets file of a successful identification (solver.identify.IdentificationResult): the one place that
    turns a fit into a file. robot : {"id", "body_id", "head_id"} (e.g. the dataset's `robot`)."""
    data = result.model.data
    fit = {"rms_px": list(result.rms_px), "n_vertices": int(data.n_rows), "n_images": int(data.n_images)}
    ids = {"id": str(robot.get("id", "unknown"))}
    for key in ("body_id", "head_id"):
        ids[key] = None if robot.get(key, robot.get("id")) is None else str(robot.get(key, robot.get("id")))
    return offsets_from_parameters(result.parameters_dict(), robot=ids, fit=fit,
                                   effects=list(result.registry.extra_effects()), source=source, created=created,
                                   description=result.registry.setup.robot.name)


def offsets_from_alpha(alpha_joints: dict, camera_rpy, board_mount: dict, *, robot: dict, fit: dict,
                       model: dict | None = None, source: dict | None = None, created: str | None = None,
                       top_camera_rpy=None) -> Offsets:
    """Build an Offsets from the paper's alphas (q_true = theta + alpha), doing the sign flip c = -alpha here.

    Parameters
    ----------
    alpha_joints : {joint: alpha} in rad for all 12 leg joints (RHipYawPitch may be left out: it then follows
        LHipYawPitch, both being one motor), optionally HeadYaw and HeadPitch.
    camera_rpy : (roll, pitch, yaw) of the bottom camera in rad, or a dict with those keys (Eq. 3).
    board_mount : {"L": (rotz rad, x m, y m), "R": ...} or dicts with the file's keys (Eq. 4).
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
        robot=_robot(robot, "nao"),
        created=created or utc_now_iso(),
        body={"joint_offsets_rad": {j: -float(alpha[j]) for j in OFFSET_JOINTS if j in alpha}},  # c = -alpha
        head={"camera_rotation_rad": cameras},
        targets={"board_mount": {leg: _mount_dict(board_mount[leg]) for leg in LEGS}},
        fit=copy.deepcopy(fit),
        model=copy.deepcopy(model) if model is not None else {"effects": [], "parameters": {}},
        source=copy.deepcopy(source) if source is not None else {},
    )


def alpha_from_offsets(offsets: Offsets) -> dict:
    """The paper's alphas a file stands for: {"joints": {joint: alpha = -c}, "camera": (roll, pitch, yaw),
    "board": {target: (rot_z, x, y)}}, rad and m."""
    return {
        "joints": {j: -c for j, c in offsets.joint_offsets_rad.items()},
        "camera": offsets.camera_rpy("bottom"),
        "board": {t: tuple(m[k] for k in BOARD_KEYS) for t, m in offsets.board_mount.items()},
    }


COMPENSATED_PREFIXES = ("joint_offset.", "head_offset.")  # parameters that are the stored offset c, as they are


def shown_name(name: str) -> str:
    """How people see a model parameter: joint_offset.<J> and head_offset.<J> as 'c <J>' (they are the stored
    offset c, value unchanged); every other parameter under its own name."""
    return "c " + name.split(".", 1)[1] if name.startswith(COMPENSATED_PREFIXES) else name


# ------------------------------------------------------------------------------------- the simulator's truth

TRUTH_SCHEMAS = ("naocal.truth/2", "naocal.truth/1")  # the mock's hidden truth (backends/mock.py writes /2)
TRUTH_EFFECTS_SCHEMA = "naocal.truth_effects/1"  # what each injected effect drew, beside truth.json
# truth_effects.json records that are per-joint values of a model parameter: effect -> the record's key
TRUTH_EFFECT_RECORDS = {"elasticity": "compliance_rad_per_nm", "backlash": "half_play_rad"}


def is_truth_file(path) -> bool:
    """Whether `path` is a simulator's truth.json (its schema), without failing on anything else."""
    try:
        doc = read_json(path)
    except (DataError, OSError):
        return False
    return isinstance(doc, dict) and doc.get("schema") in TRUTH_SCHEMAS


def read_truth(path) -> tuple[Offsets, list[str]]:
    """The simulator's hidden truth (truth.json, and truth_effects.json beside it when there) as an Offsets whose
    model.parameters are the true values with std 0: joint offsets c = -alpha (the mock's sign), camera rotations,
    board mounts, and the per-joint effects of TRUTH_EFFECT_RECORDS. Also the notes on what it does not compare
    (the other injected effects). DataError naming the file and field for anything else."""
    from naocal.solver.effect import Setup
    from naocal.solver.robot import nao

    path = Path(path)
    doc = fields.json_object(read_json(path), path, "(top level)")
    if doc.get("schema") not in TRUTH_SCHEMAS:
        fields.fail(path, f"expected a simulator's truth ({' or '.join(TRUTH_SCHEMAS)})", "schema")
    setup = Setup.everything(nao())
    units = {p.name: p.unit for e in EFFECTS.values() for p in e.parameters(setup)}
    values = {}
    for joint, alpha in fields.json_object(doc.get("alpha_rad"), path, "alpha_rad").items():
        alpha = fields.number(alpha, path, f"alpha_rad.{joint}", limit=MAX_JOINT_OFFSET_RAD, unit="rad")
        for name in (f"joint_offset.{joint}", f"head_offset.{joint}"):
            if name in units and (alpha != 0.0 or name.startswith("joint_offset.")):
                values[name] = -alpha  # the mock's alpha: q_true = servo + alpha; c = -alpha
        if not any(n in units for n in (f"joint_offset.{joint}", f"head_offset.{joint}")):
            fields.fail(path, "unknown joint", f"alpha_rad.{joint}")
    cameras = fields.json_object(doc.get("camera_rotation_rad"), path, "camera_rotation_rad")
    if "pitch" in cameras:  # naocal.truth/1: the bottom camera's
        cameras = {"bottom": cameras}
    for camera, angles in cameras.items():
        angles = fields.json_object(angles, path, f"camera_rotation_rad.{camera}")
        for a in CAMERA_ANGLES:
            values[f"camera.{camera}.{a}"] = fields.number(angles.get(a), path, f"camera_rotation_rad.{camera}.{a}",
                                                           limit=MAX_CAMERA_ROTATION_RAD, unit="rad")
    for target, mount in fields.json_object(doc.get("board_mount"), path, "board_mount").items():
        mount = fields.json_object(mount, path, f"board_mount.{target}")
        for key, short, _ in (("rot_z_rad", "rot_z", 0), ("trans_x_m", "trans_x", 0), ("trans_y_m", "trans_y", 0)):
            values[f"board.{target}.{short}"] = fields.number(mount.get(key), path, f"board_mount.{target}.{key}",
                                                              limit=BOARD_LIMITS[key], unit=key.rsplit("_", 1)[1])
    notes = []
    injected = fields.json_object(doc.get("effects", {}), path, "effects")
    records_path = path.with_name("truth_effects.json")
    records = {}
    if records_path.is_file():
        records_doc = fields.json_object(read_json(records_path), records_path, "(top level)")
        if records_doc.get("schema") != TRUTH_EFFECTS_SCHEMA:
            fields.fail(records_path, f"expected {TRUTH_EFFECTS_SCHEMA!r}", "schema")
        records = fields.json_object(records_doc.get("effects", {}), records_path, "effects")
        if "realism" in records_doc:
            notes.append(f"the realistic mock's own errors ({records_path.name}: realism) are not compared")
    for effect in injected:
        key = TRUTH_EFFECT_RECORDS.get(effect)
        if key is None or effect not in records:
            notes.append(f"the injected {effect} is not compared" + ("" if key is None else
                                                                     f" ({records_path.name} is missing)"))
            continue
        record = fields.json_object(records[effect], records_path, f"effects.{effect}")
        table = fields.json_object(record.get(key), records_path, f"effects.{effect}.{key}")
        for joint, value in table.items():
            name = f"{EFFECTS[effect].parameters(setup)[0].name.split('.')[0]}.{joint}"
            if name not in units:
                fields.fail(records_path, "unknown joint", f"effects.{effect}.{key}.{joint}")
            values[name] = fields.number(value, records_path, f"effects.{effect}.{key}.{joint}",
                                         limit=MAX_PARAMETER_SIZE[units[name]], unit=units[name])
    parameters = {name: {"value": v, "std": 0.0, "unit": units[name]} for name, v in values.items()}
    offsets = offsets_from_parameters(parameters, robot={"id": "simulated", "body_id": None, "head_id": None},
                                      fit={"rms_px": [0.0, 0.0], "n_vertices": 0, "n_images": 0},
                                      effects=[e for e in injected if e in TRUTH_EFFECT_RECORDS],
                                      source={"truth": str(path)}, created=utc_now_iso())
    return offsets, notes
