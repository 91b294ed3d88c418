"""What the team exports share: the values an offsets file calibrates, ids checked again before they go into another
program's files or file names, angle literals, provenance comments, and reading the team's existing files.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from naocal.solver.errors import DataError, NaocalError
from naocal.solver.offsets import ROBOT_ID_PATTERN, ROBOT_ID_RULE

MAX_TEAM_FILE_BYTES = 1 << 20  # team config files are a few kB
_CREATED = re.compile(r"[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9:.]+(?:Z|[+-][0-9]{2}:?[0-9]{2})?")


@dataclass(frozen=True)
class Calibrated:
    """The values one offsets file calibrates, read through solver.offsets' API; nothing else is exported.

    joints_rad : {NAOqi joint name: c}, c added to commands and subtracted from readings, only the joints fitted.
    cameras_rad : {camera name: (roll, pitch, yaw)}, the model's alpha (T_head_cam = T_nominal @ Ry(pitch) @
        Rx(roll) @ Rz(yaw), NAO camera frame), only the cameras fitted.
    """

    joints_rad: dict
    cameras_rad: dict
    robot: dict
    created: str


def calibrated(offsets) -> Calibrated:
    return Calibrated(joints_rad={joint: float(c) for joint, c in offsets.joint_offsets_rad.items()},
                      cameras_rad={camera: offsets.camera_rpy(camera) for camera in offsets.camera_rotation_rad},
                      robot=dict(offsets.robot), created=str(offsets.created))


@dataclass
class ExportFile:
    """One file of an export: `path` relative to the output directory ('/'-separated), its text, and notes for the
    user saying which values naocal wrote and which it kept."""

    path: str
    text: str
    notes: list = field(default_factory=list)


def checked_id(value, what: str) -> str:
    """`value` if it is a safe id for a file name or a config file; NaocalError otherwise (defence in depth: the
    offsets reader checks the same pattern)."""
    if value is None:
        raise NaocalError(f"{what} is unknown: give it with --{what.split('.')[-1].replace('_', '-')}")
    if not isinstance(value, str) or not ROBOT_ID_PATTERN.fullmatch(value):
        raise NaocalError(f"{what} {json.dumps(value)[:40]} is not a valid id: {ROBOT_ID_RULE}")
    return value


def comment_text(text) -> str:
    """`text` on one line of printable ASCII (escaped like a JSON string), safe in a // comment or an XML comment."""
    return json.dumps(str(text), ensure_ascii=True)[1:-1].replace("--", "-\\u002d").replace("*/", "*\\u002f")


def provenance(cal: Calibrated, source_name: str) -> str:
    """'Written by naocal from FILE: robot ..., body ..., head ..., calibrated TIME.' (every part checked)."""
    ids = [("unknown" if cal.robot.get(key) is None else checked_id(cal.robot.get(key), f"robot.{key}"))
           for key in ("id", "body_id", "head_id")]
    if not _CREATED.fullmatch(cal.created):
        raise NaocalError(f"created {json.dumps(cal.created)[:40]} is not an ISO-8601 time")
    return (f"Written by naocal from {comment_text(source_name)}: robot {ids[0]}, body {ids[1]}, head {ids[2]}, "
            f"calibrated {cal.created}.")


def deg_literal(angle_rad: float, digits: int = 6) -> str:
    """B-Human's angle literal, e.g. -3.5deg (1e-6 deg resolution, far below any joint's repeatability)."""
    if not math.isfinite(angle_rad):
        raise NaocalError(f"non-finite angle {angle_rad!r}")
    text = f"{math.degrees(angle_rad):.{digits}f}".rstrip("0").rstrip(".")
    return ("0" if text in ("-0", "") else text) + "deg"


def read_team_file(path: Path) -> str | None:
    """The text of a team's config file, None if there is none; refuses what is not a small regular file (a FIFO
    would block, /dev/zero would never end)."""
    if not path.exists() and not path.is_symlink():
        return None
    if not path.is_file():
        raise DataError(path, "not a regular file")
    if path.stat().st_size > MAX_TEAM_FILE_BYTES:
        raise DataError(path, f"larger than {MAX_TEAM_FILE_BYTES} bytes: not a calibration file")
    from naocal.solver.dataset import read_text

    return read_text(path)


def first_existing(root: Path, relative_paths) -> str | None:
    """The first of `relative_paths` ('/'-separated) that exists below `root`, in the order a team's code searches."""
    for relative in relative_paths:
        candidate = root / relative
        if candidate.exists() or candidate.is_symlink():
            return relative
    return None
