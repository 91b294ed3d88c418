"""`naocal.arm_dataset/1`: joint readings of a serial arm with 3-D points and pixels of points on its end effector
(docs/FORMATS.md, docs/ARM.md). A directory with dataset.json and observations.csv; the reader is strict: every
problem is one DataError naming the file, the line and the field.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from naocal.kinds.arm.model import POINT_KINDS, ArmChain, Observations, Sensor
from naocal.solver import fields
from naocal.solver.camera import INTRINSICS_KEYS, CameraIntrinsics
from naocal.solver.errors import DataError
from naocal.solver.fields import fail
from naocal.solver.fileio import read_json, read_text

SCHEMA = "naocal.arm_dataset/1"
JOINT_UNITS = {"_rad": 1.0, "_deg": math.pi / 180.0}
SLIDE_UNITS = {"_m": 1.0, "_mm": 1e-3}  # a prismatic joint's reading
POINT_UNITS = {"_m": 1.0, "_mm": 1e-3}
PIXEL_COLUMNS = ("u_px", "v_px")
DELIMITERS = (",", ";", "\t")  # ',' (the format); ';' (with decimal commas) or a tab as spreadsheets export
MISSING = ("", "nan", "NaN", "NAN", "-nan")  # a measurement a sensor did not make (a marker out of sight)
ANGLE_MARGIN = math.radians(10.0)  # readings beyond a joint's URDF limits by more are refused
SLIDE_MARGIN = 0.01  # m, the same for a prismatic joint
MAX_POINT_M = 100.0  # a 3-D reading farther from its sensor is refused
WORKSPACE_M = 10.0  # a point on the tip farther from the tip frame is refused
MAX_NAME = 200  # characters of a name (a link, a sensor, a point)
MAX_NOISE = {"noise_m": 1.0, "noise_px": 1e3}
PYBULLET_ARMS = {  # --robot NAME: URDFs that ship with pybullet (pybullet_data), with their chain and tool
    "kuka_iiwa": ("kuka_iiwa/model.urdf", "lbr_iiwa_link_0", "lbr_iiwa_link_7"),
    "franka_panda": ("franka_panda/panda.urdf", "panda_link0", "panda_hand"),
}


@dataclass
class ArmDataset:
    path: Path
    meta: dict
    urdf_path: Path
    base: str
    tip: str  # several chains: their tips joined by '+'
    chain: object  # solver.robot.Chain; several chains (or a sensor on a link): a tuple of kinds.arm.model.ArmChain
    link_names: tuple  # the link each joint origin (and the tip offset) ends, for link_length.<link> (first chain)
    load: tuple  # (mass kg, com in the tip frame) hanging off the last joint by fixed joints
    sensors: tuple
    points: dict  # name -> (3,) in the tip frame, m
    observations: Observations
    gravity_mps2: tuple
    notes: list = None  # what the reader left out and why (printed by the commands)
    markers: dict = None  # corner point -> the printed marker it is a corner of (kinds.arm.model.ArmModel markers)
    sheets: dict = None  # marker -> the sheet it was printed on (its corners' `sheet`; ArmModel sheets)

    @property
    def joints(self) -> tuple:
        """Every joint the readings hold (several chains: their union, in order of appearance)."""
        if isinstance(self.chain, tuple):
            return tuple(dict.fromkeys(j for ac in self.chain for j in ac.chain.joint_names))
        return self.chain.joint_names


def resolve_robot(robot: str | None, chain: str | None):
    """(URDF path, base, tip) from --robot (a URDF file, or kuka_iiwa / franka_panda from pybullet_data) and
    --chain BASE_LINK:TIP_LINK (default for the named arms: their flange or hand). None for what was not given."""
    from naocal.solver.errors import NaocalError

    base = tip = None
    if chain is not None:
        if chain.count(":") != 1 or not all(chain.split(":")):
            raise NaocalError(f"--chain {chain!r}: expected BASE_LINK:TIP_LINK")
        base, tip = chain.split(":")
    if robot is None:
        return None, base, tip
    if robot in PYBULLET_ARMS:
        import pybullet_data

        rel, default_base, default_tip = PYBULLET_ARMS[robot]
        return Path(pybullet_data.getDataPath()) / rel, base or default_base, tip or default_tip
    path = Path(robot)
    if not path.is_file():
        raise NaocalError(f"--robot {robot!r}: no such URDF file (or one of {', '.join(PYBULLET_ARMS)})")
    return path, base, tip


def is_arm_dataset(path) -> bool:
    """Whether `path` is a directory whose dataset.json says naocal.arm_dataset/1 (anything unreadable: no)."""
    from naocal.solver.fileio import read_json

    try:  # a regular file only: a FIFO here must not block the check; the whole file (the key may come last)
        doc = read_json(Path(path) / "dataset.json")
    except DataError:
        return False
    return isinstance(doc, dict) and doc.get("schema") == SCHEMA


def arm_chain(urdf_path, base, tip, where_path):
    """(chain, link names, load) of a URDF's serial chain base -> tip, DataError naming the file otherwise."""
    from naocal.solver.robot import serial_chain
    from naocal.solver.urdf import parse_urdf

    urdf = parse_urdf(urdf_path)
    links = {j.child for j in urdf.joints.values()} | {j.parent for j in urdf.joints.values()}
    for name, link in (("base", base), ("tip", tip)):
        if link not in links:
            raise DataError(urdf_path, f"no link {link!r} (the chain's {name}) in the URDF")
    chain = serial_chain(urdf, base, tip, urdf_path, prismatic=True)
    if not chain.joint_names:
        raise DataError(urdf_path, f"no movable joint between {base!r} and {tip!r}")
    names = [urdf.joints[j].parent for j in chain.joint_names] + [urdf.joints[chain.joint_names[-1]].child]
    # what the last joint carries beyond its own link (a hand on fixed joints): its mass at its centre, tip frame
    last_child = urdf.joints[chain.joint_names[-1]].child
    load = (0.0, (0.0, 0.0, 0.0))
    if tip != last_child and tip in urdf.links:
        load = (urdf.links[tip].mass, urdf.links[tip].com)
    return chain, tuple(names), load


def arm_chains(urdf_path, specs: dict) -> tuple:
    """(ArmChain, ...) of {name: (base, tip)}: the chains of one URDF, sharing their joints by name."""
    from naocal.solver.urdf import parse_urdf

    urdf = parse_urdf(urdf_path)
    out = []
    for name, (base, tip) in specs.items():
        chain, link_names, load = arm_chain(urdf_path, base, tip, urdf_path)
        out.append(ArmChain(name, chain, link_names, load, tuple(urdf.joints[j].child for j in chain.joint_names)))
    return tuple(out)


def _name(value, path, field) -> str:
    """A link's, a sensor's, a point's or a chain's name."""
    return fields.text(value, path, field, max_chars=MAX_NAME, non_empty=True)


def _sensor(name, doc, path) -> Sensor:
    where = f"sensors.{name}"
    doc = fields.json_object(doc, path, where, ("kind",),
                             ("noise_m", "noise_px", "pose", "about", "distortion", "link") + INTRINSICS_KEYS)
    kind = fields.choice(doc["kind"], POINT_KINDS, path, f"{where}.kind")
    noise_key = "noise_m" if kind == "points" else "noise_px"
    wrong = "noise_px" if kind == "points" else "noise_m"
    if wrong in doc:
        fail(path, f"a {kind} sensor states its noise as {noise_key}", f"{where}.{wrong}")
    noise = fields.number(doc[noise_key], path, f"{where}.{noise_key}", positive=True,
                          limit=MAX_NOISE[noise_key]) if noise_key in doc else None
    intrinsics = None
    if kind == "camera":
        intrinsics = CameraIntrinsics.from_fields(doc, path, where).intrinsics()
    else:
        for key in INTRINSICS_KEYS + ("distortion",):
            if key in doc:
                fail(path, "only a camera has intrinsics", f"{where}.{key}")
    rotation = translation = None
    if "pose" in doc:
        pose = fields.json_object(doc["pose"], path, f"{where}.pose", ("rotation_rad", "translation_m"), ())
        rotation = fields.vector(pose["rotation_rad"], 3, path, f"{where}.pose.rotation_rad", limit=2 * math.pi)
        translation = fields.vector(pose["translation_m"], 3, path, f"{where}.pose.translation_m", limit=MAX_POINT_M)
    link = _name(doc["link"], path, f"{where}.link") if "link" in doc else None
    return Sensor(name, kind, intrinsics, noise, rotation, translation, link)


def read_arm_dataset(directory, *, robot: str | None = None, chain: str | None = None) -> ArmDataset:
    """Read a naocal.arm_dataset/1 directory. `robot` and `chain` (the CLI's --robot, --chain) win over the
    file's robot.urdf, robot.base, robot.tip."""
    directory = Path(directory)
    meta_path = directory / "dataset.json"
    if not directory.is_dir():
        fail(directory, "not a dataset directory")
    meta = read_json(meta_path)  # regular files only, size and nesting capped (solver/fileio.py)
    meta = fields.json_object(meta, meta_path, "", ("schema", "points", "sensors"),
                              ("robot", "chains", "gravity_mps2", "source", "about", "notes", "created"))
    if meta["schema"] != SCHEMA:
        fail(meta_path, f"wrong schema {str(meta['schema'])[:60]!r}, expected {SCHEMA!r}", "schema")
    robot_meta = fields.json_object(meta.get("robot", {}), meta_path, "robot", (),
                                    ("id", "model", "urdf", "base", "tip", "about"))
    for key in robot_meta:
        _name(robot_meta[key], meta_path, f"robot.{key}")
    urdf_path, base, tip = resolve_robot(robot, chain)
    if urdf_path is None:
        if "urdf" not in robot_meta:
            fail(meta_path, "no URDF: name it here (robot.urdf, beside dataset.json) or give --robot URDF", "robot.urdf")
        urdf_path = directory / robot_meta["urdf"]
    specs = _chain_specs(meta, robot_meta, base, tip, meta_path)
    points, markers, sheets = {}, {}, {}  # markers: corner -> the printed marker; sheets: corner -> its sheet
    for name, point in fields.json_object(meta["points"], meta_path, "points").items():
        _name(name, meta_path, "points")
        point = fields.json_object(point, meta_path, f"points.{name}", ("xyz_m",), ("xyz_m", "marker", "sheet", "about"))
        points[name] = fields.vector(point["xyz_m"], 3, meta_path, f"points.{name}.xyz_m")
        if "marker" in point:
            markers[name] = _name(point["marker"], meta_path, f"points.{name}.marker")
        if "sheet" in point:
            if "marker" not in point:
                fail(meta_path, "a sheet is a printed marker's: name the marker this corner is of (marker)",
                     f"points.{name}.sheet")
            sheets[name] = _name(point["sheet"], meta_path, f"points.{name}.sheet")
        if max(abs(v) for v in points[name]) > WORKSPACE_M:
            fail(meta_path, f"more than {WORKSPACE_M:.0f} m from the tip frame (millimetres? xyz_m is in m)",
                 f"points.{name}.xyz_m")
    if not points:
        fail(meta_path, "no points: name at least one point on the end effector", "points")
    for marker in dict.fromkeys(markers.values()):
        corners = [p for p, m in markers.items() if m == marker]
        if marker in points and marker not in markers:
            fail(meta_path, f"{marker!r} names both a point and a marker", f"points.{corners[0]}.marker")
        if len(corners) < 3:
            fail(meta_path, f"marker {marker!r} has {len(corners)} corner(s): its corners (3 or more, at their printed "
                 "positions) make it one rigid body", f"points.{corners[0]}.marker")
        named = {sheets.get(p) for p in corners}
        if len(named) > 1:  # one marker is printed on one sheet
            odd = next(p for p in corners if sheets.get(p) != sheets.get(corners[0]))
            fail(meta_path, f"marker {marker!r}'s corners name different sheets ({sheets.get(corners[0])!r}, "
                 f"{sheets.get(odd)!r}): a marker is printed on one sheet (name it on every corner)",
                 f"points.{odd}.sheet")
    sensors = tuple(_sensor(_name(name, meta_path, "sensors"), doc, meta_path)
                    for name, doc in fields.json_object(meta["sensors"], meta_path, "sensors").items())
    if not sensors:
        fail(meta_path, "no sensors", "sensors")
    several = "chains" in meta or any(s.link is not None for s in sensors)
    if several:
        chains = arm_chains(urdf_path, specs)
        kin_chain, link_names, load = chains, chains[0].link_names, chains[0].load
        base, tip = chains[0].chain.base, "+".join(ac.chain.tip for ac in chains)
        for s in sensors:  # a sensor's link must be the base or a link a joint of some chain moves
            if s.link is not None and not any(s.link == ac.chain.base or s.link in ac.child_links for ac in chains):
                fail(meta_path, f"no chain moves link {s.link!r} by a joint of its own (a sensor is mounted on the "
                     "chains' base or on the child link of one of their joints)", f"sensors.{s.name}.link")
    else:
        (base, tip), = specs.values()
        kin_chain, link_names, load = arm_chain(urdf_path, base, tip, meta_path)
        chains = (ArmChain(tip, kin_chain, link_names, load),)
    gravity = fields.vector(meta.get("gravity_mps2", [0.0, 0.0, -9.81]), 3, meta_path, "gravity_mps2", limit=13.0)
    if not 7.0 <= math.hypot(*gravity) <= 13.0:
        fail(meta_path, f"|g| = {math.hypot(*gravity):.4g} m/s^2: expected 7-13 (m/s^2, in the base frame)",
             "gravity_mps2")
    notes = []
    joints = tuple(dict.fromkeys(j for ac in chains for j in ac.chain.joint_names))
    obs = _read_observations(directory / "observations.csv", joints, sensors, tuple(points),
                             joint_limits(urdf_path, joints), notes, chains=chains if several else None,
                             slides={j for ac in chains for k, j in enumerate(ac.chain.joint_names)
                                     if ac.chain.prismatic and ac.chain.prismatic[k]})
    seen = sorted(set(obs.sensor.tolist()))
    if len(seen) < len(sensors):  # e.g. a camera named in dataset.json, but only tracker rows: left out, said so
        unused = [s.name for i, s in enumerate(sensors) if i not in seen]
        notes.append(f"{meta_path}: sensor(s) {', '.join(unused)} without observations left out")
        obs.sensor = np.searchsorted(seen, obs.sensor)
        sensors = tuple(sensors[i] for i in seen)
    return ArmDataset(directory, meta, Path(urdf_path), base, tip, kin_chain, link_names, load, sensors, points, obs,
                      gravity, notes, markers, {markers[p]: sheet for p, sheet in sheets.items()})


def _chain_specs(meta, robot_meta, base, tip, meta_path) -> dict:
    """{chain name: (base, tip)}: dataset.json's `chains`, else the one chain of --chain or robot.base/robot.tip
    (named by its tip)."""
    if "chains" not in meta:
        base = base or robot_meta.get("base")
        tip = tip or robot_meta.get("tip")
        if not base or not tip:
            fail(meta_path, "no chain: name robot.base and robot.tip (or chains) here or give --chain "
                 "BASE_LINK:TIP_LINK", "robot.base" if not base else "robot.tip")
        return {tip: (base, tip)}
    if base or tip:
        fail(meta_path, "the dataset names its chains: --chain picks none of them", "chains")
    for key in ("base", "tip"):
        if key in robot_meta:
            fail(meta_path, "the chains are named in `chains`: robot.base and robot.tip are for one chain",
                 f"robot.{key}")
    specs = {}
    for name, doc in fields.json_object(meta["chains"], meta_path, "chains").items():
        _name(name, meta_path, "chains")
        doc = fields.json_object(doc, meta_path, f"chains.{name}", ("base", "tip"), ("base", "tip", "about"))
        specs[name] = (_name(doc["base"], meta_path, f"chains.{name}.base"),
                       _name(doc["tip"], meta_path, f"chains.{name}.tip"))
    if not specs:
        fail(meta_path, "no chains: name at least one {\"base\": LINK, \"tip\": LINK}", "chains")
    first = next(iter(specs.values()))[0]
    for name, (b, _) in specs.items():
        if b != first:
            fail(meta_path, f"every chain starts at one base (the first at {first!r}), not {b!r}",
                 f"chains.{name}.base")
    return specs


def joint_limits(urdf_path, joints) -> dict:
    """{joint: (lower, upper)} of the URDF's revolute (rad) and prismatic (m) joints among `joints` (continuous ones
    have none)."""
    from naocal.solver.urdf import parse_urdf

    urdf = parse_urdf(urdf_path)
    return {j: (urdf.joints[j].lower, urdf.joints[j].upper) for j in joints
            if urdf.joints[j].kind in ("revolute", "prismatic")
            and math.isfinite(urdf.joints[j].lower + urdf.joints[j].upper)}


def _comment_free_lines(text):
    """The file's lines with comment lines ('#' first) and blank lines emptied (line numbers kept)."""
    return ["" if not line.strip() or line.lstrip().startswith("#") else line
            for line in text.splitlines(keepends=True)]


def _read_observations(path, joints, sensors, points, limits=None, notes=None, *, chains=None,
                       slides=frozenset()) -> Observations:
    """The rows of observations.csv (docs/FORMATS.md); `limits` {joint: (lower, upper)} rad (m for the prismatic
    `slides`) from the URDF; what was skipped goes to `notes`. `chains` (ArmChain, ...): each row's chain (the
    `chain` column; needed when there are several), its joints' readings needed, its sensor mounted where it sees
    that chain."""
    notes = [] if notes is None else notes
    lines = _comment_free_lines(read_text(path))  # regular files only, at most 64 MiB (solver/fileio.py)
    first = next((i for i, line in enumerate(lines) if line), None)
    if first is None:
        fail(path, "empty file: no header row", line=1)
    delimiter = next((d for d in DELIMITERS if d in lines[first]), ",")
    decimal_comma = delimiter == ";"
    reader = csv.reader(io.StringIO("".join(lines), newline=""), delimiter=delimiter)
    try:
        header = next(row for row in reader if row and any(cell.strip() for cell in row))
    except csv.Error as err:
        fail(path, f"malformed CSV: {err}", line=first + 1)
    header_line = reader.line_num
    header = [h.strip() for h in header]
    seen = set()
    for h in header:
        if h in seen:
            fail(path, "column named twice", field=h, line=header_line)
        seen.add(h)
    col = {h: i for i, h in enumerate(header)}
    for required, names in (("sensor", [s.name for s in sensors]), ("point", list(points))):
        if required not in col and len(names) != 1:
            fail(path, f"missing column (needed when dataset.json names more than one {required})", field=required,
                 line=header_line)
    if chains is not None and len(chains) > 1 and "chain" not in col:
        fail(path, "missing column (needed when dataset.json names more than one chain)", field="chain",
             line=header_line)
    joint_cols = []
    for joint in joints:
        units = SLIDE_UNITS if joint in slides else JOINT_UNITS
        found = [(joint + suffix, factor) for suffix, factor in units.items() if joint + suffix in col]
        if len(found) > 1:
            fail(path, f"joint {joint} given twice ({found[0][0]}, {found[1][0]})", field=joint, line=header_line)
        if not found:
            a, b = (f"{joint}{u}" for u in units)
            hint = f" (a column {joint!r} needs its unit: {a} or {b})" if joint in col else ""
            fail(path, f"missing the column of chain joint {joint}: {a} or {b}{hint}", field=joint,
                 line=header_line)
        joint_cols.append((col[found[0][0]], found[0][1], found[0][0], joint))
    chain_index = {ac.name: c for c, ac in enumerate(chains or ())}
    chain_joints = [set(ac.chain.joint_names) for ac in chains or ()]
    point_chain = {}  # point -> (chain, first line): a point is on one chain's tool
    units = [suffix for suffix in POINT_UNITS if all(f"{a}{suffix}" in col for a in "xyz")]
    if len(units) > 1:
        fail(path, "the 3-D point is given twice (x_m and x_mm columns)", field="x_mm", line=header_line)
    xyz_cols = ([col[f"{a}{units[0]}"] for a in "xyz"], POINT_UNITS[units[0]], units[0]) if units else None
    sensor_index = {s.name: i for i, s in enumerate(sensors)}
    point_index = {p: i for i, p in enumerate(points)}
    pose_col, session_col = col.get("pose"), col.get("session")
    if session_col is not None and pose_col is None:
        fail(path, "a session column needs a pose column (a session is a set of poses)", field="session",
             line=header_line)
    theta, pose, sensor, point, measured, rows_read, row_chain = [], [], [], [], [], [], []
    session, session_of_pose = [], {}  # pose label -> (its session, first line): a pose is in one session
    unseen = 0
    line = header_line

    def number(text, field):
        return _cell(text.replace(",", ".") if decimal_comma else text, path, line, field)

    try:
        for row in reader:
            line = reader.line_num
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                fail(path, f"expected {len(header)} cells, got {len(row)}", line=line)
            row = [cell.strip() for cell in row]
            name = row[col["sensor"]] if "sensor" in col else sensors[0].name
            if name not in sensor_index:
                fail(path, f"unknown sensor {name[:40]!r} (dataset.json has {', '.join(sensor_index)})",
                     field="sensor", line=line)
            s = sensor_index[name]
            pname = row[col["point"]] if "point" in col else next(iter(points))
            if pname not in point_index:
                fail(path, f"unknown point {pname[:40]!r} (dataset.json has {', '.join(point_index)})",
                     field="point", line=line)
            row_c = 0
            if chains is not None:
                cname = row[col["chain"]] if "chain" in col else chains[0].name
                if cname not in chain_index:
                    fail(path, f"unknown chain {cname[:40]!r} (dataset.json has {', '.join(chain_index)})",
                         field="chain", line=line)
                row_c = chain_index[cname]
                ac, link = chains[row_c], sensors[s].link
                if link is not None and link != ac.chain.base and link not in ac.child_links:
                    fail(path, f"sensor {name} is mounted on {link!r}, which chain {cname} does not carry: it "
                         "cannot see that chain's points", field="sensor", line=line)
                first = point_chain.setdefault(pname, (cname, line))
                if first[0] != cname:
                    fail(path, f"point {pname} is on chain {first[0]} (line {first[1]}), here on {cname}: a point "
                         "is on one chain's tool", field="chain", line=line)
            if sensors[s].kind == "points":
                if xyz_cols is None:
                    fail(path, f"a 3-D sensor's row ({name}) needs the columns x_m, y_m, z_m (or x_mm, y_mm, z_mm)",
                         field="x_m", line=line)
                cols, factor, suffix = xyz_cols
                cells = [(row[i], f"{a}{suffix}") for i, a in zip(cols, "xyz")]
            else:
                for c in PIXEL_COLUMNS:
                    if c not in col:
                        fail(path, f"a camera's row ({name}) needs the columns u_px, v_px", field=c, line=line)
                cells = [(row[col[c]], c) for c in PIXEL_COLUMNS]
            if all(text in MISSING for text, _ in cells):  # not seen at this pose: no observation
                unseen += 1
                continue
            values = [number(text, field) for text, field in cells]
            if sensors[s].kind == "points":
                values = [v * xyz_cols[1] for v in values]
                far = max(range(3), key=lambda a: abs(values[a]))
                if abs(values[far]) > MAX_POINT_M:
                    fail(path, f"a 3-D reading {abs(values[far]):.4g} m from its sensor (more than {MAX_POINT_M:.0f} "
                         "m: millimetres in an _m column?)", field=cells[far][1], line=line)
            else:
                k = sensors[s].intrinsics
                if not (-k["width_px"] <= values[0] <= 2 * k["width_px"]
                        and -k["height_px"] <= values[1] <= 2 * k["height_px"]):
                    fail(path, f"pixel ({values[0]:.6g}, {values[1]:.6g}) is beyond one image size of camera "
                         f"{name}'s {k['width_px']:.0f} x {k['height_px']:.0f} image", field="u_px", line=line)
                values.append(0.0)
            reading = []
            for i, factor, field, joint in joint_cols:
                if chains is not None and joint not in chain_joints[row_c] and row[i] in MISSING:
                    reading.append(0.0)  # a joint off this row's chain: not read, not used
                    continue
                angle = number(row[i], field) * factor
                lower, upper = (limits or {}).get(joint, (math.nan, math.nan))
                if joint in slides:
                    if not lower - SLIDE_MARGIN <= angle <= upper + SLIDE_MARGIN and math.isfinite(lower + upper):
                        hint = " (millimetres in a _m column?)" if field.endswith("_m") else ""
                        fail(path, f"reading {angle * 1e3:.4g} mm is beyond the URDF's limits {lower * 1e3:.4g}.."
                             f"{upper * 1e3:.4g} mm by more than {SLIDE_MARGIN * 1e3:.0f} mm{hint}",
                              field=field, line=line)
                elif not lower - ANGLE_MARGIN <= angle <= upper + ANGLE_MARGIN and math.isfinite(lower + upper):
                    hint = " (degrees in a _rad column?)" if field.endswith("_rad") else ""
                    fail(path, f"reading {math.degrees(angle):.4g} deg is beyond the URDF's limits "
                         f"{math.degrees(lower):.4g}..{math.degrees(upper):.4g} deg by more than 10 deg{hint}",
                          field=field, line=line)
                reading.append(angle)
            if pose_col is not None:
                if not row[pose_col]:
                    fail(path, "empty cell: the pose column needs a value on every row", field="pose", line=line)
                pose.append(row[pose_col])
            if session_col is not None:
                if not row[session_col]:
                    fail(path, "empty cell: the session column needs a value on every row", field="session",
                         line=line)
                first = session_of_pose.setdefault(row[pose_col], (row[session_col], line))
                if first[0] != row[session_col]:
                    fail(path, f"pose {row[pose_col][:40]} is in session {first[0][:40]} (line {first[1]}), here in "
                         f"{row[session_col][:40]}: a pose is in one session", field="session", line=line)
                session.append(row[session_col])
            theta.append(reading)
            measured.append(values)
            sensor.append(s)
            point.append(point_index[pname])
            rows_read.append(line)
            row_chain.append(row_c)
    except csv.Error as err:
        fail(path, f"malformed CSV: {err}", line=line + 1)
    if unseen:
        notes.append(f"{path}: {unseen} row(s) without a measurement (empty or nan: not seen) left out")
    if not theta:
        fail(path, "no observations", line=header_line + 1)
    theta = np.array(theta, dtype=float)
    pose_labels = None
    if pose_col is None:  # rows with the same joint readings are one pose
        _, pose = np.unique(theta, axis=0, return_inverse=True)
    else:  # integers as they are; other labels numbered in order of appearance, kept for the reports
        try:
            pose = [int(p) for p in pose]
        except ValueError:
            labels = {}
            pose = [labels.setdefault(p, len(labels)) for p in pose]
            pose_labels = tuple(labels)
    session_labels = tuple(dict.fromkeys(session)) if session_col is not None else None
    return Observations(theta, np.asarray(pose, dtype=np.int64).ravel(), np.array(sensor), np.array(point),
                        np.array(measured, dtype=float).reshape(-1, 3), np.array(rows_read), pose_labels,
                        None if chains is None else np.array(row_chain, dtype=int),
                        None if session_labels is None else np.array([session_labels.index(v) for v in session]),
                        session_labels)


def _cell(text, path, line, field) -> float:
    if not text:
        fail(path, "empty cell: this row's sensor needs a value here", field=field, line=line)
    return fields.number_text(text, path, field, line=line)


def write_arm_dataset(directory, meta: dict, joints, obs: Observations, sensors, points, *, chain_names=None,
                      slides=()) -> None:
    """Write dataset.json and observations.csv (joints in rad, prismatic `slides` in m, points in m, pixels)
    atomically; with `chain_names` (several chains) each row's chain in a `chain` column; each row's session in a
    `session` column when the observations have sessions."""
    from naocal.solver.fileio import atomic_write_text

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    sessions = obs.session is not None
    header = (["pose"] + (["session"] if sessions else []) + (["chain"] if chain_names else []) + ["sensor", "point"]
              + [f"{j}_m" if j in slides else f"{j}_rad" for j in joints] + ["x_m", "y_m", "z_m", "u_px", "v_px"])
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    names = [s.name for s in sensors]
    point_names = list(points)
    row_chain = obs.chains()
    for i in range(len(obs)):
        s = sensors[obs.sensor[i]]
        m = obs.measured[i]
        values = [repr(float(v)) for v in m[:3]] + ["", ""] if s.kind == "points" else \
            ["", "", ""] + [repr(float(v)) for v in m[:2]]
        chain = [chain_names[row_chain[i]]] if chain_names else []
        session = [obs.session_labels[obs.session[i]]] if sessions else []
        writer.writerow([obs.pose_name(obs.pose[i])] + session + chain + [names[obs.sensor[i]],
                                                                          point_names[obs.point[i]]]
                        + [repr(float(v)) for v in obs.theta[i]] + values)
    atomic_write_text(directory / "observations.csv", out.getvalue())
    atomic_write_text(directory / "dataset.json", json.dumps(dict(meta, schema=SCHEMA), indent=1) + "\n")
