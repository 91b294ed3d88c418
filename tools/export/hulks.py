"""HULKs: `body.<BodyId>.json` and `head.<HeadId>.json` in etc/parameters/ (github.com/HULKs/hulk).

- HULKs overlays these sparse files on default.json (parameters::directory::deserialize, serde_json merge_json):
  a file holds only what differs, so naocal writes only what it calibrated and every other value keeps the team's
  or the default. Merges edit the team's file in place (tools/export/jsontext.py).
- `joint_calibration_offsets` (rad, Joints { head {yaw, pitch}, left_arm, right_arm, left_leg {hip_yaw_pitch,
  hip_roll, hip_pitch, knee_pitch, ankle_pitch, ankle_roll}, right_leg }): the command sender writes
  positions + offsets to the actuators and the sensor receiver reads positions - offsets: the sign of naocal's c.
- `camera_matrix_parameters.calibration.correction_in_camera_{top,bottom}` = [x, y, z] rad, nalgebra Euler angles
  (C = Rz(z) Ry(y) Rx(x), Rotation3::from_euler_angles) of a rotation in HULKs' camera frame (x right, y down,
  z along the optical axis: Intrinsic::project), applied as head_to_camera' = C * head_to_camera
  (CameraMatrix::to_corrected). `correction_in_robot` (a torso rotation) is not estimated by naocal: kept.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from naocal.solver.errors import NaocalError
from naocal.solver.joints import LEG_JOINT_SUFFIXES
from naocal.solver.transforms import rot_rpy, rot_x, rot_y, rot_z, rpy_from_rot
from naocal.tools.export import jsontext
from naocal.tools.export.common import Calibrated, ExportFile, checked_id, read_team_file

_LEG_FIELDS = ("hip_yaw_pitch", "hip_roll", "hip_pitch", "knee_pitch", "ankle_pitch", "ankle_roll")
JOINT_PATHS = {"HeadYaw": ("head", "yaw"), "HeadPitch": ("head", "pitch")}
JOINT_PATHS.update({f"L{s}": ("left_leg", f) for s, f in zip(LEG_JOINT_SUFFIXES, _LEG_FIELDS)})
JOINT_PATHS.update({f"R{s}": ("right_leg", f) for s, f in zip(LEG_JOINT_SUFFIXES, _LEG_FIELDS)})
JOINTS_KEY = "joint_calibration_offsets"
CAMERA_PATHS = {camera: ("camera_matrix_parameters", "calibration", f"correction_in_camera_{camera}")
                for camera in ("top", "bottom")}

# Axes of naocal's NAO camera frame (x optical axis, y left, z up) in HULKs' camera frame (x right, y down,
# z optical axis): p_hulks = R_HULKS_NAO @ p_nao.
R_HULKS_NAO = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def hulks_correction(camera_rpy) -> list[float]:
    """[x, y, z] of HULKs' correction_in_camera for naocal's camera alpha (roll, pitch, yaw), rad.

    naocal: R_head_cam' = R_head_cam @ R_a, R_a = Ry(pitch) Rx(roll) Rz(yaw), in the NAO camera frame.
    HULKs: R_cam'_head = C @ R_cam_head in its camera frame, with R_head_camHULKs = R_head_cam @ M.T (M =
    R_HULKS_NAO). Equal poses give C = M @ R_a.T @ M.T; [x, y, z] are C's nalgebra Euler angles.
    """
    roll, pitch, yaw = camera_rpy
    R_a = rot_y(pitch) @ rot_x(roll) @ rot_z(yaw)
    return list(rpy_from_rot(R_HULKS_NAO @ R_a.T @ R_HULKS_NAO.T))


def naocal_camera_rpy(correction) -> tuple[float, float, float]:
    """Inverse of hulks_correction: naocal's (roll, pitch, yaw) for HULKs' [x, y, z]."""
    R_a = (R_HULKS_NAO.T @ rot_rpy(*correction) @ R_HULKS_NAO).T  # = Ry(p) Rx(r) Rz(y)
    roll = float(np.arcsin(np.clip(-R_a[1, 2], -1.0, 1.0)))
    return roll, float(np.arctan2(R_a[0, 2], R_a[2, 2])), float(np.arctan2(R_a[1, 0], R_a[1, 1]))


def _nest(values: dict) -> dict:
    doc = {}
    for keys, value in values.items():
        node = doc
        for key in keys[:-1]:
            node = node.setdefault(key, {})
        node[keys[-1]] = value
    return doc


def _file(merge_from: Path | None, name: str, values: dict, what: str) -> ExportFile:
    text = None if merge_from is None else read_team_file(merge_from / name)
    if text is None:
        where = "" if merge_from is None else f" (no {name} in {merge_from} yet)"
        return ExportFile(name, json.dumps(_nest(values), indent=2) + "\n",
                          [f"new file{where} with naocal's {what} only: HULKs overlays it on default.json, so every "
                           "other value keeps its default"])
    _, doc = jsontext.parse_json(text, merge_from / name)
    top_keys = {keys[0] for keys in values}
    if isinstance(doc.get("parameters"), dict) and not top_keys & set(doc):  # newer files nest all in "parameters"
        values = {("parameters",) + keys: value for keys, value in values.items()}
    return ExportFile(name, jsontext.set_values(text, values, merge_from / name),
                      [f"merged into {merge_from / name}: naocal's {what} set, every other value kept as it was"])


def export_hulks(cal: Calibrated, *, head: str, body: str, merge_from: Path | None = None) -> list[ExportFile]:
    files = []
    joints = {(JOINTS_KEY,) + JOINT_PATHS[joint]: c for joint, c in cal.joints_rad.items()}
    if joints:
        body = checked_id(body, "robot.body_id")
        head_note = "" if "HeadYaw" in cal.joints_rad else "; head joints not calibrated: not written"
        files.append(_file(merge_from, f"body.{body}.json", joints, f"{len(joints)} joint offsets (rad)"))
        files[-1].notes.append(f"arms not calibrated by naocal: not written{head_note}")
    cameras = {CAMERA_PATHS[camera]: hulks_correction(rpy) for camera, rpy in cal.cameras_rad.items()
               if camera in CAMERA_PATHS}
    if cameras:
        head = checked_id(head, "robot.head_id")
        names = " and ".join(keys[-1] for keys in cameras)
        files.append(_file(merge_from, f"head.{head}.json", cameras, names))
        files[-1].notes.append("correction_in_robot not estimated by naocal: not written")
        for camera in CAMERA_PATHS:
            if camera not in cal.cameras_rad:
                files[-1].notes.append(f"{camera} camera not calibrated in this offsets file: not written")
    unknown = [camera for camera in cal.cameras_rad if camera not in CAMERA_PATHS]
    if not files:
        raise NaocalError("nothing to export for HULKs: the offsets file calibrates no joint and no top or bottom "
                          "camera")
    files[-1].notes += [f"camera {camera!r} has no HULKs counterpart: not exported" for camera in unknown]
    return files
