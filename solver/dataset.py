"""The `naocal.dataset/2` directory format (and `naocal.dataset/1`, which still reads): what the agent records and
the solver replays.

A dataset is a directory holding
- `dataset.json`: robot, prior camera intrinsics, board, source, optional gravity and pixel noise;
- `observations.csv`: a header row, then one row per detected board vertex (columns below, any order,
  extra columns allowed and kept);
- optionally `images/` with the captured images (never read here).

Version 2 (docs/FORMATS.md) has a camera and a target per image (columns `camera`, `target`, names from the robot
description `robot.description`), any joint set of that description (`joints` in dataset.json), the vertices'
nominal positions in the frame the target is attached to (`x_mount_m`, ...) and optional per-image gravity
(`gravity_x_mps2`, ...). Version 1 has one camera ('bottom'), the NAO's 14 joints, the sandals (`leg`) and
sole positions (`x_sole_m`, ...). Both read as written (`Dataset.version`); `Dataset.as_v2()` gives any dataset
in version 2's form, which is what the solver uses. naocal writes version 2.

Every problem is a `DataError` naming the file, the line (1-based, the header is line 1) and the column or field.
`DatasetAppender` lets the agent save each capture as it goes, so a crash never loses a complete capture.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import logging
import math
import operator
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from naocal.solver import fields
from naocal.solver.camera import INTRINSICS_KEYS, CameraIntrinsics
from naocal.solver.errors import DataError
from naocal.solver.fileio import (  # noqa: F401 (read_text, parse_json_text: also used from here by agent/)
    append_durably, atomic_write_text, decode_text, interrupts_deferred, parse_json_text,
    read_bytes, read_json, read_text,
)
from naocal.solver.joints import JOINTS

log = logging.getLogger(__name__)

SCHEMA = SCHEMA_V1 = "naocal.dataset/1"
SCHEMA_V2 = "naocal.dataset/2"  # what naocal writes
SCHEMAS = (SCHEMA_V1, SCHEMA_V2)
META_FILE = "dataset.json"
OBSERVATIONS_FILE = "observations.csv"
IMAGES_DIR = "images"
DEFAULT_GRAVITY_TORSO_MPS2 = (-9.81, 0.0, 0.0)  # a robot lying on its back

# Plausible sizes, generous: a number beyond is damage or a unit mix-up (and would overflow the maths downstream).
CAMERA_KEYS = INTRINSICS_KEYS
MAX_BOARD_SQUARES = 100
MAX_LENGTH_M = 1.0  # board square, board centre, sole coordinates: the NAO's foot is 0.16 m long
MAX_MOUNT_M = 5.0  # version 2: a target's vertex in its frame (a floor board in front of the robot, in r_sole)
MAX_SANDAL_MASS_KG = 10.0
MAX_PIXEL_NOISE_PX = 100.0
# size of gravity (gravity_mps2, gravity_torso_mps2, gravity_ columns): 9.81 on Earth, an accelerometer's reading
# within a few %
GRAVITY_MPS2 = (7.0, 13.0)
PIXEL_MARGIN_IMAGES = 1.0  # detections may lie up to one image width/height outside the image
ANGLE_MARGIN_RAD = math.radians(10.0)  # angles (measured, commanded) may pass the joint limits by this much
MAX_JOINT_SPEED_RAD_S = 50.0  # vel_ columns: the NAO's fastest joint turns at about 8 rad/s
MAX_TIME_S = 1e10  # t_image_s, t_joints_s: robot clocks, possibly Unix time (1.7e9 s)
MAX_INDEX = 2 ** 53  # integer columns: exactly representable as float64, far inside int64

INT_COLUMNS = ("image", "stance", "head_posture", "vertex")
FLOAT_COLUMNS = ("u_px", "v_px", "x_sole_m", "y_sole_m", "z_sole_m", "t_image_s", "t_joints_s")
MEASURED_COLUMNS = JOINTS
COMMANDED_COLUMNS = tuple("cmd_" + j for j in JOINTS)
DIRECTION_COLUMNS = tuple("dir_" + j for j in JOINTS)
VELOCITY_COLUMNS = tuple("vel_" + j for j in JOINTS)  # naocal extension: rad/s at t_joints_s, all 14 or none
# The required columns, in the order issue 2 lists them (also the order the writer uses).
REQUIRED_COLUMNS = (
    ("image", "leg", "stance", "head_posture", "vertex")
    + FLOAT_COLUMNS
    + MEASURED_COLUMNS
    + COMMANDED_COLUMNS
    + DIRECTION_COLUMNS
)
LEGS = ("L", "R")
# Values that describe the robot's state when an image was taken: identical on every row of one image.
PER_IMAGE_COLUMNS = ("leg", "stance", "head_posture") + MEASURED_COLUMNS + COMMANDED_COLUMNS + DIRECTION_COLUMNS

# Version 2: the columns before the joints', in the writer's order, and the optional per-image gravity.
V2_LEADING_COLUMNS = ("image", "camera", "target", "stance", "head_posture", "vertex", "u_px", "v_px",
                      "x_mount_m", "y_mount_m", "z_mount_m", "t_image_s", "t_joints_s")
GRAVITY_COLUMNS = ("gravity_x_mps2", "gravity_y_mps2", "gravity_z_mps2")  # per image, in the robot's base frame
V1_TO_V2_COLUMNS = {"leg": "target", "x_sole_m": "x_mount_m", "y_sole_m": "y_mount_m", "z_sole_m": "z_mount_m"}


@dataclass(frozen=True)
class ColumnSpec:
    """What observations.csv must hold, for one format version (and, in version 2, one dataset.json)."""

    version: int
    required: tuple  # in the writer's order
    per_image: tuple  # identical on every row of one image
    velocity: tuple  # vel_ columns: all or none
    gravity: tuple  # gravity columns: all or none (version 2)
    direction: tuple  # values -1, 0, 1
    names: dict  # text column -> its allowed values


V1_SPEC = ColumnSpec(1, REQUIRED_COLUMNS, PER_IMAGE_COLUMNS, VELOCITY_COLUMNS, (), DIRECTION_COLUMNS, {"leg": LEGS})


def column_spec(meta: dict) -> ColumnSpec:
    """The column spec of a validated dataset.json."""
    if meta.get("schema") != SCHEMA_V2:
        return V1_SPEC
    joints = tuple(meta["joints"])
    angles = joints + tuple("cmd_" + j for j in joints) + tuple("dir_" + j for j in joints)
    return ColumnSpec(2, V2_LEADING_COLUMNS + angles, ("camera", "target", "stance", "head_posture") + angles,
                      tuple("vel_" + j for j in joints), GRAVITY_COLUMNS, tuple("dir_" + j for j in joints),
                      {"camera": tuple(meta["cameras"]), "target": tuple(meta["targets"])})


@dataclass
class Dataset:
    """A dataset in memory.

    Attributes
    ----------
    meta : dict
        The contents of dataset.json, with defaults filled in (gravity_torso_mps2).
    columns : dict[str, np.ndarray]
        Column name -> (N,) array. Numeric columns float64; image, stance, head_posture, vertex int64;
        leg a str array of 'L'/'R'; extra columns float64 if every value is a number, else str.
    path : Path or None
        The dataset directory it was read from or written to.
    """

    meta: dict
    columns: dict
    path: Path | None = None

    @property
    def version(self) -> int:
        return 2 if self.meta.get("schema") == SCHEMA_V2 else 1

    @property
    def joints(self) -> tuple[str, ...]:
        """The joint columns: dataset.json's `joints` (version 2), the NAO's 14 (version 1)."""
        return tuple(self.meta["joints"]) if self.version == 2 else JOINTS

    @property
    def n_rows(self) -> int:
        return len(self.columns["image"])

    def as_v2(self) -> Dataset:
        """This dataset in version 2's form (itself when it is one)."""
        if self.version == 2:
            return self
        meta, columns = upgrade_v1(self.meta, self.columns)
        return Dataset(meta, columns, self.path)

    def joint_matrix(self, prefix: str = "") -> np.ndarray:
        """(N, J) float array in `joints` order (version 1: solver.joints.JOINTS).

        prefix "" gives the measured angles (rad), "cmd_" the commanded angles (rad), "dir_" the approach
        directions (-1, 0, 1), "vel_" the joint velocities (rad/s, only if the dataset has them).
        """
        names = [prefix + j for j in self.joints]
        missing = [n for n in names if n not in self.columns]
        if missing:
            raise KeyError(f"dataset has no column {missing[0]!r}")
        return np.stack([np.asarray(self.columns[n], dtype=np.float64) for n in names], axis=1)

    def images(self) -> np.ndarray:
        """Sorted unique image indices, int64."""
        return np.unique(self.columns["image"])

    @property
    def has_velocities(self) -> bool:
        return "vel_" + self.joints[0] in self.columns

    def select(self, rows) -> Dataset:
        """A new dataset with only `rows` (boolean mask or index array); meta is copied."""
        return Dataset(copy.deepcopy(self.meta), {k: v[rows] for k, v in self.columns.items()}, self.path)


# ----------------------------------------------------------------------------------------------------- meta


def _named_objects(meta, key: str, what: str, known, path):
    """(field, object) of each entry of meta[key], a non-empty object whose names are among `known` (the robot
    description's cameras or targets) and whose entries are objects; DataError naming the field otherwise."""
    entries = fields.json_object(meta[key], path, key)
    if not entries:
        fields.fail(path, f"expected at least one {what}", key)
    for name, entry in entries.items():
        where = f"{key}.{name}"
        if name not in known:
            fields.fail(path, f"{what} {name!r} is not one of the robot's ({', '.join(known)})", where)
        yield where, entry


def _short(value) -> str:
    return fields.shown(value, 60)


def _check_camera(camera, path, where) -> None:
    """A camera's image size and prior intrinsics (both versions)."""
    fields.json_object(camera, path, where, CAMERA_KEYS)
    CameraIntrinsics.from_fields(camera, path, where)


def _check_board(board, path, where, required) -> None:
    """A board's squares, square size and mass (both versions)."""
    fields.json_object(board, path, where, required)
    for key in ("columns", "rows"):
        fields.number(board[key], path, f"{where}.{key}", low=2, integer=True, limit=MAX_BOARD_SQUARES)
    fields.number(board["square_m"], path, f"{where}.square_m", positive=True, limit=MAX_LENGTH_M)
    fields.number(board["mass_kg"], path, f"{where}.mass_kg", non_negative=True, limit=MAX_SANDAL_MASS_KG)


def find_non_finite(obj, where=""):
    """Field path of the first NaN or infinity in a JSON document, or None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return where or "(top level)"
    if isinstance(obj, dict):
        for key, value in obj.items():
            hit = find_non_finite(value, f"{where}.{key}" if where else str(key))
            if hit:
                return hit
    elif isinstance(obj, list):
        for i, value in enumerate(obj):
            hit = find_non_finite(value, f"{where}[{i}]")
            if hit:
                return hit
    return None


def validate_meta(meta, path) -> dict:
    """Check a dataset.json document (version 1 or 2) and return a copy with defaults filled in."""
    meta = fields.json_object(meta, path, "", ("schema",))
    schema = meta["schema"]
    if schema == SCHEMA_V2:
        return validate_meta_v2(meta, path)
    if schema != SCHEMA:
        raise DataError(path, f"wrong schema {schema!r}, expected {SCHEMA_V2!r} (or {SCHEMA_V1!r})", field="schema")
    bad = find_non_finite(meta)
    if bad:
        raise DataError(path, "non-finite value (NaN or infinity)", field=bad)
    fields.json_object(meta, path, "", ("robot", "camera", "board", "source"))
    robot = fields.json_object(meta["robot"], path, "robot", ("id", "model"))
    for key in ("id", "model"):
        fields.text(robot[key], path, f"robot.{key}", one_line=False)

    camera = fields.json_object(meta["camera"], path, "camera", ("name",))
    name = fields.text(camera["name"], path, "camera.name", one_line=False)
    if name != "bottom":
        raise DataError(path, f"camera {name!r} is not supported, expected 'bottom'", field="camera.name")
    _check_camera(camera, path, "camera")
    _check_board(meta["board"], path, "board", ("columns", "rows", "square_m", "center_x_m", "mass_kg"))
    fields.number(meta["board"]["center_x_m"], path, "board.center_x_m", limit=MAX_LENGTH_M)

    fields.text(meta["source"], path, "source", one_line=False)
    if "pixel_noise_px" in meta:
        fields.number(meta["pixel_noise_px"], path, "pixel_noise_px", positive=True, limit=MAX_PIXEL_NOISE_PX)
    meta = copy.deepcopy(meta)
    if "gravity_torso_mps2" in meta:
        _check_gravity(meta["gravity_torso_mps2"], path, "gravity_torso_mps2")
    else:
        meta["gravity_torso_mps2"] = list(DEFAULT_GRAVITY_TORSO_MPS2)
    return meta


def _check_gravity(value, path, field) -> list:
    gravity = fields.vector(value, 3, path, field, limit=GRAVITY_MPS2[1])
    size = math.hypot(*gravity)
    if not GRAVITY_MPS2[0] <= size <= GRAVITY_MPS2[1]:
        raise DataError(path, f"implausible gravity of {size:.4g} m/s^2 (expected {GRAVITY_MPS2[0]:g} to "
                              f"{GRAVITY_MPS2[1]:g}: 9.81 on Earth)", field=field)
    return gravity


_NAME = re.compile(r"^[a-z0-9_]{1,64}$")


def validate_meta_v2(meta, path) -> dict:
    """Check a version 2 dataset.json and return a copy with defaults filled in (robot.description 'nao', the
    description's gravity). Names of cameras, targets and joints must be the robot description's."""
    from naocal.solver.robot import load_robot

    meta = fields.json_object(meta, path, "")
    bad = find_non_finite(meta)
    if bad:
        raise DataError(path, "non-finite value (NaN or infinity)", field=bad)
    meta = copy.deepcopy(fields.json_object(meta, path, "", ("robot", "cameras", "targets", "joints", "source")))
    robot_meta = fields.json_object(meta["robot"], path, "robot", ("id", "model"))
    for key in ("id", "model"):
        fields.text(robot_meta[key], path, f"robot.{key}", one_line=False)
    description = robot_meta.setdefault("description", "nao")
    if not isinstance(description, str) or not _NAME.match(description):
        raise DataError(path, f"expected the name of a robot description (e.g. 'nao'), got {description!r}",
                        field="robot.description")
    try:
        robot = load_robot(description)
    except DataError:
        raise DataError(path, f"unknown robot description {description!r}", field="robot.description") from None

    for where, camera in _named_objects(meta, "cameras", "camera", robot.cameras, path):
        _check_camera(camera, path, where)
    for where, board in _named_objects(meta, "targets", "target", robot.targets, path):
        _check_board(board, path, where, ("columns", "rows", "square_m", "mass_kg"))
        if "centre_m" in board:
            fields.vector(board["centre_m"], 3, path, f"{where}.centre_m", limit=MAX_MOUNT_M)

    joints = fields.names(meta["joints"], path, "joints", what="joint names", non_empty=True)
    for i, joint in enumerate(joints):
        if joint not in robot.joints:
            raise DataError(path, f"joint {joint!r} is not one of the robot's", field=f"joints[{i}]")

    fields.text(meta["source"], path, "source", one_line=False)
    if "pixel_noise_px" in meta:
        fields.number(meta["pixel_noise_px"], path, "pixel_noise_px", positive=True, limit=MAX_PIXEL_NOISE_PX)
    if "gravity_mps2" in meta:
        _check_gravity(meta["gravity_mps2"], path, "gravity_mps2")
    else:
        meta["gravity_mps2"] = list(robot.gravity_mps2)
    return meta


def upgrade_v1(meta: dict, columns: dict) -> tuple[dict, dict]:
    """(meta, columns) of a version 1 dataset in version 2's form: the NAO, its camera (dataset.json `camera`),
    the sandals 'L' and 'R' (its `board`, mass at the board centre), its 14 joints, gravity as it was."""
    camera = {k: v for k, v in meta["camera"].items() if k != "name"}
    board = meta["board"]
    sandal = {"columns": board["columns"], "rows": board["rows"], "square_m": board["square_m"],
              "mass_kg": board["mass_kg"], "centre_m": [board["center_x_m"], 0.0, 0.0]}
    upgraded = {"schema": SCHEMA_V2, "robot": {**meta["robot"], "description": "nao"},
                "cameras": {meta["camera"]["name"]: camera}, "targets": {leg: dict(sandal) for leg in LEGS},
                "joints": list(JOINTS), "source": meta["source"],
                "gravity_mps2": list(meta.get("gravity_torso_mps2", DEFAULT_GRAVITY_TORSO_MPS2))}
    for key, value in meta.items():
        if key not in ("schema", "robot", "camera", "board", "source", "gravity_torso_mps2"):
            upgraded[key] = copy.deepcopy(value)
    out = {}
    for name, values in columns.items():
        out[V1_TO_V2_COLUMNS.get(name, name)] = values
        if name == "image":
            out["camera"] = np.full(len(values), meta["camera"]["name"])
    return upgraded, out


def n_board_vertices(meta: dict, target: str | None = None) -> int:
    """Inner vertices of the board (version 1) or of a target's board (version 2)."""
    board = meta["targets"][target] if meta.get("schema") == SCHEMA_V2 else meta["board"]
    return (int(board["columns"]) - 1) * (int(board["rows"]) - 1)


# ------------------------------------------------------------------------------------------ observations


def _first_bad(mask) -> int:
    return int(np.flatnonzero(mask)[0])


def _to_float(values, path, name: str, line_numbers) -> np.ndarray:
    """Parse strings to float64, or raise naming the first value that is not a number."""
    try:
        return np.array(values, dtype=np.float64)
    except ValueError:
        pass
    for i, text in enumerate(values):
        try:
            float(text)
        except ValueError:
            raise DataError(path, f"expected a finite number, got {_short(text)}", line=line_numbers[i], field=name) from None
    raise AssertionError("unreachable: numpy refused a column that float() accepts")  # pragma: no cover


def _try_float(values):
    try:
        return np.array(values, dtype=np.float64)
    except ValueError:
        return None


def _parse_column(name: str, strings, line_numbers, path, spec=None) -> np.ndarray:
    """One required (or vel_) column: parse and check the values of a single column."""
    spec = spec or V1_SPEC
    if name in spec.names:
        allowed = spec.names[name]
        values = np.array(strings, dtype=str) if len(strings) else np.array([], dtype="<U1")
        bad = ~np.isin(values, allowed)
        if bad.any():
            i = _first_bad(bad)
            what = "leg" if name == "leg" else name
            expected = "'L' or 'R'" if name == "leg" else "one of " + ", ".join(repr(a) for a in allowed)
            raise DataError(path, f"unknown {what} {_short(str(values[i]))}, expected {expected}",
                            line=line_numbers[i], field=name)
        return values
    values = _to_float(strings, path, name, line_numbers)
    bad = ~np.isfinite(values)
    if bad.any():
        i = _first_bad(bad)
        raise DataError(path, f"expected a finite number, got {_short(strings[i])}", line=line_numbers[i], field=name)
    if name in INT_COLUMNS:
        bad = values != np.round(values)
        if bad.any():
            i = _first_bad(bad)
            raise DataError(path, f"expected a whole number, got {_short(strings[i])}", line=line_numbers[i], field=name)
        bad = np.abs(values) > MAX_INDEX
        if bad.any():  # before the cast: beyond int64 it would wrap (and warn)
            i = _first_bad(bad)
            raise DataError(path, f"integer out of range (at most 2^53 in absolute value), got {_short(strings[i])}",
                            line=line_numbers[i], field=name)
        values = values.astype(np.int64)
    if name in spec.direction:
        bad = ~np.isin(values, (-1.0, 0.0, 1.0))
        if bad.any():
            i = _first_bad(bad)
            raise DataError(path, f"direction must be -1, 0 or 1, got {_short(strings[i])}", line=line_numbers[i],
                            field=name)
    return values


def _read_table(text: str, path, spec=None):
    """(header, raw columns {name: list of str}, line numbers of the data rows) of CSV text.

    Blank lines are skipped; line numbers are 1-based (the header is line 1). The header is checked here.
    """
    if '"' not in text:  # no quoting: C-level splitting is several times faster than the csv module
        lines = text.split("\n")
        if "\r" in text:
            lines = [line.rstrip("\r") for line in lines]
        numbered = [(n, line) for n, line in enumerate(lines, start=1) if line]
        if not numbered:
            raise DataError(path, "empty file: expected a header row and observations")
        header = numbered[0][1].split(",")
        data = numbered[1:]
        _check_header_position(numbered[0][0], path)
        velocity_names = _check_header(header, path, spec)
        n_fields = len(header)
        for line_number, line in data:
            if line.count(",") != n_fields - 1:
                raise DataError(path, f"{line.count(',') + 1} fields, but the header has {n_fields}",
                                line=line_number)
        flat = ",".join(line for _, line in data).split(",") if data else []
        raw = {name: flat[j::n_fields] for j, name in enumerate(header)}
        return header, raw, [n for n, _ in data], velocity_names

    reader = csv.reader(io.StringIO(text, newline=""))
    numbered = []
    try:
        for row in reader:
            if row:
                numbered.append((reader.line_num, row))
    except csv.Error as err:
        raise DataError(path, f"malformed CSV: {err}", line=reader.line_num) from None
    if not numbered:
        raise DataError(path, "empty file: expected a header row and observations")
    _check_header_position(numbered[0][0], path)
    header, data = numbered[0][1], numbered[1:]
    velocity_names = _check_header(header, path, spec)
    for line_number, row in data:
        if len(row) != len(header):
            raise DataError(path, f"{len(row)} fields, but the header has {len(header)}", line=line_number)
    transposed = list(zip(*(row for _, row in data))) if data else [()] * len(header)
    raw = {name: list(values) for name, values in zip(header, transposed)}
    return header, raw, [n for n, _ in data], velocity_names


def _check_header_position(line_number, path):
    if line_number != 1:
        raise DataError(path, "the header must be the first line", line=1)


def _check_header(header, path, spec=None):
    """Check the header; return the optional all-or-none columns present (vel_, and gravity in version 2)."""
    spec = spec or V1_SPEC
    if header[0].startswith("\ufeff"):  # byte order mark written by some spreadsheets
        header[0] = header[0][1:]
    seen = set()
    for name in header:
        if not name:
            raise DataError(path, "empty column name in the header", line=1)
        if name in seen:
            raise DataError(path, "duplicate column in the header", line=1, field=name)
        seen.add(name)
    missing = [name for name in spec.required if name not in seen]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise DataError(path, f"missing required column{more}", line=1, field=missing[0])
    present = ()
    for group, what in ((spec.velocity, f"vel_ columns must be given for all {len(spec.velocity)} joints or none"),
                        (spec.gravity, "gravity_x_mps2, gravity_y_mps2, gravity_z_mps2 must be given together")):
        given = tuple(name for name in group if name in seen)
        if given and len(given) != len(group):
            absent = next(name for name in group if name not in seen)
            raise DataError(path, what, line=1, field=absent)
        present += given
    return present


def parse_observations(text: str, path, meta: dict, *, allow_empty: bool = False):
    """Parse and validate observations.csv text.

    Returns (columns, header): columns as in `Dataset.columns`, header the column names in file order.
    """
    spec = column_spec(meta)
    header, raw, line_numbers, velocity_names = _read_table(text, path, spec)
    n_rows = len(line_numbers)
    if not n_rows and not allow_empty:
        raise DataError(path, "no observations: the file has only a header")

    columns = {"image": _parse_column("image", raw["image"], line_numbers, path, spec)}
    per_image = spec.per_image + velocity_names
    _, first, inverse = np.unique(columns["image"], return_index=True, return_inverse=True)
    if n_rows and _constant_within_images(raw, per_image, first[inverse]):
        # Parse each image's values once (from its first row, in file order) and broadcast them to its rows.
        order = np.argsort(first)
        first_rows = first[order].tolist()
        first_lines = [line_numbers[i] for i in first_rows]
        for name in per_image:
            strings = [raw[name][i] for i in first_rows]
            parsed = _parse_column(name, strings, first_lines, path, spec)
            per_image_values = np.empty_like(parsed)
            per_image_values[order] = parsed
            columns[name] = per_image_values[inverse]
        per_row, check_per_image = [n for n in spec.required if n not in columns], False
    else:
        per_row, check_per_image = [n for n in spec.required + velocity_names if n != "image"], True
    for name in per_row:
        columns[name] = _parse_column(name, raw[name], line_numbers, path, spec)

    _check_plausible(columns, raw, line_numbers, path, meta)
    if spec.version == 2:  # each row's board: its target's
        counts = {t: n_board_vertices(meta, t) for t in meta["targets"]}
        n_vertices_of_row = np.array([counts[t] for t in columns["target"]], dtype=np.int64)
        n_vertices = max(counts.values())
        vertex_range = "its target's vertex range"
    else:
        n_vertices_of_row = n_vertices = n_board_vertices(meta)
        vertex_range = f"0..{n_vertices - 1}"
    checks = (
        ("image", columns["image"] < 0, "image index must not be negative"),
        ("vertex", (columns["vertex"] < 0) | (columns["vertex"] >= n_vertices_of_row),
         f"vertex must be in {vertex_range}"),
    )
    for name, bad, problem in checks:
        if bad.any():
            i = _first_bad(bad)
            raise DataError(path, f"{problem}, got {_short(raw[name][i])}", line=line_numbers[i], field=name)
    if n_rows:
        _check_unique_vertices(columns, path, line_numbers, n_vertices)
        if check_per_image:
            _check_per_image(columns, path, line_numbers, velocity_names, spec)

    for name in header:
        if name not in columns:  # extra column: numbers if every value is one, else text
            values = _try_float(raw[name]) if n_rows else np.array([], dtype=np.float64)
            columns[name] = values if values is not None else np.array(raw[name], dtype=str)
    return {name: columns[name] for name in header}, header


def plausible_ranges(meta: dict) -> dict:
    """{column: (lower, upper, unit)}: where the values of the model's columns can physically lie (generously).

    Version 1: the NAO's joint limits (solver.limits), its one camera's image. Version 2: the joint limits of the
    robot description, and pixel bounds per camera: u_px and v_px map to {camera: (lower, upper, unit)}.
    """
    ranges = {"t_image_s": (-MAX_TIME_S, MAX_TIME_S, "s"), "t_joints_s": (-MAX_TIME_S, MAX_TIME_S, "s")}
    if meta.get("schema") == SCHEMA_V2:
        from naocal.solver.robot import load_robot

        robot = load_robot(meta["robot"].get("description", "nao"))
        joints = meta["joints"]
        limits = {joint: robot.joint_limits(joint) for joint in joints}
        cameras = meta["cameras"]
        lengths = ("x_mount_m", "y_mount_m", "z_mount_m")
        for name in GRAVITY_COLUMNS:
            ranges[name] = (-GRAVITY_MPS2[1], GRAVITY_MPS2[1], "m/s^2")
        for name in lengths:
            ranges[name] = (-MAX_MOUNT_M, MAX_MOUNT_M, "m")
    else:
        from naocal.solver.limits import joint_limits

        joints, limits = JOINTS, joint_limits()
        cameras = {meta["camera"]["name"]: meta["camera"]}
        for name in ("x_sole_m", "y_sole_m", "z_sole_m"):
            ranges[name] = (-MAX_LENGTH_M, MAX_LENGTH_M, "m")
    for axis, side in (("u_px", "width_px"), ("v_px", "height_px")):
        bounds = {name: (-PIXEL_MARGIN_IMAGES * camera[side], (1 + PIXEL_MARGIN_IMAGES) * camera[side], "px")
                  for name, camera in cameras.items()}
        ranges[axis] = bounds if meta.get("schema") == SCHEMA_V2 else next(iter(bounds.values()))
    for joint in joints:
        lower, upper = limits[joint]
        for prefix in ("", "cmd_"):
            ranges[prefix + joint] = (lower - ANGLE_MARGIN_RAD, upper + ANGLE_MARGIN_RAD, "rad")
        ranges["vel_" + joint] = (-MAX_JOINT_SPEED_RAD_S, MAX_JOINT_SPEED_RAD_S, "rad/s")
    return ranges


def _check_plausible(columns, raw, line_numbers, path, meta):
    for name, bounds in plausible_ranges(meta).items():
        if name not in columns:
            continue
        values = columns[name]
        if isinstance(bounds, dict):  # per camera (version 2 pixels)
            camera_of_row = columns["camera"]
            lower = np.array([bounds[c][0] for c in camera_of_row], dtype=float)
            upper = np.array([bounds[c][1] for c in camera_of_row], dtype=float)
            unit = "px"
        else:
            lower, upper, unit = bounds
        bad = (values < lower) | (values > upper)
        if bad.any():
            i = _first_bad(bad)
            lo, hi = (float(np.broadcast_to(b, values.shape)[i]) for b in (lower, upper))
            if unit == "rad":
                where = f"{lo:.4f}..{hi:.4f} rad: the joint's limits and {math.degrees(ANGLE_MARGIN_RAD):g} deg"
            elif name in ("u_px", "v_px"):
                camera = (meta["cameras"][str(columns["camera"][i])] if isinstance(bounds, dict)
                          else meta["camera"])
                where = f"{lo:g}..{hi:g} px, the {camera['width_px']} x {camera['height_px']} image with a margin"
            else:
                where = f"{lo:g}..{hi:g} {unit}"
            raise DataError(path, f"implausible value {_short(raw[name][i])} (expected {where})",
                            line=line_numbers[i], field=name)
    if all(name in columns for name in GRAVITY_COLUMNS):
        size = np.sqrt(sum(np.square(columns[name]) for name in GRAVITY_COLUMNS))
        bad = (size < GRAVITY_MPS2[0]) | (size > GRAVITY_MPS2[1])
        if bad.any():
            i = _first_bad(bad)
            raise DataError(path, f"implausible gravity of {size[i]:.4g} m/s^2 (expected {GRAVITY_MPS2[0]:g} to "
                                  f"{GRAVITY_MPS2[1]:g}: 9.81 on Earth)", line=line_numbers[i], field=GRAVITY_COLUMNS[0])


def _constant_within_images(raw: dict, names, first_row) -> bool:
    """True if, in every column of `names`, each row holds exactly the text of its image's first row.

    first_row : (N,) index of the first row of each row's image. Text equality is a sufficient check that lets
    us parse each image's values once; if it fails, the caller compares parsed numbers instead.
    """
    if len(first_row) < 2:
        return True
    gather = operator.itemgetter(*first_row.tolist())  # C-level gather of a whole column
    return all(gather(raw[name]) == tuple(raw[name]) for name in names)


def _check_unique_vertices(columns, path, line_numbers, n_vertices):
    key = columns["image"] * n_vertices + columns["vertex"]
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(key[order][1:] == key[order][:-1])
    if dup.size:
        later = order[dup + 1]
        i = int(later.min())  # the first row (in file order) that repeats an earlier one
        raise DataError(path, f"duplicate observation of vertex {columns['vertex'][i]} in image "
                              f"{columns['image'][i]}", line=line_numbers[i], field="vertex")


def _check_per_image(columns, path, line_numbers, velocity_columns, spec=None):
    spec = spec or V1_SPEC
    _, first, inverse = np.unique(columns["image"], return_index=True, return_inverse=True)
    first_row = first[inverse]  # for each row, the first row of the same image
    for name in spec.per_image + velocity_columns:
        values = columns[name]
        bad = values != values[first_row]
        if bad.any():
            i = _first_bad(bad)
            raise DataError(path, f"differs within image {columns['image'][i]}: {_short(values[i].item())} here, "
                                  f"{_short(values[first_row[i]].item())} on line {line_numbers[first_row[i]]}",
                            line=line_numbers[i], field=name)


# ---------------------------------------------------------------------------------------------- reading


def read_dataset(path) -> Dataset:
    """Read and validate a `naocal.dataset/2` (or /1) directory. Raises DataError on any problem."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "dataset directory not found")
    if not path.is_dir():
        raise DataError(path, "a dataset is a directory holding dataset.json and observations.csv")
    images = path / IMAGES_DIR
    if images.exists() and not images.is_dir():
        raise DataError(images, "expected a directory of images")
    meta_path = path / META_FILE
    meta = validate_meta(read_json(meta_path), meta_path)
    obs_path = path / OBSERVATIONS_FILE
    columns, _ = parse_observations(read_text(obs_path), obs_path, meta)
    dataset = Dataset(meta=meta, columns=columns, path=path)
    check_chain_joints(dataset, meta_path)
    return dataset


def check_chain_joints(dataset: Dataset, meta_path) -> None:
    """DataError naming dataset.json's `joints` unless they hold every joint between the robot description's base
    and each camera and target the observations use (the model moves those chains by them; version 2 may list any
    subset of the description's joints, version 1 has all 14)."""
    if dataset.version != 2 or not len(dataset.columns["image"]):
        return
    from naocal.solver.robot import load_robot

    robot = load_robot(dataset.meta["robot"]["description"])
    listed = set(dataset.joints)
    image = dataset.columns["image"]
    for kind, chain_of in (("camera", robot.camera_chain), ("target", robot.target_chain)):
        names, first = np.unique(dataset.columns[kind], return_index=True)
        for name, i in zip(names.tolist(), first.tolist()):
            chain = chain_of(name)
            missing = [j for j in chain.joint_names if j not in listed]
            if missing:
                raise DataError(meta_path, f"lacks joint {missing[0]!r}, which moves {kind} {name!r} (seen in image "
                                           f"{image[i]}; its chain {chain.base} to {chain.tip} needs "
                                           f"{', '.join(chain.joint_names)})", field="joints")


# ---------------------------------------------------------------------------------------------- writing


def ordered_column_names(names, meta: dict | None = None) -> list[str]:
    """Required columns in the format's order (version 1: issue 2's), then vel_ columns in joint order (and the
    gravity columns), then extras in their order."""
    spec = column_spec(meta) if meta is not None else V1_SPEC
    names = list(names)
    known = set(spec.required) | set(spec.velocity) | set(spec.gravity)
    ordered = [n for n in spec.required if n in names]
    ordered += [n for n in spec.velocity + spec.gravity if n in names]
    ordered += [n for n in names if n not in known]
    return ordered


def _format_int(value) -> str:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)  # the parser names it
    return str(int(number)) if number.is_integer() else repr(number)


def _format_column(name, values) -> list[str]:
    values = np.asarray(values)
    if name in INT_COLUMNS:
        return [_format_int(v) for v in values]
    if values.dtype.kind in "fiub":
        return [repr(float(v)) for v in values]  # repr round-trips a float64 exactly
    return [str(v) for v in values]


def format_rows(columns: dict, names) -> str:
    """CSV text (no header) of `columns` in the order `names`."""
    formatted = [_format_column(n, columns[n]) for n in names]
    lengths = {len(c) for c in formatted}
    if len(lengths) > 1:
        raise ValueError(f"columns have different lengths: {sorted(lengths)}")
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(zip(*formatted))
    return out.getvalue()


def format_header(names) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(list(names))
    return out.getvalue()


def format_meta(meta: dict) -> str:
    return json.dumps(meta, indent=2, allow_nan=False) + "\n"


def _split_parts(dataset_or_parts):
    if isinstance(dataset_or_parts, Dataset):
        return dataset_or_parts.meta, dataset_or_parts.columns
    if isinstance(dataset_or_parts, dict) and set(dataset_or_parts) == {"meta", "columns"}:
        return dataset_or_parts["meta"], dataset_or_parts["columns"]
    if isinstance(dataset_or_parts, tuple) and len(dataset_or_parts) == 2:
        return dataset_or_parts
    raise TypeError("write_dataset expects a Dataset, a (meta, columns) tuple or {'meta': ..., 'columns': ...}")


def write_dataset(dataset_or_parts, path) -> Dataset:
    """Write a dataset directory atomically (each file via temporary file, fsync, rename).

    Accepts a Dataset, a (meta, columns) tuple or a {"meta", "columns"} dict; columns may be any sequences.
    The data is validated exactly as `read_dataset` would before anything is written, and the Dataset that
    reading the files back gives is returned. Floats are written with repr(), so a round trip is bit-identical.
    """
    path = Path(path)
    meta, columns = _split_parts(dataset_or_parts)
    meta_path, obs_path = path / META_FILE, path / OBSERVATIONS_FILE
    meta = validate_meta(meta, meta_path)
    names = ordered_column_names(columns, meta)
    csv_text = format_header(names) + format_rows(columns, names)
    parsed, _ = parse_observations(csv_text, obs_path, meta)  # never write what we could not read back
    path.mkdir(parents=True, exist_ok=True)
    atomic_write_text(obs_path, csv_text)
    atomic_write_text(meta_path, format_meta(meta))
    return Dataset(meta=meta, columns=parsed, path=path)


# ------------------------------------------------------------------------------------------- appending


ROWS_IN_IMAGE_COLUMN = "rows_in_image"  # written by the appender: lets a resume tell a complete image from a torn one
COMPARED_META_KEYS = ("schema", "robot", "camera", "board", "gravity_torso_mps2",  # version 1
                       "cameras", "targets", "joints", "gravity_mps2")  # version 2


def _rows_to_columns(rows) -> dict:
    """A list of row dicts, or a dict of equal-length sequences, as a dict of lists."""
    if isinstance(rows, dict):
        return {k: list(np.atleast_1d(np.asarray(v))) for k, v in rows.items()}
    rows = list(rows)
    if not rows:
        return {}
    names = list(rows[0])
    for i, row in enumerate(rows):
        if set(row) != set(names):
            raise ValueError(f"row {i} has columns {sorted(row)}, row 0 has {sorted(names)}")
    return {n: [row[n] for row in rows] for n in names}


class DatasetAppender:
    """Saves a dataset capture by capture, so a crash never loses a complete capture nor keeps half of one.

    On open: creates the directory and dataset.json (atomically) if absent, else checks that the existing
    dataset.json is compatible with `meta` (same robot, camera, board, gravity). If observations.csv ends in a
    torn write (a last line without newline, or an image with fewer rows than its `rows_in_image` says), the
    torn rows are cut off, saved to `observations.csv.torn`, logged, and described in `self.repair`.

    `append(rows)` writes one capture (all rows of one image) with a single write, then flush and fsync.
    It adds the column `rows_in_image` (an extra column in the naocal.dataset/1 sense).
    """

    def __init__(self, path, meta: dict):
        self.path = Path(path)
        self.meta_path = self.path / META_FILE
        self.obs_path = self.path / OBSERVATIONS_FILE
        self.repair: str | None = None  # what was cut off on open, if anything
        self._header: list[str] | None = None
        self._images: set[int] = set()
        self.meta = self._open_meta(meta)
        self._open_observations()

    # -- opening

    def _open_meta(self, meta: dict) -> dict:
        meta = validate_meta(meta, "<meta given to DatasetAppender>")
        if self.path.exists() and not self.path.is_dir():
            raise DataError(self.path, "exists and is not a directory")
        if not self.meta_path.exists():
            self.path.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.meta_path, format_meta(meta))
            return meta
        existing = validate_meta(read_json(self.meta_path), self.meta_path)
        if existing.get("schema") != meta.get("schema"):
            raise DataError(self.meta_path, f"existing dataset is {existing.get('schema')}, this run writes "
                                            f"{meta.get('schema')}: finish it with the naocal that began it, or "
                                            "start a new one", field="schema")
        for key in COMPARED_META_KEYS:
            if existing.get(key) != meta.get(key):
                raise DataError(self.meta_path, f"existing dataset has a different {key!r} "
                                                f"({existing.get(key)!r} != {meta.get(key)!r}): "
                                                "refusing to mix captures of two set-ups", field=key)
        return existing

    def _open_observations(self) -> None:
        if not self.obs_path.exists():
            return
        data = read_bytes(self.obs_path)
        keep = self._complete_prefix_length(data)
        if keep < len(data) and data[:keep].count(b"\n") <= 1:
            keep = 0  # only the header of the torn first capture is left: the next capture writes its own
        if keep < len(data):
            self._cut(data, keep)
            data = data[:keep]
        if not data:
            return
        columns, header = parse_observations(decode_text(data, self.obs_path), self.obs_path, self.meta,
                                             allow_empty=True)
        self._header = header
        self._images = set(int(i) for i in columns["image"])

    def _complete_prefix_length(self, data: bytes) -> int:
        """Length of the longest prefix of `data` that holds only complete lines of complete captures."""
        end = data.rfind(b"\n") + 1  # drop a last line without newline
        if end == 0:
            return 0
        lines = data[:end].decode("utf-8", errors="replace").splitlines(keepends=True)
        header = next(csv.reader([lines[0]]))
        if ROWS_IN_IMAGE_COLUMN not in header or "image" not in header or len(lines) == 1:
            return end
        i_image, i_count = header.index("image"), header.index(ROWS_IN_IMAGE_COLUMN)
        # Walk back over the rows of the last image; if fewer than it announces, the write was torn.
        last = next(csv.reader([lines[-1]]))
        try:
            image, announced = last[i_image], int(float(last[i_count]))
        except (IndexError, ValueError):
            return end  # not ours to judge: read_dataset will name the bad line
        n = 0
        for line in reversed(lines[1:]):
            fields = next(csv.reader([line]))
            if len(fields) <= i_image or fields[i_image] != image:
                break
            n += 1
        if n >= announced:
            return end
        return end - sum(len(line.encode("utf-8")) for line in lines[len(lines) - n:])

    def _cut(self, data: bytes, keep: int) -> None:
        torn = data[keep:]
        torn_path = self.obs_path.with_name(self.obs_path.name + ".torn")
        _append_and_sync(torn_path, torn)
        with open(self.obs_path, "r+b") as f:
            f.truncate(keep)
            f.flush()
            os.fsync(f.fileno())
        n_lines = torn.count(b"\n") + (0 if torn.endswith(b"\n") else 1)
        self.repair = (f"{self.obs_path}: cut off a torn last capture ({len(torn)} bytes, {n_lines} line(s)), "
                       f"kept in {torn_path.name}")
        log.warning(self.repair)

    # -- appending

    def captured_images(self) -> set[int]:
        """Image indices already saved."""
        return set(self._images)

    def append(self, rows) -> int:
        """Append the rows of one capture (one image): a list of row dicts or a dict of columns.

        Values are validated like read_dataset does; the image must not be on disk yet. Returns the number
        of rows written (0 for no rows).
        """
        columns = _rows_to_columns(rows)
        if not columns or not len(next(iter(columns.values()))):
            return 0
        n = len(next(iter(columns.values())))
        if self._header is None or ROWS_IN_IMAGE_COLUMN in self._header:  # not in datasets other tools began
            columns[ROWS_IN_IMAGE_COLUMN] = [n] * n
        if self._header is None:
            names = ordered_column_names(columns, self.meta)
        else:
            names = self._header
            if set(columns) != set(names):
                extra = sorted(set(columns) - set(names))
                lacking = sorted(set(names) - set(columns))
                raise DataError(self.obs_path, f"capture columns differ from the file's header: extra {extra}, "
                                               f"missing {lacking}")
        text = format_rows(columns, names)
        header_text = format_header(names)
        label = f"{self.obs_path} (capture being appended)"
        parsed, _ = parse_observations(header_text + text, label, self.meta)
        images = set(int(i) for i in np.unique(parsed["image"]))
        if len(images) != 1:
            raise DataError(label, f"one capture must hold one image, got images {sorted(images)}", field="image")
        image = images.pop()
        if image in self._images:
            raise DataError(label, f"image {image} is already saved", field="image")
        data = (text if self._header is not None else header_text + text).encode("utf-8")
        with interrupts_deferred():  # on disk means counted as saved, even if Ctrl-C comes in between
            self._write_all(data, new_file=self._header is None)
            self._header = names
            self._images.add(image)
        return n

    def _write_all(self, data: bytes, *, new_file: bool) -> None:
        append_durably(self.obs_path, data, new_file=new_file)  # an empty or torn-away file: rewritten from its header


def _append_and_sync(path: Path, data: bytes) -> None:
    """Append `data` to `path` (created if absent) and fsync: used for the record of cut-off torn rows."""
    with open(path, "ab") as f:
        f.write(data if data.endswith(b"\n") else data + b"\n")
        f.flush()
        os.fsync(f.fileno())
