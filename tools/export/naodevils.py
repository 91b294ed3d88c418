"""Nao Devils: `jointCalibration.cfg` and `cameraCalibration.cfg`, fresh or merged (github.com/NaoDevils/CodeRelease).

- jointCalibration.cfg: one top-level record per value of their Joints enum (B-Human's 26 names, in its order),
  `lHipPitch = { offset = 0deg; minAngle = -88deg; maxAngle = 27.73deg; };` (JointCalibration::serialize).
  Their NaoProvider sends request + offset and reads sensor - offset: the sign of naocal's c (their public V6
  provider does not apply it at all: docs/EXPORTS.md).
- cameraCalibration.cfg: `lowerCameraRotationCorrection = {x; y; z};`, `upperCameraRotationCorrection = {...};`,
  `bodyRotationCorrection = {x; y};`, applied like B-Human's (rotateY(tilt + y) * rotateX(x) * rotateZ(z)).
- Search path (File::getFullNames): Robots/<robot>/<body>/, Robots/<robot>/Head/, Robots/<body>/Body/,
  Robots/<robot>/, Robots/<V5|V6>/, Robots/Default/. Their camera calibrator (CMCorrector) saves to
  Robots/<robot>/<body>/cameraCalibration.cfg; joint offsets belong to the body: Robots/<body>/Body/.
"""

from __future__ import annotations

import math
from pathlib import Path

from naocal.solver.errors import DataError
from naocal.tools.export import cfgtext
from naocal.tools.export.bhuman import (
    CAMERA_AXES, CAMERA_FILE, FIRST_RELEASE, JOINT_FILE, bhuman_key, camera_notes, camera_paths, fresh_cameras,
    joint_keys,
)
from naocal.tools.export.common import (
    Calibrated, ExportFile, checked_id, deg_literal, first_existing, provenance, read_team_file,
)

JOINT_KEYS = joint_keys(FIRST_RELEASE)  # Nao Devils' Joints enum: B-Human's names before waistYaw


def _naoqi_joint(key: str) -> str:
    return key[0].upper() + key[1:]


def _limit_literals() -> dict[str, tuple[str, str]]:
    """{key: (minAngle, maxAngle)} for a fresh file: the Aldebaran limits naocal uses (the URDF's, RKneePitch from the
    documentation) to 0.01 deg as documented, as in Nao Devils' Config/Robots/V5/jointCalibration.cfg (the hands'
    0..1 in deg like theirs)."""
    from naocal.solver.limits import joint_limits

    def inward(low_rad, high_rad):  # rounded to 0.01 deg towards the inside: never wider than the robot's range
        low, high = math.ceil(math.degrees(low_rad) * 100 - 1e-9), math.floor(math.degrees(high_rad) * 100 + 1e-9)
        return tuple(deg_literal(math.radians(v / 100), digits=2) for v in (low, high))

    limits = joint_limits()
    return {key: inward(*limits[_naoqi_joint(key)]) for key in JOINT_KEYS}


def _search_path(robot: str, body: str, file_name: str) -> list[str]:
    return [f"Robots/{robot}/{body}/{file_name}", f"Robots/{robot}/Head/{file_name}",
            f"Robots/{body}/Body/{file_name}", f"Robots/{robot}/{file_name}", f"Robots/V6/{file_name}",
            f"Robots/V5/{file_name}", f"Robots/Default/{file_name}"]


def export_naodevils(cal: Calibrated, source_name: str, *, head: str, body: str,
                     merge_from: Path | None = None) -> list[ExportFile]:
    head, body = checked_id(head, "robot.head_id"), checked_id(body, "robot.body_id")
    header = provenance(cal, source_name)
    joints_at, cameras_at = f"Robots/{body}/Body/{JOINT_FILE}", f"Robots/{head}/{body}/{CAMERA_FILE}"
    if merge_from is None:
        return [_fresh_joints(cal, header, joints_at), fresh_cameras(cal, header, cameras_at, per_camera_keys=True)]
    return [_merged(cal, merge_from, head, body, JOINT_FILE, joints_at, _joint_edits),
            _merged(cal, merge_from, head, body, CAMERA_FILE, cameras_at, _camera_edits)]


def _fresh_joints(cal: Calibrated, header: str, relative: str) -> ExportFile:
    fitted = {bhuman_key(joint): c for joint, c in cal.joints_rad.items()}
    limits = _limit_literals()
    lines = [f"// {header}",
             "// offset is added to every joint request (naocal's c); 0deg where naocal calibrated nothing.",
             "// minAngle/maxAngle: Aldebaran's joint limits (as in Config/Robots/V5/jointCalibration.cfg)."]
    for key in JOINT_KEYS:
        low, high = limits[key]
        lines += [f"{key} = {{", f"  offset = {deg_literal(fitted.get(key, 0.0))};", f"  minAngle = {low};",
                  f"  maxAngle = {high};", "};"]
    notes = [f"naocal's offsets for {len(fitted)} joints; 0deg for the {len(JOINT_KEYS) - len(fitted)} others and "
             "Aldebaran's limits: merge with --merge-from to keep yours"]
    return ExportFile(relative, "\n".join(lines) + "\n", notes)


def _joint_edits(cal: Calibrated, root, path):
    for key in JOINT_KEYS:
        node = cfgtext.lookup(root, (key, "offset"))
        if node is None or node.kind != "literal":
            raise DataError(path, "missing value", field=f"{key}.offset")
    new = {(bhuman_key(joint), "offset"): deg_literal(c) for joint, c in cal.joints_rad.items()}
    kept = [key for key in JOINT_KEYS if (key, "offset") not in new]
    return new, [f"naocal's offsets for {len(new)} joints; kept as they were: every minAngle/maxAngle and the "
                 f"offsets of {', '.join(kept)}"]


def _camera_edits(cal: Calibrated, root, path):
    paths = camera_paths(root, path)
    cameras, notes = camera_notes(cal, "kept as it was")
    new = {paths[name] + (axis,): deg_literal(rpy[i]) for name, rpy in cameras.items() for axis, i in CAMERA_AXES}
    return new, notes + ["bodyRotationCorrection kept as it was"]


def _merged(cal: Calibrated, merge_from: Path, head: str, body: str, file_name: str, canonical: str,
            edits) -> ExportFile:
    search = _search_path(head, body, file_name)
    found = first_existing(merge_from, search)
    if found is None:
        raise DataError(merge_from, f"no {file_name} in " + ", ".join(p.rsplit("/", 1)[0] for p in search)
                        + ": is --merge-from your Nao Devils Config directory?")
    path = merge_from / found
    text = read_team_file(path)
    root = cfgtext.parse_cfg(text, path)
    new, notes = edits(cal, root, path)
    robot_specific = found.startswith((f"Robots/{head}/", f"Robots/{body}/Body/"))
    relative = found if robot_specific else canonical
    note = f"merged into {found}" if robot_specific else f"no robot-specific {file_name} yet: started from {found}"
    return ExportFile(relative, cfgtext.replace_literals(text, root, new, path), [note] + notes)

