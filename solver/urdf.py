"""Read the nominal NAO geometry from the URDF shipped in solver/data (a copy of ../shared/reference/nao_v50.urdf).

Only kinematics and inertias are used; the URDF's meshes are not available and are ignored.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solver.errors import DataError

NOMINAL_URDF = Path(__file__).with_name("data") / "nao_v50.urdf"


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: str  # "revolute" or "fixed"
    parent: str
    child: str
    xyz: tuple[float, float, float]  # origin translation in the parent link frame, m
    rpy: tuple[float, float, float]  # origin rotation, fixed-axis roll, pitch, yaw, rad
    axis: tuple[float, float, float]  # unit rotation axis in the child frame (normalised here: the file rounds it)
    lower: float = float("nan")  # rad
    upper: float = float("nan")  # rad
    velocity: float = float("nan")  # rad/s
    effort: float = float("nan")  # N m


@dataclass(frozen=True)
class UrdfLink:
    name: str
    mass: float  # kg
    com: tuple[float, float, float]  # centre of mass in the link frame, m


@dataclass(frozen=True)
class Urdf:
    joints: dict[str, UrdfJoint]
    links: dict[str, UrdfLink]

    def joint_by_child(self, child: str) -> UrdfJoint:
        for joint in self.joints.values():
            if joint.child == child:
                return joint
        raise KeyError(child)


def _floats(text: str | None, default: str) -> tuple[float, ...]:
    return tuple(float(x) for x in (text or default).split())


def parse_urdf(path=NOMINAL_URDF) -> Urdf:
    """Joints and link inertias of a URDF file; a malformed file raises DataError naming it and the element."""
    from solver.fileio import read_bytes

    data = read_bytes(path)  # a regular file only (a FIFO would block the parser), size capped
    try:
        root = ET.fromstring(data)
    except ET.ParseError as err:
        raise DataError(path, f"cannot read the robot model: {err}") from None
    joints = {}
    for element in root.findall("joint"):
        try:
            joints[element.get("name")] = _parse_joint(element)
        except (AttributeError, TypeError, ValueError) as err:
            raise DataError(path, f"malformed joint: {err}", field=element.get("name")) from None
    links = {}
    for element in root.findall("link"):
        try:
            link = _parse_link(element)
        except (AttributeError, TypeError, ValueError) as err:
            raise DataError(path, f"malformed link: {err}", field=element.get("name")) from None
        if link is not None:
            links[link.name] = link
    return Urdf(joints=joints, links=links)


def _parse_joint(element) -> UrdfJoint:
    origin = element.find("origin")
    axis_element = element.find("axis")
    axis = np.array(_floats(axis_element.get("xyz") if axis_element is not None else None, "1 0 0"))
    norm = np.linalg.norm(axis)
    axis = tuple(float(a) for a in axis / norm) if norm > 0 else (0.0, 0.0, 0.0)
    limit = element.find("limit")
    limits = {}
    if limit is not None:
        limits = {key: float(limit.get(key, "nan")) for key in ("lower", "upper", "velocity", "effort")}
    return UrdfJoint(
        name=element.get("name"),
        kind=element.get("type"),
        parent=element.find("parent").get("link"),
        child=element.find("child").get("link"),
        xyz=_floats(origin.get("xyz") if origin is not None else None, "0 0 0"),
        rpy=_floats(origin.get("rpy") if origin is not None else None, "0 0 0"),
        axis=axis,
        **limits,
    )


def _parse_link(element) -> UrdfLink | None:
    inertial = element.find("inertial")
    if inertial is None or inertial.find("mass") is None:
        return None
    origin = inertial.find("origin")
    return UrdfLink(
        name=element.get("name"),
        mass=float(inertial.find("mass").get("value")),
        com=_floats(origin.get("xyz") if origin is not None else None, "0 0 0"),
    )


@functools.lru_cache(maxsize=1)
def nominal_urdf() -> Urdf:
    return parse_urdf(NOMINAL_URDF)
