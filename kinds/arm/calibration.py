"""`naocal.arm_calibration/1`: an arm's calibration file, as `naocal identify --out` writes it (docs/FORMATS.md).

The reader is strict: every problem is one DataError naming the file and the field. `model.parameters` is the
file's truth (every parameter by its identify --json name, SI value, std, unit, fixed); the sections
`joint_offsets_rad`, `link_lengths_m` and `sensors` repeat it for people and other programs and must agree.
A camera's intrinsics corrections (the intrinsics effect) are `intrinsics.<camera>.<fx|fy|cx|cy>` (px) and its
distortion's `intrinsics.<camera>.<k1|k2|p1|p2|k3>` (1, OpenCV's plumb_bob), added to the dataset's filed intrinsics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from naocal.solver import fields
from naocal.solver.effects import EFFECTS
from naocal.solver.effects.intrinsics import DISTORTION
from naocal.solver.errors import DataError
from naocal.solver.fileio import read_json
from naocal.solver.offsets import MAX_PARAMETER_SIZE  # the NAO's file's bounds per unit, where the arm has none stricter

SCHEMA = "naocal.arm_calibration/1"
# The units a parameter of each kind is stored in (kinds/arm/model.py), by the first part of its name.
UNITS = {"joint_offset": "rad", "link_length": "m", "elasticity": "rad/(N m)", "intrinsics": "px", "marker_scale": "1"}
# x, y, z in m and rx, ry, rz in rad: a joint origin's pose error, a tool mount's, a marker's (a point's: x, y, z)
POSE_KINDS = ("link_pose", "tool", "point")
# Largest |value| a file may hold (SI) before it is taken as damaged or a unit mix-up: 20 deg (the NAO's offsets
# limit), 0.1 m of link length or point position, a camera's intrinsics corrections as the NAO's offsets file's
# (200 px, a distortion coefficient of 2).
LIMITS = {"rad": math.radians(20.0), "m": 0.1, "rad/(N m)": MAX_PARAMETER_SIZE["rad/(N m)"],
          "px": EFFECTS["intrinsics"].offsets_limit, "1": EFFECTS["distortion"].offsets_limit}
SENSOR_LIMITS = {"rad": 2 * math.pi, "m": 100.0}  # a sensor's frame: anywhere within 100 m
FIT_LIMITS = {"m": MAX_PARAMETER_SIZE["m"], "px": MAX_PARAMETER_SIZE["px"]}  # an RMS error beyond: no calibration
FIT_UNITS = ("m", "px")
MAX_TEXT = 4096  # characters of a name or a line of text
AXES = "xyz"


def implausible(parameters: dict) -> list:
    """Names of {name: {"value", "unit"}} beyond what a calibration file may hold (LIMITS): identify refuses such a
    fit (exit 3) rather than write a file every reader would refuse."""
    return [n for n, e in parameters.items() if not n.startswith("sensor.")
            and abs(e["value"]) > LIMITS.get(e["unit"], math.inf)]


@dataclass
class ArmCalibration:
    path: str
    robot: dict  # urdf, base, tip, id
    effects: tuple
    parameters: dict  # name -> {"value", "std", "unit", "fixed"} (SI)
    fixed_reasons: dict
    rms: dict  # sensor -> (value, unit) of the fit
    noise: dict  # sensor -> (value, unit) the fit weighted by (absent in older files)
    created: str
    chains: dict = None  # {chain name: (base, tip)}: the file's `chains`, else its one chain named by its tip

    def __post_init__(self):
        if self.chains is None:
            self.chains = {self.robot["tip"]: (self.robot["base"], self.robot["tip"])}

    @property
    def arm_parameters(self) -> dict:
        """The arm's own parameters (not the sensors' frames, which belong to the setup)."""
        return {n: e for n, e in self.parameters.items() if not n.startswith("sensor.")}


def is_arm_calibration(path) -> bool:
    """Whether `path` is a file whose JSON says naocal.arm_calibration/1 (anything unreadable: no)."""
    try:  # a regular file only: a FIFO must not block the check; the whole file (the key may come last)
        doc = read_json(path)
    except DataError:
        return False
    return isinstance(doc, dict) and doc.get("schema") == SCHEMA


def read_arm_calibration(path) -> ArmCalibration:
    doc = fields.json_object(read_json(path), path, "")  # regular files only, size and nesting capped (fileio)
    if doc.get("schema") != SCHEMA:
        fields.fail(path, f"expected schema {SCHEMA!r}, got {str(doc.get('schema'))[:60]!r}", "schema")
    robot = fields.json_object(doc.get("robot"), path, "robot", ("base", "tip"))
    robot = {k: fields.text(v, path, f"robot.{k}", max_chars=MAX_TEXT) for k, v in robot.items()}
    model = fields.json_object(doc.get("model"), path, "model", ("parameters",))
    effects = fields.names(model.get("effects", []), path, "model.effects", what="effect names")
    from naocal.solver.effects import ARM_EFFECTS

    for i, e in enumerate(effects):
        if e not in ARM_EFFECTS:
            fields.fail(path, f"unknown arm effect {str(e)[:40]!r}", f"model.effects[{i}]")
    params = fields.json_object(model["parameters"], path, "model.parameters")
    if not params:
        fields.fail(path, "expected the fitted parameters, got none", "model.parameters")
    parameters = {}
    for name, entry in params.items():
        where = f"model.parameters.{name}"
        fields.text(name, path, "model.parameters", max_chars=MAX_TEXT)
        entry = fields.json_object(entry, path, where, ("value", "std", "unit"))
        value = fields.number(entry["value"], path, f"{where}.value")
        std = fields.number(entry["std"], path, f"{where}.std", non_negative=True)
        unit = fields.text(entry["unit"], path, f"{where}.unit", max_chars=MAX_TEXT)
        kind = name.split(".", 1)[0]
        expected = "rad" if kind in POSE_KINDS and name.rsplit(".", 1)[-1].startswith("r") else \
            "m" if kind in POSE_KINDS else UNITS.get(kind)
        if kind == "joint_offset" and unit == "m":  # a prismatic joint's offset
            expected = "m"
        if kind == "intrinsics" and name.rsplit(".", 1)[-1] in DISTORTION:  # lens distortion: no unit
            expected = "1"
        if kind == "sensor":
            expected = "rad" if ".rotation." in name else "m"
        if expected is None:
            fields.fail(path, "not an arm parameter (joint_offset., link_length., link_pose., tool., point., "
                        "marker_scale., elasticity., intrinsics., sensor.)", where)
        if unit != expected:
            fields.fail(path, f"unit {unit[:20]!r}, expected {expected!r}", f"{where}.unit")
        fields.number(value, path, f"{where}.value", limit=(SENSOR_LIMITS if kind == "sensor" else LIMITS)[unit],
                      unit=unit)
        parameters[name] = {"value": value, "std": std, "unit": unit, "fixed": bool(entry.get("fixed", False))}
    # the people's sections must say what model.parameters says (an edited file that disagrees is refused)
    for section, prefix in (("joint_offsets_rad", "joint_offset."), ("link_lengths_m", "link_length.")):
        for key, value in fields.json_object(doc.get(section, {}), path, section).items():
            value = fields.number(value, path, f"{section}.{key}")
            entry = parameters.get(prefix + key)
            if entry is None or abs(entry["value"] - value) > 1e-12 * max(1.0, abs(value)):
                fields.fail(path, f"disagrees with model.parameters.{prefix}{key}", f"{section}.{key}")
    _check_sensors(doc.get("sensors", {}), parameters, path)
    fit = fields.json_object(doc.get("fit", {}), path, "fit")
    rms, noise = {}, {}
    for section, out in (("rms", rms), ("noise", noise)):
        for sensor, entry in fields.json_object(fit.get(section, {}), path, f"fit.{section}").items():
            where = f"fit.{section}.{sensor}"
            entry = fields.json_object(entry, path, where, ("value", "unit"))
            unit = fields.choice(entry["unit"], FIT_UNITS, path, f"{where}.unit")
            out[sensor] = (_fit_size(entry["value"], unit, path, f"{where}.value"), unit)
    for sensor, entry in fields.json_object(fit.get("heldout") or {}, path, "fit.heldout").items():
        where = f"fit.heldout.{sensor}"
        entry = fields.json_object(entry, path, where, ("nominal", "calibrated", "unit"))
        unit = fields.choice(entry["unit"], FIT_UNITS, path, f"{where}.unit")
        for key in ("nominal", "calibrated"):
            _fit_size(entry[key], unit, path, f"{where}.{key}")
    if "n_observations" in fit:
        fields.count(fit["n_observations"], path, "fit.n_observations")
    reasons = fields.json_object(model.get("fixed", {}), path, "model.fixed")
    created = doc.get("created", "?")
    return ArmCalibration(str(path), robot, tuple(effects), parameters,
                          {str(k): str(v) for k, v in reasons.items()}, rms, noise,
                          fields.text(created, path, "created", max_chars=MAX_TEXT) if created != "?" else "?",
                          _chains(doc, robot, path))


def _chains(doc, robot, path):
    """The file's `chains` {name: (base, tip)} (several chains: their tips joined by '+' are robot.tip), or None:
    one chain, robot.base to robot.tip."""
    if "chains" not in doc:
        if "+" in robot["tip"]:
            fields.fail(path, "several chains (robot.tip joins their tips) but no chains section naming them: "
                              "written by an older naocal; identify the dataset again", "chains")
        return None
    chains = doc["chains"]
    if not isinstance(chains, dict) or not chains:
        fields.fail(path, "expected {name: {base, tip}, ...}", "chains")
    out = {}
    for name, entry in chains.items():
        where = f"chains.{fields.text(name, path, 'chains', max_chars=MAX_TEXT)}"
        entry = fields.json_object(entry, path, where, required=("base", "tip"), optional=())
        out[name] = tuple(fields.text(entry[k], path, f"{where}.{k}", max_chars=MAX_TEXT) for k in ("base", "tip"))
    if "+".join(tip for _, tip in out.values()) != robot["tip"]:
        fields.fail(path, f"the chains' tips are not robot.tip {robot['tip']!r}", "chains")
    return out


def _fit_size(value, unit, path, field) -> float:
    """An RMS error of the fit: finite, not negative, within FIT_LIMITS."""
    return fields.number(value, path, field, non_negative=True, limit=FIT_LIMITS[unit], unit=unit)


def _check_sensors(sensors, parameters: dict, path) -> None:
    """The `sensors` section: per sensor rotation_rad and translation_m, 3 finite numbers each within SENSOR_LIMITS,
    saying what model.parameters' sensor.<name>.rotation/translation.<axis> say."""
    for name, frame in fields.json_object(sensors, path, "sensors").items():
        frame = fields.json_object(frame, path, f"sensors.{name}", ("rotation_rad", "translation_m"))
        for key, part, unit in (("rotation_rad", "rotation", "rad"), ("translation_m", "translation", "m")):
            where = f"sensors.{name}.{key}"
            values = fields.vector(frame[key], 3, path, where, limit=SENSOR_LIMITS[unit], unit=unit)
            for axis, value in zip(AXES, values):
                entry = parameters.get(f"sensor.{name}.{part}.{axis}")
                if entry is None or abs(entry["value"] - value) > 1e-12 * max(1.0, abs(value)):
                    fields.fail(path, f"disagrees with model.parameters.sensor.{name}.{part}.{axis}",
                                f"{where}[{AXES.index(axis)}]")
