"""The robot description: what naocal knows about a robot, from its URDF plus a small documented config.

A description (`solver/data/nao.json` for the NAO; the format is docs/ROBOT.md) names
- `joints`: the joints a dataset reads, in its column order;
- `shared_motors`: joints driven by one motor and read by one sensor (the NAO's two HipYawPitch joints);
- `chains`: named serial chains, each from a URDF base link to a tip link (any serial chain of the URDF works);
- `cameras`: each camera's frame (a URDF link, NAO camera convention: x optical axis, y left, z up), prior
  intrinsics, image size and rolling-shutter readout time (a documented prior: the model treats images as global
  shutter, so the robot must be still while one is exposed);
- `targets`: boards (columns x rows squares of square_m, colours, mass) attached to a URDF frame at a nominal pose,
  with `load` saying whether the chain to that frame hangs free (its distal links and the board load its joints:
  the robot on its back with sandals) or carries the body (a standing robot's support foot);
- `gravity_mps2`: the default gravity in the base frame (per image in a dataset, when it says so).

Everything else (joint origins, axes, masses, centres of mass) comes from the URDF. Nothing in the solver knows
more about a NAO than this file says.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from naocal.solver import fields
from naocal.solver.camera import CameraIntrinsics
from naocal.solver.errors import DataError
from naocal.solver.fileio import read_json
from naocal.solver.transforms import make_transform, rot_rpy
from naocal.solver.urdf import Urdf, parse_urdf

SCHEMA = "naocal.robot/1"
DATA_DIR = Path(__file__).with_name("data")
MOVABLE = ("revolute", "continuous")
LOADS = ("hanging", "supporting")


@dataclass(frozen=True)
class Chain:
    """Movable joints from a base link to a tip link, fixed joints folded into their neighbours.

    T_origin[k] is the pose of joint k's frame in the frame before it (the previous joint's child frame, or the
    base), before rotating about axes[k]; T_end is the tip's pose in the last joint's child frame (in the base
    frame when the chain has no movable joint). link_mass[k] and link_com[k] (in joint k's child frame) describe
    the URDF link joint k moves (links hanging off it through fixed joints, 2 mg sensor frames on the NAO, are
    not counted).
    """

    base: str
    tip: str
    joint_names: tuple[str, ...]
    T_origin: np.ndarray  # (k, 4, 4)
    axes: np.ndarray  # (k, 3) unit axes in the joint frames
    T_end: np.ndarray  # (4, 4)
    link_mass: np.ndarray  # (k,) kg
    link_com: np.ndarray  # (k, 3) m
    prismatic: tuple = ()  # per joint: True for a prismatic joint (it slides along axes[k]); () none is

    def index(self, joint: str) -> int:
        return self.joint_names.index(joint)


@dataclass(frozen=True)
class Board:
    """A checkerboard: columns x rows squares of square_m; (columns - 1) x (rows - 1) inner vertices."""

    columns: int
    rows: int
    square_m: float
    colours: tuple[str, str] = ("black", "white")
    mass_kg: float = 0.0

    @property
    def n_vertices(self) -> int:
        return (self.columns - 1) * (self.rows - 1)

    def vertices(self) -> np.ndarray:
        """Inner vertices in the board frame (origin at the board centre, z = 0 on the printed face), (n, 3).

        Vertex index = row * (columns - 1) + col; col counts along +x of the board, row along +y; vertex 0 has the
        smallest x and y.
        """
        cols = np.arange(self.columns - 1) - (self.columns - 2) / 2.0
        rows = np.arange(self.rows - 1) - (self.rows - 2) / 2.0
        xx, yy = np.broadcast_arrays(cols[None, :] * self.square_m, rows[:, None] * self.square_m)
        return np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], axis=-1)


@dataclass(frozen=True)
class Target:
    """A board attached to a URDF frame (`frame`) at the nominal pose T_frame_board."""

    name: str
    frame: str
    board: Board
    T_frame_board: np.ndarray  # (4, 4)
    load: str = "hanging"  # "hanging": the chain to `frame` hangs free; "supporting": it carries the body
    about: str = ""

    def vertices(self) -> np.ndarray:
        """Nominal inner vertices in the target's frame (`frame`), (n, 3), in the board's vertex order."""
        V = self.board.vertices()
        return V @ self.T_frame_board[:3, :3].T + self.T_frame_board[:3, 3]

    @property
    def centre(self) -> np.ndarray:
        """The board centre in the target's frame (where its mass acts), (3,)."""
        return self.T_frame_board[:3, 3].copy()


@dataclass(frozen=True)
class Camera(CameraIntrinsics):
    """A camera: its prior intrinsics (solver.camera.CameraIntrinsics, `intrinsics()` the dict), its name, its URDF
    frame (NAO camera convention) and its rolling-shutter readout. Made with keywords."""

    # required: None only because fields after CameraIntrinsics' defaults need one (kw_only=True is Python 3.10+,
    # and this module runs on the Duckiebot's Python 3.8: docs/DEPLOY.md)
    name: str = None
    frame: str = None
    readout_s: float = 0.0  # rolling shutter: time between the first and the last row's exposure (prior)

    def __post_init__(self):
        for field_name in ("name", "frame"):
            if getattr(self, field_name) is None:
                raise TypeError(f"Camera() missing required keyword argument: {field_name!r}")


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: one object per loaded file
class RobotDescription:
    name: str
    path: Path
    urdf: Urdf
    base: str
    joints: tuple[str, ...]
    shared_motors: tuple[tuple[str, ...], ...]
    chains: dict  # name -> (base link, tip link)
    cameras: dict  # name -> Camera
    targets: dict  # name -> Target
    default_cameras: tuple[str, ...]
    default_targets: tuple[str, ...]
    gravity_mps2: tuple[float, float, float]
    link_lengths: dict = field(default_factory=dict)  # "<chain label>.<link>" -> joint whose origin it lengthens
    command_limits: dict = field(default_factory=dict)  # joint -> (lower, upper) rad naocal commands it within

    # -- chains

    def chain(self, tip: str, base: str | None = None) -> Chain:
        """The serial chain from `base` (default: the description's base link) to the URDF link `tip`."""
        return _chain(self, base or self.base, tip)

    def named_chain(self, name: str) -> Chain:
        base, tip = self.chains[name]
        return self.chain(tip, base)

    def camera_chain(self, camera: str) -> Chain:
        return self.chain(self.camera(camera).frame)

    def target_chain(self, target: str) -> Chain:
        return self.chain(self.target(target).frame)

    # -- look-ups with clear errors

    def camera(self, name: str) -> Camera:
        try:
            return self.cameras[name]
        except KeyError:
            raise DataError(self.path, f"unknown camera {name!r} (this robot has {', '.join(self.cameras)})",
                            field="cameras") from None

    def target(self, name: str) -> Target:
        try:
            return self.targets[name]
        except KeyError:
            raise DataError(self.path, f"unknown target {name!r} (this robot has {', '.join(self.targets)})",
                            field="targets") from None

    def joint_limits(self, joint: str) -> tuple[float, float]:
        j = self.urdf.joints[joint]
        return j.lower, j.upper

    def motor_partner(self, joint: str) -> str | None:
        """The first joint of `joint`'s shared motor when it is not `joint` itself (the one it follows), else None."""
        for group in self.shared_motors:
            if joint in group and joint != group[0]:
                return group[0]
        return None


# ------------------------------------------------------------------------------------------------ chains


def _joint_origin(joint) -> np.ndarray:
    return make_transform(rot_rpy(*joint.rpy), joint.xyz)


@functools.lru_cache(maxsize=None)
def _chain(robot: RobotDescription, base: str, tip: str) -> Chain:
    return serial_chain(robot.urdf, base, tip, robot.path)


def serial_chain(urdf: Urdf, base: str, tip: str, path="URDF", *, prismatic: bool = False) -> Chain:
    """The serial chain of `urdf` from link `base` to link `tip`; DataError naming `path` when there is none.
    prismatic: accept prismatic joints (the arm's model has them; the NAO's has none)."""
    movable = MOVABLE + (("prismatic",) if prismatic else ())
    by_child = {j.child: j for j in urdf.joints.values()}
    path_joints = []
    link = tip
    while link != base:
        joint = by_child.get(link)
        if joint is None:
            raise DataError(path, f"no chain from {base!r} to {tip!r} in the URDF (stopped at {link!r})",
                            field="chains")
        if joint.kind not in movable + ("fixed",):
            raise DataError(path, f"joint {joint.name!r} is {joint.kind}: only {', '.join(movable)} and "
                                        "fixed joints are supported", field="chains")
        path_joints.append(joint)
        link = joint.parent
    path_joints.reverse()
    names, origins, axes, masses, coms, sliding = [], [], [], [], [], []
    pending = np.eye(4)  # fixed transforms since the last movable joint
    for joint in path_joints:
        pending = pending @ _joint_origin(joint)
        if joint.kind == "fixed":
            continue
        names.append(joint.name)
        origins.append(pending)
        axes.append(joint.axis)
        sliding.append(joint.kind == "prismatic")
        child = urdf.links.get(joint.child)
        masses.append(child.mass if child is not None else 0.0)
        coms.append(child.com if child is not None else (0.0, 0.0, 0.0))
        pending = np.eye(4)
    k = len(names)
    return Chain(base=base, tip=tip, joint_names=tuple(names),
                 T_origin=np.stack(origins) if k else np.zeros((0, 4, 4)),
                 axes=np.array(axes, dtype=float).reshape(k, 3), T_end=pending,
                 link_mass=np.array(masses, dtype=float), link_com=np.array(coms, dtype=float).reshape(k, 3),
                 prismatic=tuple(sliding) if any(sliding) else ())


# ------------------------------------------------------------------------------------------------ loading


def _link(urdf: Urdf, name, path, where) -> str:
    links = {j.child for j in urdf.joints.values()} | {j.parent for j in urdf.joints.values()}
    if not isinstance(name, str) or name not in links:
        fields.fail(path, f"no link {name!r} in the URDF", where)
    return name


def parse_robot(doc, path) -> RobotDescription:
    """A RobotDescription from a `naocal.robot/1` document; DataError naming the file and field otherwise."""
    doc = fields.json_object(doc, path, "", ("schema", "name", "urdf", "base", "joints", "cameras", "targets"),
                             ("about", "shared_motors", "chains", "link_lengths", "default_cameras", "default_targets",
                              "gravity_mps2", "command_limits_rad"))
    if doc["schema"] != SCHEMA:
        fields.fail(path, f"wrong schema {doc['schema']!r}, expected {SCHEMA!r}", "schema")
    if not isinstance(doc["urdf"], str) or "/" in doc["urdf"] or doc["urdf"].startswith("."):
        fields.fail(path, "expected the name of a URDF file beside this one", "urdf")
    urdf = parse_urdf(Path(path).with_name(doc["urdf"]))
    base = _link(urdf, doc["base"], path, "base")
    joints = fields.names(doc["joints"], path, "joints")
    for i, joint in enumerate(joints):
        if joint not in urdf.joints or urdf.joints[joint].kind not in MOVABLE:
            fields.fail(path, f"{joint!r} is not a revolute joint of the URDF", f"joints[{i}]")
    shared = []
    for i, group in enumerate(doc.get("shared_motors", [])):
        group = fields.names(group, path, f"shared_motors[{i}]")
        if len(group) < 2 or any(j not in joints for j in group):
            fields.fail(path, "expected two or more joints of `joints`", f"shared_motors[{i}]")
        shared.append(group)
    chains = {}
    for name, chain in fields.json_object(doc.get("chains", {}), path, "chains").items():
        chain = fields.json_object(chain, path, f"chains.{name}", ("base", "tip"), ())
        chains[name] = (_link(urdf, chain["base"], path, f"chains.{name}.base"),
                        _link(urdf, chain["tip"], path, f"chains.{name}.tip"))
    link_lengths = {}
    for name, joint in fields.json_object(doc.get("link_lengths", {}), path, "link_lengths").items():
        if joint not in joints:
            fields.fail(path, f"{joint!r} is not one of `joints`", f"link_lengths.{name}")
        link_lengths[name] = joint
    command_limits = {}
    for name, bounds in fields.json_object(doc.get("command_limits_rad", {}), path, "command_limits_rad").items():
        where = f"command_limits_rad.{name}"
        if name not in joints:
            fields.fail(path, f"{name!r} is not one of `joints`", where)
        lower, upper = fields.vector(bounds, 2, path, where)
        if not lower < upper:
            fields.fail(path, "expected [lower, upper] with lower < upper", where)
        command_limits[name] = (lower, upper)
    cameras = {}
    for name, cam in fields.json_object(doc["cameras"], path, "cameras").items():
        where = f"cameras.{name}"
        cam = fields.json_object(cam, path, where, ("frame", "width_px", "height_px", "fx_px", "fy_px", "cx_px",
                                                    "cy_px"), ("distortion", "readout_s"))
        cameras[name] = Camera(
            name=name, frame=_link(urdf, cam["frame"], path, f"{where}.frame"),
            width_px=int(fields.number(cam["width_px"], path, f"{where}.width_px", positive=True, integer=True)),
            height_px=int(fields.number(cam["height_px"], path, f"{where}.height_px", positive=True, integer=True)),
            fx_px=fields.number(cam["fx_px"], path, f"{where}.fx_px", positive=True),
            fy_px=fields.number(cam["fy_px"], path, f"{where}.fy_px", positive=True),
            cx_px=fields.number(cam["cx_px"], path, f"{where}.cx_px"),
            cy_px=fields.number(cam["cy_px"], path, f"{where}.cy_px"),
            distortion=fields.vector(cam.get("distortion", [0.0] * 5), 5, path, f"{where}.distortion"),
            readout_s=fields.number(cam.get("readout_s", 0.0), path, f"{where}.readout_s", non_negative=True))
    targets = {}
    for name, tgt in fields.json_object(doc["targets"], path, "targets").items():
        where = f"targets.{name}"
        tgt = fields.json_object(tgt, path, where, ("frame", "board", "pose"), ("about", "load"))
        board = fields.json_object(tgt["board"], path, f"{where}.board", ("columns", "rows", "square_m"),
                                   ("colours", "mass_kg"))
        size = [int(fields.number(board[k], path, f"{where}.board.{k}", positive=True, integer=True))
                for k in ("columns", "rows")]
        if min(size) < 2:
            fields.fail(path, "a board needs at least 2 squares each way", f"{where}.board")
        colours = fields.names(board.get("colours", ["black", "white"]), path, f"{where}.board.colours")
        pose = fields.json_object(tgt["pose"], path, f"{where}.pose", ("xyz", "rpy"), ())
        load = fields.choice(tgt.get("load", "hanging"), LOADS, path, f"{where}.load")
        targets[name] = Target(
            name=name, frame=_link(urdf, tgt["frame"], path, f"{where}.frame"),
            board=Board(size[0], size[1],
                        fields.number(board["square_m"], path, f"{where}.board.square_m", positive=True),
                        tuple(colours), fields.number(board.get("mass_kg", 0.0), path, f"{where}.board.mass_kg",
                                                      non_negative=True)),
            T_frame_board=make_transform(rot_rpy(*fields.vector(pose["rpy"], 3, path, f"{where}.pose.rpy")),
                                         fields.vector(pose["xyz"], 3, path, f"{where}.pose.xyz")),
            load=load, about=str(tgt.get("about", "")))
    default_cameras = fields.names(doc.get("default_cameras", list(cameras)[:1]), path, "default_cameras")
    default_targets = fields.names(doc.get("default_targets", list(targets)), path, "default_targets")
    for where, names, known in (("default_cameras", default_cameras, cameras),
                                ("default_targets", default_targets, targets)):
        for n in names:
            if n not in known:
                fields.fail(path, f"{n!r} is not defined", where)
    robot = RobotDescription(
        name=str(doc["name"]), path=Path(path), urdf=urdf, base=base, joints=joints, shared_motors=tuple(shared),
        chains=chains, cameras=cameras, targets=targets, default_cameras=default_cameras,
        default_targets=default_targets,
        gravity_mps2=fields.vector(doc.get("gravity_mps2", [0.0, 0.0, -9.81]), 3, path, "gravity_mps2"),
        link_lengths=link_lengths, command_limits=command_limits)
    for name, cam in cameras.items():  # every frame must hang off the base by a serial chain
        robot.camera_chain(name)
    for name in targets:
        robot.target_chain(name)
    return robot


def load_robot(name_or_path) -> RobotDescription:
    """A robot description by name ('nao': solver/data/nao.json) or by the path of its JSON file."""
    path = DATA_DIR / f"{name_or_path}.json" if "/" not in str(name_or_path) and not str(
        name_or_path).endswith(".json") else Path(name_or_path)
    return _load(str(path))


@functools.lru_cache(maxsize=8)
def _load(path: str) -> RobotDescription:
    return parse_robot(read_json(path), path)  # regular files only, size and nesting capped, no key twice


def nao() -> RobotDescription:
    """The NAO (solver/data/nao.json)."""
    return load_robot("nao")


def default_intrinsics(camera: str | None = None, robot: RobotDescription | None = None) -> dict:
    """The prior intrinsics of a camera of a robot description (default: the NAO's first default camera)."""
    robot = robot or nao()
    return robot.camera(camera or robot.default_cameras[0]).intrinsics()
