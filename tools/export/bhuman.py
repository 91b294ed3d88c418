"""B-Human: `jointCalibration.cfg` and `cameraCalibration.cfg`, fresh or merged into a team's Config directory.

Facts (B-Human's code release, github.com/bhuman/BHumanCodeRelease; details and sources in docs/EXPORTS.md):
- jointCalibration.cfg is `offsets = { <joint> = <angle>; ... };` with one key per value of the `Joints::Joint` enum,
  in its order: 26 keys up to the 2024 release, 27 from 2025 (`waistYaw` after `headPitch`). B-Human's NaoProvider
  sends request + offset and reads sensor - offset: the sign of naocal's c.
- cameraCalibration.cfg is `cameraRotationCorrections = { upper = {x; y; z}; lower = {...}; };` and
  `bodyRotationCorrection = {x; y};` (until 2018: `lowerCameraRotationCorrection = {x; y; z};` ...).
  RobotCameraMatrix turns the camera by rotateY(tilt + y) * rotateX(x) * rotateZ(z) in a frame with x forward,
  y left, z up: naocal's Ry(pitch) Rx(roll) Rz(yaw). So x = roll, y = pitch, z = yaw, same signs.
- Config search path (Settings::getSearchPath): Robots/<head>/Head/, Robots/<body>/Body/, Robots/<head>/<body>/,
  ..., Robots/Default/. Joint offsets belong to the body (Robots/<body>/Body/); the camera file holds head values
  (camera rotations) and a body value (bodyRotationCorrection), so it belongs to the pair (Robots/<head>/<body>/).
"""

from __future__ import annotations

from pathlib import Path

from naocal.solver.errors import DataError, NaocalError
from naocal.tools.export import cfgtext
from naocal.tools.export.common import (
    Calibrated, ExportFile, checked_id, deg_literal, first_existing, provenance, read_team_file,
)

FIRST_RELEASE = 2017  # the first release with `offsets = { ... }`; before it each joint had {offset; min; max}
WAIST_YAW_RELEASE = 2025  # Joints::waistYaw ("not present on the NAO") added after headPitch
LATEST_RELEASE = 2025
# cameraRotationCorrections = {upper; lower} replaced lower/upperCameraRotationCorrection with the V6 (2019): B-Human's
# 2019+ code has the array; TJArkCodeRelease2019, built on B-Human's 2018 release, still has the two keys.
CAMERA_ARRAY_RELEASE = 2019
_ARM_KEYS = ("ShoulderPitch", "ShoulderRoll", "ElbowYaw", "ElbowRoll", "WristYaw", "Hand")
_LEG_KEYS = ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")
CAMERAS = {"top": "upper", "bottom": "lower"}  # naocal camera name -> B-Human's CameraInfo::Camera
CAMERA_ORDER = ("upper", "lower")  # CameraInfo::Camera's order, the order B-Human writes
JOINT_FILE = "jointCalibration.cfg"
CAMERA_FILE = "cameraCalibration.cfg"
CAMERA_AXES = (("x", 0), ("y", 1), ("z", 2))  # B-Human axis -> index in naocal's (roll, pitch, yaw)


def joint_keys(release: int) -> tuple[str, ...]:
    """jointCalibration.cfg's keys for a release, in B-Human's order."""
    if release < FIRST_RELEASE:
        raise NaocalError(f"B-Human releases before {FIRST_RELEASE} store each joint as {{offset; minAngle; maxAngle}}"
                          f" (like Nao Devils): not supported; give --bhuman-release {FIRST_RELEASE} or later")
    head = ("headYaw", "headPitch") + (("waistYaw",) if release >= WAIST_YAW_RELEASE else ())
    return (head + tuple("l" + k for k in _ARM_KEYS) + tuple("r" + k for k in _ARM_KEYS)
            + tuple("l" + k for k in _LEG_KEYS) + tuple("r" + k for k in _LEG_KEYS))


def bhuman_key(joint: str) -> str:
    """NAOqi joint name -> B-Human key: LHipPitch -> lHipPitch, HeadYaw -> headYaw."""
    return joint[0].lower() + joint[1:]


def _search_path(head: str, body: str, file_name: str) -> list[str]:
    return [f"Robots/{head}/Head/{file_name}", f"Robots/{body}/Body/{file_name}", f"Robots/{head}/{body}/{file_name}",
            f"Robots/Default/{file_name}"]


def _release_of(keys, path) -> int:
    """The release layout (2017 or 2025) a file's joint keys belong to; DataError naming a wrong key otherwise."""
    for release in (WAIST_YAW_RELEASE, FIRST_RELEASE):
        if set(keys) == set(joint_keys(release)):
            return release
    closest = joint_keys(WAIST_YAW_RELEASE if "waistYaw" in keys else FIRST_RELEASE)
    unknown = [k for k in keys if k not in closest]
    missing = [k for k in closest if k not in keys]
    key, problem = (unknown[0], "unknown joint key") if unknown else (missing[0], "missing joint key")
    raise DataError(path, f"{problem}: not a B-Human jointCalibration.cfg of any release", field=f"offsets.{key}")


def _release_name(release: int) -> str:
    if release >= WAIST_YAW_RELEASE:
        return f"{WAIST_YAW_RELEASE}+ (27 keys, waistYaw)"
    return f"{FIRST_RELEASE}-{WAIST_YAW_RELEASE - 1} (26 keys)"


def camera_paths(root: cfgtext.CfgValue, path) -> dict[str, tuple]:
    """{'upper'/'lower': key path of its x/y/z record} in either camera file layout; DataError if neither fits."""
    if "cameraRotationCorrections" in root.fields:
        paths = {name: ("cameraRotationCorrections", name) for name in CAMERA_ORDER}
    elif "lowerCameraRotationCorrection" in root.fields or "upperCameraRotationCorrection" in root.fields:
        paths = {name: (f"{name}CameraRotationCorrection",) for name in CAMERA_ORDER}
    else:
        raise DataError(path, "missing the camera rotation corrections", field="cameraRotationCorrections")
    for keys in paths.values():
        for axis, _ in CAMERA_AXES:
            node = cfgtext.lookup(root, keys + (axis,))
            if node is None or node.kind != "literal":
                raise DataError(path, "missing value", field=".".join(keys + (axis,)))
    return paths


def camera_notes(cal: Calibrated, kept_word: str) -> tuple[dict, list]:
    """({B-Human camera: (roll, pitch, yaw)}, notes) for the cameras the file calibrates."""
    cameras, notes = {}, []
    for camera, rpy in cal.cameras_rad.items():
        if camera in CAMERAS:
            cameras[CAMERAS[camera]] = rpy
        else:
            notes.append(f"camera {camera!r} has no B-Human counterpart: not exported")
    for name in CAMERA_ORDER:
        if name not in cameras:
            notes.append(f"{name} camera not calibrated in this offsets file: {kept_word}")
    return cameras, notes


def export_bhuman(cal: Calibrated, source_name: str, *, head: str, body: str, release: int | None = None,
                  merge_from: Path | None = None) -> list[ExportFile]:
    """The two files under B-Human's Config layout. With `merge_from` (a team's Config directory) the team's current
    files are edited in place of their calibrated values only; without it, fresh files (0 where not calibrated)."""
    head, body = checked_id(head, "robot.head_id"), checked_id(body, "robot.body_id")
    if release is not None:
        joint_keys(release)  # refuses releases before the offsets layout
    header = provenance(cal, source_name)
    if merge_from is None:
        release = LATEST_RELEASE if release is None else release
        return [_fresh_joints(cal, header, release, f"Robots/{body}/Body/{JOINT_FILE}"),
                fresh_cameras(cal, header, f"Robots/{head}/{body}/{CAMERA_FILE}",
                              per_camera_keys=release < CAMERA_ARRAY_RELEASE)]
    return [_merged_joints(cal, merge_from, release, head, body),
            _merged_cameras(cal, merge_from, head, body)]


def _fresh_joints(cal: Calibrated, header: str, release: int, relative: str) -> ExportFile:
    fitted = {bhuman_key(joint): c for joint, c in cal.joints_rad.items()}
    kept = [key for key in joint_keys(release) if key not in fitted]
    lines = [f"// {header}",
             f"// B-Human {_release_name(release)} layout. offset is added to every joint request and subtracted "
             "from every reading (naocal's c).",
             "// 0deg (nominal) where naocal calibrated nothing: " + ", ".join(kept) + ".",
             "offsets = {"]
    lines += [f"  {key} = {deg_literal(fitted.get(key, 0.0))};" for key in joint_keys(release)]
    lines.append("};")
    notes = [f"B-Human {_release_name(release)} layout; naocal's offsets for {len(fitted)} joints; "
             f"0deg written for {len(kept)} joints naocal did not calibrate (arms, hands"
             + (", waistYaw" if release >= WAIST_YAW_RELEASE else "")
             + ("" if "headYaw" in fitted else ", head") + "): merge with --merge-from to keep yours"]
    return ExportFile(relative, "\n".join(lines) + "\n", notes)


def camera_file_lines(cameras: dict, per_camera_keys: bool) -> list[str]:
    """Body of a fresh camera file, 0deg where a camera is not in `cameras` ({'upper'/'lower': (roll, pitch, yaw)}).

    per_camera_keys: the older layout, `lowerCameraRotationCorrection = {x; y; z};` ... (Nao Devils, B-Human until
    2018); otherwise `cameraRotationCorrections = { upper = {...}; lower = {...}; };`."""
    lines = ["// x = roll, y = pitch (tilt), z = yaw (pan) about the camera frame (x forward, y left, z up), "
             "applied after the nominal tilt."]
    indent = "" if per_camera_keys else "  "
    if not per_camera_keys:
        lines.append("cameraRotationCorrections = {")
    for name in (("lower", "upper") if per_camera_keys else CAMERA_ORDER):
        if name not in cameras:
            lines.append(f"{indent}// {name}: not calibrated in this file (0deg = nominal); keep your own value.")
        rpy = cameras.get(name, (0.0, 0.0, 0.0))
        key = f"{name}CameraRotationCorrection" if per_camera_keys else name
        lines += [f"{indent}{key} = {{"] + [f"{indent}  {axis} = {deg_literal(rpy[i])};" for axis, i in CAMERA_AXES]
        lines.append(f"{indent}}};")
    if not per_camera_keys:
        lines.append("};")
    return lines + ["// bodyRotationCorrection: not estimated by naocal (0deg); keep your own value.",
                    "bodyRotationCorrection = {", "  x = 0deg;", "  y = 0deg;", "};"]


def fresh_cameras(cal: Calibrated, header: str, relative: str, per_camera_keys: bool) -> ExportFile:
    cameras, notes = camera_notes(cal, "written as 0deg (nominal); merge with --merge-from to keep yours")
    notes.append("bodyRotationCorrection not estimated by naocal: written as 0deg; merge with --merge-from to keep "
                 "yours")
    return ExportFile(relative, "\n".join([f"// {header}"] + camera_file_lines(cameras, per_camera_keys)) + "\n",
                      notes)


def _base(merge_from: Path, head: str, body: str, file_name: str, canonical: str):
    """(relative path to write, base text, relative path read, note) for a merge: the file B-Human reads now."""
    found = first_existing(merge_from, _search_path(head, body, file_name))
    if found is None:
        raise DataError(merge_from, f"no {file_name} in Robots/{head}/Head, Robots/{body}/Body, "
                                    f"Robots/{head}/{body} or Robots/Default: is --merge-from your B-Human Config "
                                    "directory?")
    text = read_team_file(merge_from / found)
    if found.startswith("Robots/Default/"):
        return canonical, text, found, f"no robot-specific {file_name} yet: started from {found}"
    return found, text, found, f"merged into {found}"


def _merged_joints(cal: Calibrated, merge_from: Path, release, head: str, body: str) -> ExportFile:
    relative, text, found, note = _base(merge_from, head, body, JOINT_FILE, f"Robots/{body}/Body/{JOINT_FILE}")
    path = merge_from / found
    root = cfgtext.parse_cfg(text, path)
    offsets = cfgtext.lookup(root, ("offsets",))
    if offsets is None or offsets.kind != "record":
        raise DataError(path, "missing the offsets record", field="offsets")
    file_release = _release_of(list(offsets.fields), path)
    if release is not None and (release >= WAIST_YAW_RELEASE) != (file_release >= WAIST_YAW_RELEASE):
        raise DataError(path, f"has the B-Human {_release_name(file_release)} layout but --bhuman-release "
                              f"{release} expects {_release_name(release)}: is the release right?",
                        field="offsets.waistYaw")
    new = {("offsets", bhuman_key(joint)): deg_literal(c) for joint, c in cal.joints_rad.items()}
    kept = [key for key in offsets.fields if ("offsets", key) not in new]
    return ExportFile(relative, cfgtext.replace_literals(text, root, new, path),
                      [note, f"B-Human {_release_name(file_release)} layout; naocal's offsets for {len(new)} joints; "
                             f"kept as they were: {', '.join(kept)}"])


def _merged_cameras(cal: Calibrated, merge_from: Path, head: str, body: str) -> ExportFile:
    relative, text, found, note = _base(merge_from, head, body, CAMERA_FILE, f"Robots/{head}/{body}/{CAMERA_FILE}")
    path = merge_from / found
    root = cfgtext.parse_cfg(text, path)
    paths = camera_paths(root, path)
    cameras, notes = camera_notes(cal, "kept as it was")
    new = {paths[name] + (axis,): deg_literal(rpy[i]) for name, rpy in cameras.items() for axis, i in CAMERA_AXES}
    kept = [key for key in root.fields if key not in {keys[0] for keys in new}]
    notes.append("kept as they were: " + ", ".join(kept))
    return ExportFile(relative, cfgtext.replace_literals(text, root, new, path), [note] + notes)
