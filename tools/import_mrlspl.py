"""Importing MRL-SPL's 2009 calibration samples (a standing NAO V3 looking at a board on the floor) as a
`naocal.dataset/2`.

The input directory (tests/data/realdata/mrlspl-nao-2009/ is one) holds `joints_raw.csv` and `image_<N>.png`:

- `joints_raw.csv`: a header, then one row per image: `image`, `camera_flag` (0 bottom, 1 top: the 23rd number
  of an upstream `.joint` file) and the 22 joint angles (rad) as upstream stored them, in B-Human's joint order
  of 2009 (`JOINT_ORDER`: head, left arm, right arm, left leg, right leg; github.com/mrlspl/auto-calibration,
  `fitnessFunction.m` reads the head from values 1-2, the legs from 11-16 and 17-22, the camera from 23).
  The header must name exactly these columns in this order, so that a file in another order is refused rather
  than read wrongly.
- `image_<N>.png`: the 320 x 240 image of row N.

What the importer does, and why:
- Joints: the robot description's joints are taken from their columns; the arms are dropped (no chain to the
  camera or the floor runs through them). HeadPitch is stored with the opposite sign to today's convention
  (positive = head up in the file: `SIGN`). Commanded angles are unknown: the readings are written as commands,
  directions 0. Times are unknown: 0 s.
- Corners: `agent.board_detect.detect_board` with the floor target's board (size, square, colours from the
  robot description). A 4 x 4 board looks the same turned by 180 deg, so the detector gives the corners in image
  order only; they are put in the target's vertex order by matching the nominal prediction (the robot
  description's kinematics at the read angles, `agent.corners.order_like_prediction`: every labelling is
  compared after removing the mean shift, so the 20-35 px nominal error does not matter, and a wrong turn misses
  by squares). The colours then check the choice: the square before vertex 0 must have the target's first colour.
- Gravity: per image, along -z of the support sole (the right foot stands flat), in the torso frame through
  the nominal right-leg kinematics at the read angles.
- Camera: `INTRINSICS`, the 320 x 240 bottom camera with the V3's nominal field of view (no lens calibration
  came with the data).

Everything done is written into dataset.json (`source`, `provenance`); the images are copied into DATASET/images/.
Errors name the file, line and field (DataError).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from pathlib import Path

import numpy as np

from naocal.solver.errors import DataError, NaocalError

JOINTS_FILE = "joints_raw.csv"
LICENCE_FILE = "LICENSE.MIT.txt"
IMAGE_PATTERN = "image_{}.png"
RAW_SUFFIX = "_raw_rad"

# B-Human's joint order of 2009 (its JointData; upstream .joint files), as named in joints_raw.csv.
JOINT_ORDER = (
    "HeadYaw", "HeadPitch",
    "LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll",
    "RShoulderPitch", "RShoulderRoll", "RElbowYaw", "RElbowRoll",
    "LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch", "LAnkleRoll",
    "RHipYawPitch", "RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll",
)
HEADER = ("image", "camera_flag") + tuple(j + RAW_SUFFIX for j in JOINT_ORDER)
SIGN = {"HeadPitch": -1.0}  # today's angle = SIGN * stored angle (1 for the joints not named)
CAMERAS = {0: "bottom", 1: "top"}  # camera_flag
MAX_ANGLE_RAD = 2 * math.pi  # a stored angle beyond a full turn is damage (the joint limits are checked later)
MAX_IMAGES = 10_000

TARGET = "floor"
SUPPORT_SOLE = "r_sole"  # the robot stands on its right foot: the floor is this sole's plane
GRAVITY_MPS2 = 9.81

# The NAO V3's camera at 320 x 240: no lens calibration came with the data. Upstream
# (mrlspl/auto-calibration, Jacobian_inFieldSpace_fromCameraSpace.m) uses the nominal horizontal field of view of
# 1.0641 rad (60.97 deg, "according to NAO documentation") over the image width and the image centre.
WIDTH_PX, HEIGHT_PX = 320, 240
HORIZONTAL_FOV_RAD = 1.0641
FOCAL_PX = (WIDTH_PX / 2) / math.tan(HORIZONTAL_FOV_RAD / 2)  # 271.8 px
INTRINSICS = {"width_px": WIDTH_PX, "height_px": HEIGHT_PX, "fx_px": FOCAL_PX, "fy_px": FOCAL_PX,
              "cx_px": (WIDTH_PX - 1) / 2, "cy_px": (HEIGHT_PX - 1) / 2,  # pixel (0, 0) is a pixel's centre
              "distortion": [0.0, 0.0, 0.0, 0.0, 0.0]}
INTRINSICS_SOURCE = ("fx = fy = 160 px / tan(1.0641 rad / 2) = 271.8 px: the nominal horizontal field of view "
                     "(60.97 deg) upstream's code uses (mrlspl/auto-calibration, "
                     "Jacobian_inFieldSpace_fromCameraSpace.m); principal point the image centre; no distortion; "
                     "not calibrated")


def read_joints(path: Path) -> list[dict]:
    """The rows of joints_raw.csv: [{"image", "camera_flag", "line", "raw": {joint: rad}}], checked."""
    from naocal.solver.fileio import read_text

    text = read_text(path)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise DataError(path, "empty file: expected a header and one row per image", line=1)
    header = tuple(name.strip() for name in rows[0])
    if header != HEADER:
        for k, expected in enumerate(HEADER):
            if k >= len(header) or header[k] != expected:
                got = repr(header[k]) if k < len(header) else "nothing"
                raise DataError(path, f"column {k + 1} must be {expected!r} (B-Human's joint order of 2009), "
                                      f"got {got}", line=1, field=expected)
        raise DataError(path, f"{len(header)} columns: expected {len(HEADER)}", line=1, field=header[len(HEADER)])
    out, seen = [], set()
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(HEADER):
            raise DataError(path, f"{len(row)} values: expected {len(HEADER)}", line=line)
        image = _integer(row[0], path, line, "image", 0, MAX_IMAGES)
        if image in seen:
            raise DataError(path, f"image {image} appears twice", line=line, field="image")
        seen.add(image)
        flag = _integer(row[1], path, line, "camera_flag", 0, 1)
        raw = {}
        for joint, cell in zip(JOINT_ORDER, row[2:]):
            raw[joint] = _angle(cell, path, line, joint + RAW_SUFFIX)
        out.append({"image": image, "camera_flag": flag, "line": line, "raw": raw})
    if not out:
        raise DataError(path, "no rows: expected one row per image", line=2)
    return out


def _integer(cell: str, path, line, field, low, high) -> int:
    try:
        value = int(cell.strip())
    except ValueError:
        raise DataError(path, f"expected a whole number, got {cell!r}", line=line, field=field) from None
    if not low <= value <= high:
        raise DataError(path, f"expected {low} to {high}, got {value}", line=line, field=field)
    return value


def _angle(cell: str, path, line, field) -> float:
    try:
        value = float(cell.strip())
    except ValueError:
        raise DataError(path, f"expected an angle in rad, got {cell!r}", line=line, field=field) from None
    if not math.isfinite(value) or abs(value) > MAX_ANGLE_RAD:
        raise DataError(path, f"implausible angle {value!r} rad (more than a full turn)", line=line, field=field)
    return value


def today_angles(raw: dict, joints) -> np.ndarray:
    """The robot description's `joints` (rad, today's sign convention) from one row's stored angles."""
    return np.array([SIGN.get(j, 1.0) * raw[j] for j in joints])


def check_limits(rows: list[dict], robot, path: Path) -> None:
    """Every angle read within its joint's limits and the margin a dataset allows (names the line and column)."""
    from naocal.solver.dataset import ANGLE_MARGIN_RAD

    for row in rows:
        for joint in robot.joints:
            low, high = robot.joint_limits(joint)
            value = SIGN.get(joint, 1.0) * row["raw"][joint]
            if not low - ANGLE_MARGIN_RAD <= value <= high + ANGLE_MARGIN_RAD:
                raise DataError(path, f"{joint} of {math.degrees(value):.1f} deg (sign as today's) is beyond its "
                                      f"limits ({math.degrees(low):.1f} to {math.degrees(high):.1f} deg)",
                                line=row["line"], field=joint + RAW_SUFFIX)


def nominal_pose(robot, camera: str, q: dict):
    """(T_torso_cam, T_torso_sole) of the nominal robot (URDF geometry, no offsets) at the angles `q`."""
    from naocal.solver.kinematics import chain_frames

    def fk(chain):
        angles = np.array([[q[j] for j in chain.joint_names]]) if chain.joint_names else np.zeros((1, 0))
        return chain_frames(chain, angles)[1][0]

    return fk(robot.camera_chain(camera)), fk(robot.target_chain(TARGET))


def predict_vertices(robot, camera: str, q: dict, intrinsics: dict) -> np.ndarray:
    """(n, 2) nominal projection of the floor target's vertices, in its vertex order, or a non-finite array when
    the board is behind the camera."""
    from naocal.solver.camera import project_points, transform_to_camera

    T_torso_cam, T_torso_sole = nominal_pose(robot, camera, q)
    vertices = robot.target(TARGET).vertices()
    p_torso = vertices @ T_torso_sole[:3, :3].T + T_torso_sole[:3, 3]
    uv, depth = project_points(transform_to_camera(T_torso_cam, p_torso), intrinsics)
    return np.where(depth[:, None] > 0, uv, np.nan)


def gravity_in_torso(robot, q: dict) -> np.ndarray:
    """Gravity (m/s^2) in the torso frame when the support sole lies flat: -z of the sole."""
    _, T_torso_sole = nominal_pose(robot, "bottom", q)
    return T_torso_sole[:3, :3] @ np.array([0.0, 0.0, -GRAVITY_MPS2])


def board_spec(robot):
    """The floor target's board as the detector describes it (size, square, colours from the description)."""
    from naocal.agent.board_detect import BoardSpec

    board = robot.target(TARGET).board
    return BoardSpec(board.columns, board.rows, board.square_m, tuple(board.colours))


def colour_check(image, channel: str, ordered: np.ndarray, board) -> str | None:
    """None when the square before vertex 0 has the board's first colour in `channel` (or the polarity there is
    unknown), else what is wrong. Compares the channel at the centres of squares (0, 0) and (1, 0)."""
    from naocal.agent.board_detect import channel_image, polarity

    sign = polarity(board, channel)
    if sign == 0:
        return None
    rows, columns = board.shape
    g = ordered.reshape(rows, columns, 2)
    along_x, along_y = g[0, 1] - g[0, 0], g[1, 0] - g[0, 0]
    square_00 = g[0, 0] - 0.5 * along_x - 0.5 * along_y
    square_10 = g[0, 0] + 0.5 * along_x - 0.5 * along_y
    img = channel_image(image, channel).astype(float)

    def value(p):
        x, y = int(round(p[0])), int(round(p[1]))
        if not (1 <= x < img.shape[1] - 1 and 1 <= y < img.shape[0] - 1):
            return None
        return float(img[y - 1:y + 2, x - 1:x + 2].mean())

    a, b = value(square_00), value(square_10)
    if a is None or b is None:
        return None
    if np.sign(a - b) == sign:
        return None
    return (f"the square before vertex 0 is not {board.colours[0]} in {channel} ({a:.0f} against {b:.0f} beside "
            f"it): is the board turned by 90 deg against the robot description's {TARGET!r} target?")


def detect_and_order(image_path: Path, image, robot, camera: str, q: dict, intrinsics: dict, board):
    """(corners (n, 2) in the target's vertex order, a dict saying how) for one image; DataError naming the image
    when the board is not found or its order cannot be told."""
    from naocal.agent.board_detect import detect_board
    from naocal.agent.corners import order_like_prediction

    found = detect_board(image, board)
    if found.image_order_px is None or found.reason not in (None, "ambiguous") or "boards of" in found.detail:
        raise DataError(image_path, f"no single {board} board found ({found.reason}: {found.detail})")
    predicted = predict_vertices(robot, camera, q, intrinsics)
    if not np.all(np.isfinite(predicted)):
        raise DataError(image_path, f"the nominal model puts the {TARGET!r} target behind the camera at this "
                                    "image's joint angles: are the angles or their signs right?")
    ordered, detail = order_like_prediction(found.image_order_px, predicted, board)
    if ordered is None:
        raise DataError(image_path, f"the corners' order cannot be told from the nominal prediction ({detail})")
    problem = colour_check(image, found.channel, ordered, board)
    if problem:
        raise DataError(image_path, problem)
    nominal_rms_px = float(np.sqrt(np.mean(np.sum((ordered - predicted) ** 2, axis=1))))
    how = {"channel": found.channel, "line_rms_px": round(float(found.line_rms_px), 3),
           "order": detail.split(",")[0].split(":")[0], "nominal_rms_px": round(nominal_rms_px, 2)}
    return ordered, how


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _read_checked(image_path: Path):
    """A 320 x 240 colour image (BGR), or DataError naming the file."""
    from naocal.tools.cmd_detect import read_image

    image = read_image(str(image_path))
    if image.shape[:2] != (HEIGHT_PX, WIDTH_PX):
        raise DataError(image_path, f"{image.shape[1]} x {image.shape[0]} pixels: expected {WIDTH_PX} x "
                                    f"{HEIGHT_PX} (the intrinsics are the 320 x 240 camera's)")
    if image.ndim != 3:
        raise DataError(image_path, "a grey image: the board's colours (orange, blue) need colour")
    return image


def build_dataset(directory) -> tuple[dict, dict, dict]:
    """(meta, columns, image files {image: path}) of the dataset the directory's samples make."""
    from naocal.solver.dataset import SCHEMA_V2
    from naocal.solver.robot import load_robot

    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(directory, "expected a directory holding joints_raw.csv and image_<N>.png")
    joints_path = directory / JOINTS_FILE
    rows = read_joints(joints_path)
    robot = load_robot("nao")
    check_limits(rows, robot, joints_path)
    board = board_spec(robot)
    joints = list(robot.joints)
    columns: dict = {name: [] for name in ("image", "camera", "target", "stance", "head_posture", "vertex", "u_px",
                                           "v_px", "x_mount_m", "y_mount_m", "z_mount_m", "t_image_s",
                                           "t_joints_s", "gravity_x_mps2", "gravity_y_mps2", "gravity_z_mps2")}
    for prefix in ("", "cmd_", "dir_"):
        for j in joints:
            columns[prefix + j] = []
    vertices = robot.target(TARGET).vertices()
    for row in rows:  # every image checked before any is searched: bad input is found at once
        _read_checked(directory / IMAGE_PATTERN.format(row["image"]))
    images, per_image, files = {}, {}, {}
    for row in rows:
        image_path = directory / IMAGE_PATTERN.format(row["image"])
        image = _read_checked(image_path)
        camera = CAMERAS[row["camera_flag"]]
        q = dict(zip(joints, today_angles(row["raw"], joints)))
        corners, how = detect_and_order(image_path, image, robot, camera, q, INTRINSICS, board)
        gravity = gravity_in_torso(robot, q)
        for k, (uv, p) in enumerate(zip(corners, vertices)):
            for name, value in (("image", row["image"]), ("camera", camera), ("target", TARGET),
                                ("stance", row["image"]), ("head_posture", 0), ("vertex", k), ("u_px", uv[0]),
                                ("v_px", uv[1]), ("x_mount_m", p[0]), ("y_mount_m", p[1]), ("z_mount_m", p[2]),
                                ("t_image_s", 0.0), ("t_joints_s", 0.0), ("gravity_x_mps2", gravity[0]),
                                ("gravity_y_mps2", gravity[1]), ("gravity_z_mps2", gravity[2])):
                columns[name].append(value)
            for j in joints:
                columns[j].append(q[j])
                columns["cmd_" + j].append(q[j])
                columns["dir_" + j].append(0)
        per_image[str(row["image"])] = {"camera_flag": row["camera_flag"], **how,
                                        "image_sha256": sha256(image_path)}
        images[row["image"]] = camera
        files[row["image"]] = image_path
    cameras_used = sorted(set(images.values()))
    target = robot.target(TARGET)
    meta = {
        "schema": SCHEMA_V2,
        "robot": {"id": "mrlspl-nao-2009", "model": "NAO V3 (2009)", "description": robot.name},
        "cameras": {name: dict(INTRINSICS) for name in cameras_used},
        "targets": {TARGET: {"columns": target.board.columns, "rows": target.board.rows,
                             "square_m": target.board.square_m, "mass_kg": target.board.mass_kg}},
        "joints": joints,
        "source": (f"naocal import mrlspl {directory.name}: {len(rows)} real images of a standing NAO V3 "
                   "(MRL-SPL 2009, MIT licence, github.com/mrlspl/auto-calibration, samples 1253146175); joints "
                   "as read (HeadPitch's sign turned to today's), commands unknown (= readings), times unknown "
                   f"(0 s); corners by naocal's detector, ordered by the nominal prediction; gravity along -z of "
                   f"{SUPPORT_SOLE}; camera: {INTRINSICS_SOURCE}"),
        "provenance": {
            "importer": "naocal import mrlspl",
            "input": directory.name,
            "joints_file_sha256": sha256(joints_path),
            "joint_order": "B-Human 2009 (JointData): " + ", ".join(JOINT_ORDER),
            "sign_changes": {j: s for j, s in SIGN.items()},
            "intrinsics": INTRINSICS_SOURCE,
            "gravity": f"per image, {GRAVITY_MPS2} m/s^2 along -z of {SUPPORT_SOLE} (the support foot, flat), "
                       "through the nominal right-leg kinematics",
            "detector": f"agent.board_detect.detect_board, board {board} squares of {board.square_m} m, colours "
                        f"{'/'.join(board.colours)}; order by agent.corners.order_like_prediction against the "
                        "nominal prediction, checked by the colours",
            "images": per_image,
        },
    }
    return meta, columns, files


def import_mrlspl(directory, out):
    """Write the dataset of `directory`'s samples to `out` (absent or an empty directory); returns it as read
    back (solver.dataset.Dataset). Nothing is left written when anything is wrong."""
    from naocal.agent.rundir import RunLock, entries
    from naocal.solver.dataset import IMAGES_DIR, META_FILE, OBSERVATIONS_FILE, write_dataset
    from naocal.solver.fileio import atomic_write_bytes, check_output_directory

    out = Path(out)
    check_output_directory(out)
    if entries(out):
        raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
    meta, columns, files = build_dataset(directory)
    with RunLock(out, f"naocal import mrlspl {directory} --out {out}"):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        written = []
        try:
            for image, path in files.items():
                written.append(atomic_write_bytes(out / IMAGES_DIR / f"{image:06d}.png", path.read_bytes()))
            licence = Path(directory) / LICENCE_FILE  # the images' licence travels with them
            if licence.is_file():
                written.append(atomic_write_bytes(out / IMAGES_DIR / LICENCE_FILE, licence.read_bytes()))
            dataset = write_dataset((meta, columns), out)
        except BaseException:  # the directory was empty: take back what we wrote, so no half dataset stays
            for path in written + [out / META_FILE, out / OBSERVATIONS_FILE]:
                path.unlink(missing_ok=True)
            if (out / IMAGES_DIR).is_dir() and not any((out / IMAGES_DIR).iterdir()):
                (out / IMAGES_DIR).rmdir()
            raise
    return dataset
