"""Exports for robot models and tools: a calibrated URDF, and the offsets file itself in canonical form.

URDF
----
The nominal NAO URDF with `<calibration rising="c"/>` in every calibrated joint (a driver applies it: reading
published = raw - c, command sent = requested + c), the RHipYawPitch mimic offset set to c_L - c_R (both joints are
one motor: q_true_R = q_true_L + alpha_R - alpha_L), and the camera joint origin turned by the camera correction
(T_head_cam = T_head_cam_nominal @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw), written back as URDF rpy).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from naocal.solver.errors import DataError, NaocalError
from naocal.solver.fileio import read_bytes
from naocal.solver.offsets import Offsets, format_offsets
from naocal.solver.transforms import rot_rpy, rot_x, rot_y, rot_z, rpy_from_rot
from naocal.tools.export.common import calibrated, provenance

NOMINAL_URDF = Path(__file__).resolve().parents[2] / "solver" / "data" / "nao_v50.urdf"
CAMERA_URDF_JOINTS = {"bottom": "CameraBottom_sensor_fixedjoint", "top": "CameraTop_sensor_fixedjoint"}


def export_json(offsets: Offsets) -> str:
    """The file itself, validated and in canonical form (naocal.offsets/2; a version 1 file is upgraded)."""
    return format_offsets(offsets)


def corrected_camera_rpy(nominal_rpy, camera_rpy) -> tuple[float, float, float]:
    """URDF rpy of T_head_cam_nominal @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw).

    nominal_rpy : the URDF origin rpy (fixed-axis: R = Rz(y) Ry(p) Rx(r)); camera_rpy : (alpha_roll, alpha_pitch,
    alpha_yaw) of Eq. 3. Both in rad.
    """
    roll, pitch, yaw = camera_rpy
    R = rot_rpy(*nominal_rpy) @ rot_y(pitch) @ rot_x(roll) @ rot_z(yaw)
    return rpy_from_rot(R)


def _floats(text: str | None, default: str = "0 0 0") -> tuple[float, ...]:
    return tuple(float(v) for v in (text or default).split())


def _strip_meshes(root: ET.Element) -> None:
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                if element.find("geometry/mesh") is not None:
                    link.remove(element)


def export_urdf(offsets: Offsets, nominal_urdf=NOMINAL_URDF, *, strip_meshes: bool = False,
                source_name: str = "an offsets file") -> str:
    """Text of the calibrated URDF. `strip_meshes` drops mesh visuals/collisions (whose files naocal does not ship),
    e.g. to load the model in PyBullet."""
    nominal_urdf = Path(nominal_urdf)
    if not nominal_urdf.exists():
        raise DataError(nominal_urdf, "nominal URDF not found")
    try:
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.fromstring(read_bytes(nominal_urdf), parser=parser)  # a regular file: a FIFO cannot hang us
    except FileNotFoundError:
        raise DataError(nominal_urdf, "nominal URDF not found") from None
    except ET.ParseError as err:
        raise DataError(nominal_urdf, f"invalid XML: {err}") from None
    except OSError as err:
        raise DataError(nominal_urdf, f"cannot read: {err.strerror or err}") from None
    joints = {j.get("name"): j for j in root.findall("joint")}  # not the <joint> refs in <transmission>

    for name, c in offsets.joint_offsets_rad.items():
        joint = joints.get(name)
        if joint is None:
            raise DataError(nominal_urdf, f"no joint {name!r} in the nominal URDF")
        for old in joint.findall("calibration"):
            joint.remove(old)
        ET.SubElement(joint, "calibration", {"rising": repr(float(c))})
    mimic = joints["RHipYawPitch"].find("mimic") if "RHipYawPitch" in joints else None
    if mimic is not None and mimic.get("joint") == "LHipYawPitch":
        mimic.set("offset", repr(offsets.joint_offset("LHipYawPitch") - offsets.joint_offset("RHipYawPitch")))

    for camera in offsets.camera_rotation_rad:
        if camera not in CAMERA_URDF_JOINTS:
            raise NaocalError(f"camera {camera!r} has no joint in the NAO URDF "
                              f"(known: {', '.join(CAMERA_URDF_JOINTS)})")
        joint = joints.get(CAMERA_URDF_JOINTS[camera])
        if joint is None:
            raise DataError(nominal_urdf, f"no joint {CAMERA_URDF_JOINTS[camera]!r} in the nominal URDF")
        origin = joint.find("origin")
        if origin is None:
            origin = ET.SubElement(joint, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
        rpy = corrected_camera_rpy(_floats(origin.get("rpy")), offsets.camera_rpy(camera))
        origin.set("rpy", " ".join(repr(float(a)) for a in rpy))

    if strip_meshes:
        _strip_meshes(root)
    # Every string in the comment is checked or escaped (comment_text): nothing can end the comment early.
    note = (f" {provenance(calibrated(offsets), source_name)} "
            "calibration rising = c: command = requested + c, reading = raw - c. ")
    root.insert(0, ET.Comment(note))
    ET.indent(root, space="  ")
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"
