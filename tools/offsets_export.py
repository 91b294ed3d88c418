"""Exports of a naocal.offsets file for other robot software: B-Human config files, a calibrated URDF, JSON.

B-Human
-------
`jointCalibration.cfg` (`offsets = { headYaw = 0deg; ... rAnkleRoll = 0deg; };`, all 26 keys in B-Human's order):
B-Human adds these offsets to every joint request (actuator = request + offset), the same sign as naocal's c.
`cameraCalibration.cfg` (`cameraRotationCorrections = { lower = {x; y; z}; upper = {...}; };`): B-Human builds the
camera pose as ... translate(neck to camera) * rotateY(tilt + y) * rotateX(x) * rotateZ(z) in a camera frame with
x forward, y left, z up: exactly naocal's T_head_cam = T_head_cam_nominal @ Rot_y(alpha_pitch) @ Rot_x(alpha_roll)
@ Rot_z(alpha_yaw). So x = alpha_roll, y = alpha_pitch, z = alpha_yaw, same signs, lower = bottom camera.

URDF
----
The nominal NAO URDF with `<calibration rising="c"/>` in every calibrated joint (a driver applies it: reading
published = raw - c, command sent = requested + c), the RHipYawPitch mimic offset set to c_L - c_R (both joints are
one motor: q_true_R = q_true_L + alpha_R - alpha_L), and the camera joint origin turned by the camera correction
(T_head_cam = T_head_cam_nominal @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw), written back as URDF rpy).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from solver.errors import DataError
from solver.offsets import Offsets, format_offsets
from solver.transforms import rot_rpy, rot_x, rot_y, rot_z, rpy_from_rot

NOMINAL_URDF = Path(__file__).resolve().parents[1] / "solver" / "data" / "nao_v50.urdf"
CAMERA_URDF_JOINTS = {"bottom": "CameraBottom_sensor_fixedjoint", "top": "CameraTop_sensor_fixedjoint"}

# B-Human's joint keys in the order of its jointCalibration.cfg.
BHUMAN_JOINT_KEYS = (
    "headYaw", "headPitch",
    "lShoulderPitch", "lShoulderRoll", "lElbowYaw", "lElbowRoll", "lWristYaw", "lHand",
    "rShoulderPitch", "rShoulderRoll", "rElbowYaw", "rElbowRoll", "rWristYaw", "rHand",
    "lHipYawPitch", "lHipRoll", "lHipPitch", "lKneePitch", "lAnklePitch", "lAnkleRoll",
    "rHipYawPitch", "rHipRoll", "rHipPitch", "rKneePitch", "rAnklePitch", "rAnkleRoll",
)
BHUMAN_CAMERAS = (("lower", "bottom"), ("upper", "top"))
JOINT_CALIBRATION_CFG = "jointCalibration.cfg"
CAMERA_CALIBRATION_CFG = "cameraCalibration.cfg"


def bhuman_key(joint: str) -> str:
    """NAOqi joint name -> B-Human key: LHipPitch -> lHipPitch, HeadYaw -> headYaw."""
    return joint[0].lower() + joint[1:]


def naoqi_joint(key: str) -> str:
    return key[0].upper() + key[1:]


def deg_literal(angle_rad: float) -> str:
    """B-Human angle literal, e.g. 0.62deg (1e-6 deg resolution, far below any joint's repeatability)."""
    text = f"{math.degrees(angle_rad):.6f}".rstrip("0").rstrip(".")
    return ("0" if text in ("-0", "") else text) + "deg"


def _provenance(offsets: Offsets, source_name: str) -> str:
    robot = offsets.robot
    return (f"// Written by naocal from {source_name}: robot {robot.get('id')}, body {robot.get('body_id')}, "
            f"head {robot.get('head_id')}, calibrated {offsets.created}.\n")


def export_bhuman(offsets: Offsets, source_name: str = "an offsets file") -> dict[str, str]:
    """{file name: text} for B-Human's jointCalibration.cfg and cameraCalibration.cfg."""
    header = _provenance(offsets, source_name)
    lines = [header.rstrip("\n"), "// offset is added to every joint request (naocal's c).", "offsets = {"]
    for key in BHUMAN_JOINT_KEYS:
        lines.append(f"  {key} = {deg_literal(offsets.joint_offset(naoqi_joint(key)))};")
    lines.append("};")
    joint_cfg = "\n".join(lines) + "\n"

    lines = [header.rstrip("\n"), "// x = roll, y = pitch (tilt), z = yaw (pan) about the camera frame "
                                  "(x forward, y left, z up), applied after the nominal tilt.",
             "cameraRotationCorrections = {"]
    for bhuman_name, camera in BHUMAN_CAMERAS:
        roll, pitch, yaw = offsets.camera_rpy(camera)
        if camera not in offsets.camera_rotation_rad:
            lines.append(f"  // {bhuman_name}: not calibrated in this file (0 = nominal); keep your own value.")
        lines += [f"  {bhuman_name} = {{", f"    x = {deg_literal(roll)};", f"    y = {deg_literal(pitch)};",
                  f"    z = {deg_literal(yaw)};", "  };"]
    lines += ["};", "// not estimated by naocal: keep your own value if you have one.",
              "bodyRotationCorrection = {", "  x = 0deg;", "  y = 0deg;", "};"]
    camera_cfg = "\n".join(lines) + "\n"
    return {JOINT_CALIBRATION_CFG: joint_cfg, CAMERA_CALIBRATION_CFG: camera_cfg}


def export_json(offsets: Offsets) -> str:
    """The file itself, validated and in canonical form (naocal.offsets/2)."""
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
    try:
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.parse(nominal_urdf, parser=parser).getroot()
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
    note = (f" Calibrated by naocal from {source_name}: robot {offsets.robot.get('id')}, body "
            f"{offsets.robot.get('body_id')}, head {offsets.robot.get('head_id')}, calibrated {offsets.created}. "
            "calibration rising = c: command = requested + c, reading = raw - c. ")
    root.insert(0, ET.Comment(note.replace("--", "-")))
    ET.indent(root, space="  ")
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding="unicode") + "\n"
