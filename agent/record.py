"""Saving captures as they are made: the dataset (fsync'd appends), the images, and the run's progress.

Order of writes per capture: the image file (atomic), then the observations (one fsync'd append), then the
progress file (atomic). A crash between them leaves at worst an image without observations, which a resumed run
overwrites; a capture is in the dataset completely or not at all (solver.dataset.DatasetAppender).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from naocal.solver import fields
from naocal.solver.dataset import IMAGES_DIR, DatasetAppender, parse_json_text, read_text
from naocal.solver.errors import DataError
from naocal.solver.fileio import atomic_write_bytes, atomic_write_text
from naocal.solver.joints import JOINTS
from naocal.solver.nao_model import board_vertices_sole

log = logging.getLogger(__name__)

PROGRESS_SCHEMA = "naocal.progress/1"
MAX_ROBOT_TIME_S = 1e6  # 11 days of measuring: a calibration takes minutes


def read_progress(path) -> dict:
    """A run's progress.json (a fresh progress when `path` is None or absent); DataError naming the field unless its
    values are what a run writes (check_progress). agent.rundir reads it before a resumed run starts."""
    progress = {"schema": PROGRESS_SCHEMA, "robot_time_s": 0.0, "skipped": {}, "sessions": 0}
    if path is not None and Path(path).exists():
        doc = parse_json_text(read_text(path), path)
        if not isinstance(doc, dict) or doc.get("schema") != PROGRESS_SCHEMA:
            raise DataError(path, f"expected schema {PROGRESS_SCHEMA!r}", field="schema")
        progress.update(doc)
        check_progress(progress, path)
    return progress


def check_progress(progress: dict, path) -> None:
    """DataError naming the field unless progress.json's values are what a run writes: robot_time_s a number of
    seconds within MAX_ROBOT_TIME_S, sessions a count, skipped {image number: reason}."""
    fields.number(progress["robot_time_s"], path, "robot_time_s", low=0, high=MAX_ROBOT_TIME_S)
    fields.count(progress["sessions"], path, "sessions")
    skipped = progress["skipped"]
    if not isinstance(skipped, dict):
        raise DataError(path, "expected {image number: reason}", field="skipped")
    for image, reason in skipped.items():
        if not (image.isdigit() and len(image) <= 15 and isinstance(reason, str)):
            raise DataError(path, "expected an image number and the reason it was skipped", field=f"skipped.{image}")


@dataclass
class CaptureRecord:
    """One capture, ready to be saved. Angles (14,) in solver.joints.JOINTS order, rad; velocities rad/s."""

    image: int
    leg: str
    stance: int
    head_posture: int
    vertices_px: np.ndarray  # (24, 2), naocal vertex order
    measured_rad: np.ndarray
    commanded_rad: np.ndarray
    direction: np.ndarray  # -1/0/1
    velocity_rad_s: np.ndarray
    t_image_s: float
    t_joints_s: float
    camera: str = "bottom"

    def rows(self) -> dict:
        """The observations.csv columns of this capture (24 rows), naocal.dataset/2: its camera, the sandal
        of `leg` (target 'L' or 'R'), its vertices' nominal positions in the sole frame."""
        V = board_vertices_sole()
        n = len(V)
        cols = {
            "image": [self.image] * n, "camera": [self.camera] * n, "target": [self.leg] * n,
            "stance": [self.stance] * n, "head_posture": [self.head_posture] * n, "vertex": list(range(n)),
            "u_px": self.vertices_px[:, 0], "v_px": self.vertices_px[:, 1],
            "x_mount_m": V[:, 0], "y_mount_m": V[:, 1], "z_mount_m": V[:, 2],
            "t_image_s": [self.t_image_s] * n, "t_joints_s": [self.t_joints_s] * n,
        }
        for k, joint in enumerate(JOINTS):
            cols[joint] = [float(self.measured_rad[k])] * n
            cols["cmd_" + joint] = [float(self.commanded_rad[k])] * n
            cols["dir_" + joint] = [int(self.direction[k])] * n
            cols["vel_" + joint] = [float(self.velocity_rad_s[k])] * n
        return cols


class CaptureStore:
    """The dataset directory being filled, plus the progress file (skipped captures, robot time).

    dataset_dir : the naocal.dataset/2 directory (created if absent).
    meta : its dataset.json contents (must match an existing one).
    progress_path : where to keep progress (None: in memory only, e.g. for `naocal simulate`).
    """

    def __init__(self, dataset_dir, meta: dict, *, progress_path=None, save_images: bool = True):
        self.dataset_dir = Path(dataset_dir)
        self.appender = DatasetAppender(self.dataset_dir, meta)
        self.save_images = save_images
        self.progress_path = Path(progress_path) if progress_path else None
        self.progress = read_progress(self.progress_path)
        self.progress["sessions"] = int(self.progress["sessions"]) + 1
        self._robot_time_before = float(self.progress["robot_time_s"])

    @property
    def repair(self) -> str | None:
        """What the appender cut off a torn file on opening, if anything."""
        return self.appender.repair

    def saved_images(self) -> set[int]:
        return self.appender.captured_images()

    def skipped_images(self) -> dict[int, str]:
        return {int(k): v for k, v in self.progress["skipped"].items()}

    def done_images(self) -> set[int]:
        return self.saved_images() | set(self.skipped_images())

    def save(self, record: CaptureRecord, pixels: np.ndarray | None, robot_time_s: float) -> None:
        if self.save_images and pixels is not None:
            if pixels.ndim == 3 and np.array_equal(pixels[..., 0], pixels[..., 1]) and np.array_equal(
                    pixels[..., 0], pixels[..., 2]):
                pixels = pixels[..., 0]  # a grey image (the mock's): one channel is a third of the work
            ok, png = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, 1])  # fast; lossless anyway
            if ok:
                atomic_write_bytes(self.dataset_dir / IMAGES_DIR / f"{record.image:06d}.png", png.tobytes())
        self.appender.append(record.rows())
        self._write_progress(robot_time_s)

    def skip(self, image: int, reason: str, robot_time_s: float) -> None:
        log.warning("capture %d skipped: %s", image, reason)
        self.progress["skipped"][str(image)] = reason
        self._write_progress(robot_time_s)

    def robot_time_s(self, session_time_s: float) -> float:
        """Robot time of the measurement over all sessions, given this session's so far."""
        return self._robot_time_before + session_time_s

    def _write_progress(self, session_time_s: float) -> None:
        self.progress["robot_time_s"] = self.robot_time_s(session_time_s)
        if self.progress_path:
            atomic_write_text(self.progress_path, json.dumps(self.progress, indent=1) + "\n")
