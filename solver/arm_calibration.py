"""`naocal.arm_calibration/1`: an arm's calibration file, as `naocal identify --out` writes it (docs/FORMATS.md).

The reader is strict: every problem is one DataError naming the file and the field. `model.parameters` is the
file's truth (every parameter by its identify --json name, SI value, std, unit, fixed); the sections
`joint_offsets_rad`, `link_lengths_m` and `sensors` repeat it for people and other programs and must agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from naocal.solver.errors import DataError
from naocal.solver.fileio import read_json
from naocal.solver.offsets import MAX_PARAMETER_SIZE  # the NAO's file's bounds per unit, where the arm has none stricter

SCHEMA = "naocal.arm_calibration/1"
# The units a parameter of each kind is stored in (solver/arm.py), by the first part of its name.
UNITS = {"joint_offset": "rad", "link_length": "m", "point": "m", "elasticity": "rad/(N m)"}
POSE_KINDS = ("link_pose", "tool")  # x, y, z in m and rx, ry, rz in rad: a joint origin's pose error, a tool mount's
# Largest |value| a file may hold (SI) before it is taken as damaged or a unit mix-up: 20 deg (the NAO's offsets
# limit), 0.1 m of link length or point position.
LIMITS = {"rad": math.radians(20.0), "m": 0.1, "rad/(N m)": MAX_PARAMETER_SIZE["rad/(N m)"]}
SENSOR_LIMITS = {"rad": 2 * math.pi, "m": 100.0}  # a sensor's frame: anywhere within 100 m
FIT_LIMITS = {"m": MAX_PARAMETER_SIZE["m"], "px": MAX_PARAMETER_SIZE["px"]}  # an RMS error beyond: no calibration
MAX_COUNT = 2 ** 53  # an integer a JSON reader holds exactly
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


def _fail(path, problem, field=None):
    raise DataError(path, problem, field=field)


def _number(value, path, field):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(path, f"expected a finite number, got {str(value)[:40]!r}", field)
    return float(value)


def _plausible(value, limit, unit, path, field):
    if abs(value) > limit:
        _fail(path, f"|value| {abs(value):.4g} {unit} is beyond any plausible calibration ({limit:.4g} {unit}): "
                    "a damaged file or a unit mix-up", field)
    return value


def _text(value, path, field):
    if not isinstance(value, str) or len(value) > 4096 or not value.isprintable():
        _fail(path, "expected a line of printable text", field)
    return value


def is_arm_calibration(path) -> bool:
    """Whether `path` is a file whose JSON says naocal.arm_calibration/1 (anything unreadable: no)."""
    try:  # a regular file only: a FIFO must not block the check; the whole file (the key may come last)
        doc = read_json(path)
    except DataError:
        return False
    return isinstance(doc, dict) and doc.get("schema") == SCHEMA


def read_arm_calibration(path) -> ArmCalibration:
    doc = read_json(path)  # regular files only, size and nesting capped (solver/fileio.py)
    if not isinstance(doc, dict):
        _fail(path, "expected a JSON object")
    if doc.get("schema") != SCHEMA:
        _fail(path, f"expected schema {SCHEMA!r}, got {str(doc.get('schema'))[:60]!r}", "schema")
    robot = doc.get("robot")
    if not isinstance(robot, dict):
        _fail(path, "expected a JSON object", "robot")
    for key in ("base", "tip"):
        if key not in robot:
            _fail(path, "missing required field", f"robot.{key}")
    robot = {k: _text(v, path, f"robot.{k}") for k, v in robot.items()}
    model = doc.get("model")
    if not isinstance(model, dict):
        _fail(path, "missing the fitted model", "model")
    effects = model.get("effects", [])
    if not isinstance(effects, list):
        _fail(path, "expected a list of effect names", "model.effects")
    from naocal.solver.arm import EFFECTS

    for i, e in enumerate(effects):
        if e not in EFFECTS:
            _fail(path, f"unknown arm effect {str(e)[:40]!r}", f"model.effects[{i}]")
    params = model.get("parameters")
    if not isinstance(params, dict) or not params:
        _fail(path, "missing the fitted parameters", "model.parameters")
    parameters = {}
    for name, entry in params.items():
        where = f"model.parameters.{name}"
        _text(name, path, "model.parameters")
        if not isinstance(entry, dict):
            _fail(path, "expected {value, std, unit, fixed}", where)
        for key in ("value", "std", "unit"):
            if key not in entry:
                _fail(path, "missing required field", f"{where}.{key}")
        value = _number(entry["value"], path, f"{where}.value")
        std = _number(entry["std"], path, f"{where}.std")
        unit = _text(entry["unit"], path, f"{where}.unit")
        kind = name.split(".", 1)[0]
        expected = "rad" if kind in POSE_KINDS and name.rsplit(".", 1)[-1].startswith("r") else \
            "m" if kind in POSE_KINDS else UNITS.get(kind)
        if kind == "joint_offset" and unit == "m":  # a prismatic joint's offset
            expected = "m"
        if kind == "sensor":
            expected = "rad" if ".rotation." in name else "m"
        if expected is None:
            _fail(path, "not an arm parameter (joint_offset., link_length., link_pose., tool., point., "
                        "elasticity., sensor.)", where)
        if unit != expected:
            _fail(path, f"unit {unit[:20]!r}, expected {expected!r}", f"{where}.unit")
        _plausible(value, (SENSOR_LIMITS if kind == "sensor" else LIMITS)[unit], unit, path, f"{where}.value")
        if std < 0:
            _fail(path, "a standard deviation cannot be negative", f"{where}.std")
        parameters[name] = {"value": value, "std": std, "unit": unit, "fixed": bool(entry.get("fixed", False))}
    # the people's sections must say what model.parameters says (an edited file that disagrees is refused)
    for section, prefix in (("joint_offsets_rad", "joint_offset."), ("link_lengths_m", "link_length.")):
        table = doc.get(section, {})
        if not isinstance(table, dict):
            _fail(path, "expected a JSON object", section)
        for key, value in table.items():
            value = _number(value, path, f"{section}.{key}")
            entry = parameters.get(prefix + key)
            if entry is None or abs(entry["value"] - value) > 1e-12 * max(1.0, abs(value)):
                _fail(path, f"disagrees with model.parameters.{prefix}{key}", f"{section}.{key}")
    _check_sensors(doc.get("sensors", {}), parameters, path)
    fit = doc.get("fit", {})
    if not isinstance(fit, dict):
        _fail(path, "expected a JSON object", "fit")
    rms, noise = {}, {}
    for section, out in (("rms", rms), ("noise", noise)):
        table = fit.get(section, {})
        if not isinstance(table, dict):
            _fail(path, "expected a JSON object", f"fit.{section}")
        for sensor, entry in table.items():
            if not isinstance(entry, dict) or entry.get("unit") not in ("m", "px"):
                _fail(path, "expected {value, unit: m | px}", f"fit.{section}.{sensor}")
            out[sensor] = (_fit_size(entry.get("value"), entry["unit"], path, f"fit.{section}.{sensor}.value"),
                           entry["unit"])
    heldout = fit.get("heldout") or {}
    if not isinstance(heldout, dict):
        _fail(path, "expected a JSON object or null", "fit.heldout")
    for sensor, entry in heldout.items():
        if not isinstance(entry, dict) or entry.get("unit") not in ("m", "px"):
            _fail(path, "expected {nominal, calibrated, unit: m | px}", f"fit.heldout.{sensor}")
        for key in ("nominal", "calibrated"):
            _fit_size(entry.get(key), entry["unit"], path, f"fit.heldout.{sensor}.{key}")
    if "n_observations" in fit:
        count = fit["n_observations"]
        if type(count) is not int or not 0 <= count <= MAX_COUNT:
            _fail(path, f"expected a count of observations, got {str(count)[:40]!r}", "fit.n_observations")
    reasons = model.get("fixed", {})
    if not isinstance(reasons, dict):
        _fail(path, "expected a JSON object", "model.fixed")
    created = doc.get("created", "?")
    return ArmCalibration(str(path), robot, tuple(effects), parameters,
                          {str(k): str(v) for k, v in reasons.items()}, rms, noise,
                          _text(created, path, "created") if created != "?" else "?", _chains(doc, robot, path))


def _chains(doc, robot, path):
    """The file's `chains` {name: (base, tip)} (several chains: their tips joined by '+' are robot.tip), or None:
    one chain, robot.base to robot.tip."""
    if "chains" not in doc:
        if "+" in robot["tip"]:
            _fail(path, "several chains (robot.tip joins their tips) but no chains section naming them: written by "
                        "an older naocal; identify the dataset again", "chains")
        return None
    chains = doc["chains"]
    if not isinstance(chains, dict) or not chains:
        _fail(path, "expected {name: {base, tip}, ...}", "chains")
    out = {}
    for name, entry in chains.items():
        if not isinstance(entry, dict) or set(entry) != {"base", "tip"}:
            _fail(path, "expected {base, tip}", f"chains.{name}")
        out[_text(name, path, f"chains.{name}")] = (_text(entry["base"], path, f"chains.{name}.base"),
                                                    _text(entry["tip"], path, f"chains.{name}.tip"))
    if "+".join(tip for _, tip in out.values()) != robot["tip"]:
        _fail(path, f"the chains' tips are not robot.tip {robot['tip']!r}", "chains")
    return out


def _fit_size(value, unit, path, field) -> float:
    """An RMS error of the fit: finite, not negative, within FIT_LIMITS."""
    value = _number(value, path, field)
    if value < 0:
        _fail(path, "cannot be negative", field)
    return _plausible(value, FIT_LIMITS[unit], unit, path, field)


def _check_sensors(sensors, parameters: dict, path) -> None:
    """The `sensors` section: per sensor rotation_rad and translation_m, 3 finite numbers each within SENSOR_LIMITS,
    saying what model.parameters' sensor.<name>.rotation/translation.<axis> say."""
    if not isinstance(sensors, dict):
        _fail(path, "expected a JSON object", "sensors")
    for name, frame in sensors.items():
        if not isinstance(frame, dict):
            _fail(path, "expected {rotation_rad, translation_m}", f"sensors.{name}")
        for key, part, unit in (("rotation_rad", "rotation", "rad"), ("translation_m", "translation", "m")):
            where = f"sensors.{name}.{key}"
            values = frame.get(key)
            if not isinstance(values, list) or len(values) != 3:
                _fail(path, "expected 3 numbers (x, y, z)", where)
            for axis, value in zip(AXES, values):
                value = _plausible(_number(value, path, f"{where}[{AXES.index(axis)}]"), SENSOR_LIMITS[unit], unit,
                                   path, f"{where}[{AXES.index(axis)}]")
                entry = parameters.get(f"sensor.{name}.{part}.{axis}")
                if entry is None or abs(entry["value"] - value) > 1e-12 * max(1.0, abs(value)):
                    _fail(path, f"disagrees with model.parameters.sensor.{name}.{part}.{axis}",
                          f"{where}[{AXES.index(axis)}]")
