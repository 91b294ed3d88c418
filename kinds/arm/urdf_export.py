"""An arm's calibration as a corrected URDF (`naocal offsets export CAL --format urdf`, docs/ARM.md).

The arm's URDF with the calibration written into its joint origins, so that any URDF reader's forward kinematics
at the joint READINGS gives the calibrated pose (kinds/arm/model.py's model):

- link_length.<link> L: the chain's origin ending that link moves by L along its offset. The origin may be folded
  from several joints (fixed joints before a revolute one, or between the last revolute joint and the tip); the
  first of them gets the shift, expressed in its parent's frame, which is the frame the folded offset is in.
- link_pose.<link>.{x,y,z,rx,ry,rz}: T_origin @ Trans(t) @ Exp(r), on the revolute joint itself.
- joint_offset.<joint> c: q_true = theta - c, so T_origin @ Rot(axis, theta - c) = (T_origin @ Rot(axis, -c)) @
  Rot(axis, theta): the joint's origin turns by -c about its axis. The joint's limits stay the readings' limits.
- tool.<chain>.{x,y,z,rx,ry,rz}: the tip frame times the tool's pose, on the fixed joint whose child is the tip.

Several chains (two arms on one torso: the file's `chains`) are written into one URDF, a joint they share
(the torso's) once; the parameters' names are the model's (kinds.arm.model.ArmModel), e.g. link_length.torso_to_left_j1.

Not in a URDF, and said so in its header comment: the sensors' frames (the setup, not the arm), the points on the
tool (points effect), the markers' print scale (marker_scale) and elasticity. Relative mesh file names are made
absolute (the file loads from anywhere); package:// names are kept. Every string written comes from the URDF itself (ElementTree escapes attributes) or
is checked (the header comment: tools.export.common.comment_text).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from naocal.kinds.arm.model import exp_so3
from naocal.solver.errors import DataError, NaocalError
from naocal.solver.fileio import read_bytes
from naocal.solver.transforms import rot_axis_angle, rot_rpy, rpy_from_rot
from naocal.tools.export.common import comment_text

MOVABLE = ("revolute", "continuous")
_CREATED = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z?")


def _floats(text, default="0 0 0"):
    return np.array([float(v) for v in (text or default).split()])


def _origin(joint):
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
    return origin


def _set(origin, xyz=None, R=None):
    if xyz is not None:
        origin.set("xyz", " ".join(repr(float(v)) for v in xyz))
    if R is not None:
        origin.set("rpy", " ".join(repr(float(a)) for a in rpy_from_rot(R)))


def chain_folds(root, base, tip, path):
    """[(fold joint elements, ending movable joint element or None)] from base to tip: one per movable joint (the
    fixed joints before it and itself), and last the fixed joints after the last movable joint (None)."""
    by_child = {}
    for j in root.findall("joint"):
        child = j.find("child")
        if child is not None:
            by_child[child.get("link")] = j
    joints, link = [], tip
    while link != base:
        j = by_child.get(link)
        if j is None:
            raise DataError(path, f"no chain from {base!r} to {tip!r} in the URDF (stopped at {link!r})")
        joints.append(j)
        link = j.find("parent").get("link")
    joints.reverse()
    folds, pending = [], []
    for j in joints:
        pending.append(j)
        if j.get("type") in MOVABLE:
            folds.append((pending, j))
            pending = []
    folds.append((pending, None))
    return folds


def _fold_translation(fold):
    T = np.eye(4)
    for j in fold:
        o = j.find("origin")
        A = np.eye(4)
        A[:3, :3] = rot_rpy(*_floats(o.get("rpy") if o is not None else None))
        A[:3, 3] = _floats(o.get("xyz") if o is not None else None)
        T = T @ A
    return T[:3, 3]


POSE = ("x", "y", "z", "rx", "ry", "rz")


def _origin_names(cal, urdf_path) -> dict:
    """{("joint", joint) or ("tip", chain name): the name its link_length / link_pose parameters carry}: the
    model's own naming (kinds.arm.model.ArmModel: a link ending several origins is named by the joint or chain each
    leads to), so the export places exactly what identify fitted."""
    from naocal.kinds.arm.model import ArmModel
    from naocal.kinds.arm.dataset import arm_chains

    model = ArmModel(arm_chains(urdf_path, cal.chains), {}, [], ())
    return dict(zip(model.origin_keys, model.origin_names))


def _place_tool(fold, chain_name, values, used) -> None:
    """tool.<chain>.{x,y,z,rx,ry,rz}: the tip frame becomes T_tip @ [Exp(r), t] (kinds/arm/model.py: p_tip = t +
    Exp(r) p), i.e. the origin of the fold's last fixed joint (the one whose child is the tip) times that pose.
    A tip moved directly by a joint has no fixed joint to carry it: refused, naming the parameter."""
    tool = np.array([values.get(f"tool.{chain_name}.{q}", 0.0) for q in POSE])
    names = [f"tool.{chain_name}.{q}" for q in POSE]
    if not np.any(tool):
        return
    if not fold:
        raise NaocalError(f"{names[0]}: chain {chain_name}'s tip is moved directly by a joint: no fixed joint to "
                          "carry its tool's pose in a URDF (add a fixed tool link to the URDF and calibrate to it)")
    origin = _origin(fold[-1])
    xyz, R = _floats(origin.get("xyz")), rot_rpy(*_floats(origin.get("rpy")))
    _set(origin, xyz=xyz + R @ tool[:3], R=R @ exp_so3(tool[3:]))
    used.update(names)


def export_arm_urdf(cal, urdf_path, *, source_name="a calibration file", strip_meshes=False) -> str:
    """Text of the corrected URDF of the calibration `cal` (kinds.arm.calibration.ArmCalibration)."""
    urdf_path = Path(urdf_path)
    try:
        root = ET.fromstring(read_bytes(urdf_path), parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    except ET.ParseError as err:
        raise DataError(urdf_path, f"invalid XML: {err}") from None
    values = {n: e["value"] for n, e in cal.arm_parameters.items()}
    names = _origin_names(cal, urdf_path)
    used, done = set(), set()
    for chain_name, (base, tip) in cal.chains.items():
        for fold, joint in chain_folds(root, base, tip, urdf_path):
            key = ("joint", joint.get("name")) if joint is not None else ("tip", chain_name)
            if key in done:  # a joint the chains share (a torso's) is corrected once
                continue
            done.add(key)
            link = names.get(key)
            length = values.get(f"link_length.{link}")
            if length is not None and fold:
                offset = _fold_translation(fold)
                if np.linalg.norm(offset) < 1e-9:
                    raise NaocalError(f"link_length.{link}: the URDF's origin ending {link} has no offset to lengthen")
                first = _origin(fold[0])
                _set(first, xyz=_floats(first.get("xyz")) + length * offset / np.linalg.norm(offset))
                used.add(f"link_length.{link}")
            if joint is None:
                _place_tool(fold, chain_name, values, used)
                continue
            origin = _origin(joint)
            xyz, R = _floats(origin.get("xyz")), rot_rpy(*_floats(origin.get("rpy")))
            pose = [values.get(f"link_pose.{link}.{q}", 0.0) for q in POSE]
            used.update(f"link_pose.{link}.{q}" for q in POSE)
            xyz = xyz + R @ np.array(pose[:3])
            R = R @ exp_so3(np.array(pose[3:]))
            name = joint.get("name")
            c = values.get(f"joint_offset.{name}", 0.0)
            used.add(f"joint_offset.{name}")
            if c:
                axis_element = joint.find("axis")
                axis = _floats(axis_element.get("xyz") if axis_element is not None else None, "1 0 0")
                R = R @ rot_axis_angle(axis / np.linalg.norm(axis), -c)
            _set(origin, xyz=xyz, R=R)
    base, tip = cal.robot["base"], cal.robot["tip"]
    unplaced = [n for n, v in values.items() if n not in used and v != 0.0
                and n.split(".", 1)[0] in ("joint_offset", "link_length", "link_pose", "tool")]
    if unplaced:
        raise NaocalError(f"{unplaced[0]}: no such joint, link or chain on the URDF's chain(s) {base} -> {tip} "
                          "(another arm's calibration?)")
    left_out = sorted({n.split(".", 1)[0] for n, v in values.items()
                       if n.split(".", 1)[0] in ("point", "elasticity", "intrinsics", "marker_scale") and v != 0.0})
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if name and "://" not in name and not name.startswith("/"):
            mesh.set("filename", str((urdf_path.parent / name).resolve()))
    if strip_meshes:
        for link in root.iter("link"):
            for tag in ("visual", "collision"):
                for element in link.findall(tag):
                    if element.find("geometry/mesh") is not None:
                        link.remove(element)
    created = cal.created if _CREATED.fullmatch(cal.created) else "unknown"
    note = (f" Written by naocal from {comment_text(source_name)}: arm {comment_text(cal.robot.get('id', 'unknown'))}, "
            f"chain {comment_text(base)} -> {comment_text(tip)}, calibrated {created}. Joint offsets, link lengths, "
            "link poses and tool mounts are in the joint origins: forward kinematics at the joint readings gives the calibrated "
            "pose (no calibration tags to apply). Not here: the sensors' frames"
            + (f" and the calibrated {', '.join(left_out)} (see the calibration file)" if left_out else "") + ". ")
    root.insert(0, ET.Comment(note))
    ET.indent(root, space="  ")
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"
