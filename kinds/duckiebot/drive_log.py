"""A Duckiebot's drive log (`naocal.drive_log/1`): the strict reader and the writer (docs/DUCKIEBOT.md).

    LOG/log.json     {"schema": "naocal.drive_log/1", "robot": {"id", "model"}, "camera": {"width_px", "height_px"},
                      "wheels": {"radius_m", "baseline_m", "k", "limit", "ticks_per_revolution" (optional)},
                      "markers": {"family": "tag36h11", "size_m"}, "boards": {"inner_corners": [7, 5], "square_m"},
                      "source"}
    LOG/wheels.csv   t_s,left_duty,right_duty     every wheel command as sent (duty in [-1, 1], positive drives
                                                  forward); each holds until the next row
    LOG/frames.csv   t_s,file                     one row per frame (t_s mid-exposure, the same clock), file
                                                  relative to LOG (PNG or JPEG)
    LOG/encoders.csv t_s,left_ticks,right_ticks   optional: cumulative signed ticks
    LOG/segments.csv t_s                          optional: one row per break (the robot may have been moved
                                                  between the rows before t_s and those at or after it)

Strict: every problem is one DataError naming the file and the line or field (missing files or fields, another
header row, times that decrease or repeat with other values, NaN or out-of-range duties, frames that are not PNG/JPEG
images of the camera's size or are damaged, paths or symbolic links that leave LOG). Tolerant of what valid exports
write (docs/DUCKIEBOT.md): any clock, a row repeated exactly (read once), a byte order mark, CRLF, blank lines,
log.json keys the format does not define (ignored, with a warning). Every file is read through solver.fileio (regular files, bounded size).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import logging
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import cv2
import numpy as np

from naocal.kinds.duckiebot.calibration_files import USUAL
from naocal.kinds.duckiebot.robot import ENCODER_MODELS, duckiebot, raw_pixels, robot_name_problem
from naocal.solver import fields
from naocal.solver.fields import fail
from naocal.solver.fileio import (append_durably, atomic_write_bytes, atomic_write_text, disk_full_as_error,
                                  native_stderr_held, read_bytes, read_json, read_text)

SCHEMA = "naocal.drive_log/1"
META_FILE, WHEELS_FILE, FRAMES_FILE, ENCODERS_FILE = "log.json", "wheels.csv", "frames.csv", "encoders.csv"
# A log in parts: each break's time, after which the robot's pose is unknown (a run stopped and resumed wherever the
# robot then stood: kinds.duckiebot.mission); every row at or after a break belongs to the part it starts
SEGMENTS_FILE = "segments.csv"
WHEELS_HEADER = ("t_s", "left_duty", "right_duty")
FRAMES_HEADER = ("t_s", "file")
ENCODERS_HEADER = ("t_s", "left_ticks", "right_ticks")
SEGMENTS_HEADER = ("t_s",)
MARKER_FAMILIES = ("tag36h11",)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
IMAGE_SIGNATURES = {".png": b"\x89PNG\r\n\x1a\n", ".jpg": b"\xff\xd8\xff", ".jpeg": b"\xff\xd8\xff"}
MAX_IMAGE_BYTES = 16 * 1024 ** 2  # a 640 x 480 PNG is under 1 MB
MAX_TICKS = 2 ** 53  # cumulative ticks beyond this lose integer precision as floats
MAX_TIME_S = 1e10  # seconds: any clock (Unix time included) for centuries
INT32_MIN, INT32_MAX = -2 ** 31, 2 ** 31 - 1  # Duckietown's encoder counters (WheelEncoderStamped.data)
WHOLE_NUMBER = re.compile(r"[+-]?[0-9]+")  # one sign at most, ASCII digits (int() takes others' digits too)
MIN_REAL_GAIN = USUAL["gain"][0]  # the lowest gain real robots' files hold: the fastest a wheel turns at a duty


@dataclass(frozen=True)
class Wheels:
    """The log's wheel description: nominal radius and baseline (m), Duckietown's k (rad/s per unit duty) and duty
    limit, encoder ticks per wheel revolution (None: no encoders)."""

    radius_m: float
    baseline_m: float
    k: float
    limit: float
    ticks_per_revolution: int | None = None


@dataclass(frozen=True)
class DriveLog:
    """A drive log read and checked. Times are seconds on the log's one clock; arrays are float64 except ticks."""

    path: Path
    robot_id: str
    model: str
    width_px: int
    height_px: int
    wheels: Wheels
    marker_family: str
    marker_size_m: float
    board_inner_corners: tuple[int, int]  # (columns, rows) of inner corners
    board_square_m: float
    source: str
    wheel_t_s: np.ndarray  # (n,) strictly increasing
    left_duty: np.ndarray  # (n,) in [-1, 1]; each holds until the next row
    right_duty: np.ndarray
    frame_t_s: np.ndarray  # (m,) strictly increasing, mid-exposure
    frame_files: tuple[str, ...]  # relative to `path`, POSIX separators
    encoder_t_s: np.ndarray | None = None  # (e,) strictly increasing, None without encoders.csv
    left_ticks: np.ndarray | None = None  # (e,) int64, cumulative signed
    right_ticks: np.ndarray | None = None
    segment_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (b,) the breaks, strictly increasing

    def meta(self) -> dict:
        """The log.json document of this log."""
        wheels = {"radius_m": self.wheels.radius_m, "baseline_m": self.wheels.baseline_m, "k": self.wheels.k,
                  "limit": self.wheels.limit}
        if self.wheels.ticks_per_revolution is not None:
            wheels["ticks_per_revolution"] = self.wheels.ticks_per_revolution
        return {"schema": SCHEMA, "robot": {"id": self.robot_id, "model": self.model},
                "camera": {"width_px": self.width_px, "height_px": self.height_px}, "wheels": wheels,
                "markers": {"family": self.marker_family, "size_m": self.marker_size_m},
                "boards": {"inner_corners": list(self.board_inner_corners), "square_m": self.board_square_m},
                "source": self.source}

    def duties_at(self, t_s):
        """(left, right) duties in force at times t_s (the last command at or before each; 0 before the first)."""
        index = np.searchsorted(self.wheel_t_s, np.asarray(t_s, dtype=float), side="right") - 1
        held = index >= 0
        safe = np.maximum(index, 0)
        return np.where(held, self.left_duty[safe], 0.0), np.where(held, self.right_duty[safe], 0.0)

    def frame_path(self, i: int) -> Path:
        return self.path / self.frame_files[i]

    def load_frame(self, i: int, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
        """Frame i decoded (BGR by default); DataError naming the file if it no longer decodes."""
        return decode_image(read_bytes(self.frame_path(i), max_bytes=MAX_IMAGE_BYTES), self.frame_path(i), flags)


# ------------------------------------------------------------------------------------------------ log.json

def parse_meta(doc, path) -> dict:
    """log.json checked: the keyword arguments of DriveLog's description fields. DataError naming the field. Keys
    the format does not define are ignored, with one warning naming them (an exporter's own notes: the bag's name,
    the camera's rate): everything naocal needs is required by name, so a misspelt one is refused as missing."""
    unknown = []

    def section(value, field, required, optional=()):
        fields.json_object(value, path, field, required, None)
        unknown.extend(f"{field}.{key}" if field else key for key in value if key not in (*required, *optional))
        return value

    section(doc, "", ("schema", "robot", "camera", "wheels", "markers", "boards", "source"))
    if doc["schema"] != SCHEMA:
        fail(path, f"expected {SCHEMA!r}, got {str(doc['schema'])[:40]!r}", "schema")
    robot = section(doc["robot"], "robot", ("id", "model"))
    problem = robot_name_problem(robot["id"])
    if problem:
        fail(path, problem, "robot.id")
    camera = section(doc["camera"], "camera", ("width_px", "height_px"))
    wheels = section(doc["wheels"], "wheels", ("radius_m", "baseline_m", "k", "limit"), ("ticks_per_revolution",))
    ticks = wheels.get("ticks_per_revolution")
    markers = section(doc["markers"], "markers", ("family", "size_m"))
    if markers["family"] not in MARKER_FAMILIES:
        fail(path, f"unsupported marker family {str(markers['family'])[:40]!r} (expected "
             f"{', '.join(MARKER_FAMILIES)})", "markers.family")
    boards = section(doc["boards"], "boards", ("inner_corners", "square_m"))
    if unknown:
        logging.getLogger(__name__).warning("%s: ignored the fields the drive log format does not define: %s", path,
                                            ", ".join(fields.shown(key) for key in unknown[:10]))
    corners = boards["inner_corners"]
    if not isinstance(corners, list) or len(corners) != 2:
        fail(path, "expected [columns, rows] of inner corners", "boards.inner_corners")
    # agent.board_detect finds boards of 3..40 squares a side: 2..39 inner corners
    corners = tuple(fields.count(c, path, f"boards.inner_corners[{i}]", 2, 39) for i, c in enumerate(corners))
    return dict(
        robot_id=robot["id"], model=fields.text(robot["model"], path, "robot.model", max_chars=40, non_empty=True),
        width_px=fields.count(camera["width_px"], path, "camera.width_px", 16, 10000),
        height_px=fields.count(camera["height_px"], path, "camera.height_px", 16, 10000),
        wheels=Wheels(radius_m=fields.number(wheels["radius_m"], path, "wheels.radius_m", high=1.0, positive=True),
                      baseline_m=fields.number(wheels["baseline_m"], path, "wheels.baseline_m", high=2.0,
                                               positive=True),
                      k=fields.number(wheels["k"], path, "wheels.k", high=1000.0, positive=True),
                      limit=fields.number(wheels["limit"], path, "wheels.limit", high=1.0, positive=True),
                      ticks_per_revolution=None if ticks is None else
                      fields.count(ticks, path, "wheels.ticks_per_revolution", 1, 10 ** 6)),
        marker_family=markers["family"],
        marker_size_m=fields.number(markers["size_m"], path, "markers.size_m", high=1.0, positive=True),
        board_inner_corners=corners,
        board_square_m=fields.number(boards["square_m"], path, "boards.square_m", high=1.0, positive=True),
        source=fields.text(doc["source"], path, "source", max_chars=1000, non_empty=True))


# ------------------------------------------------------------------------------------------------ CSV files

def _rows(path, header: tuple[str, ...], text: str | None = None):
    """(line number, cells) of the data rows of a CSV file (or of `text`, the content it is about to get) whose
    header must be exactly `header`; blank lines are skipped. At least one data row."""
    if text is None:
        text = read_text(path)  # regular files only, bounded (solver/fileio.py)
    reader = csv.reader(io.StringIO(text, newline=""))
    rows, seen_header = [], False
    try:
        for cells in reader:
            if not cells or all(not c.strip() for c in cells):
                continue
            cells = [c.strip() for c in cells]
            if not seen_header:
                if tuple(cells) != header:
                    fail(path, f"expected the header {','.join(header)}, got {','.join(cells)[:80]!r}",
                         line=reader.line_num)
                seen_header = True
                continue
            if len(cells) != len(header):
                fail(path, f"expected {len(header)} cells ({','.join(header)}), got {len(cells)}",
                     line=reader.line_num)
            rows.append((reader.line_num, cells))
    except csv.Error as err:
        fail(path, f"malformed CSV: {err}", line=reader.line_num)
    if not seen_header:
        fail(path, f"empty file: expected the header {','.join(header)}", line=1)
    if not rows:
        fail(path, "no data rows after the header", line=reader.line_num)
    return rows


def _int_cell(text, path, line, field) -> int:
    whole, point, fraction = text.partition(".")  # '12.0': an exporter writing counts as floats
    if not WHOLE_NUMBER.fullmatch(whole) or len(text) > 24 or (point and fraction.strip("0")):
        fail(path, f"expected a whole number of ticks, got {text[:40]!r}", field, line)
    value = int(whole)
    if abs(value) >= MAX_TICKS:
        fail(path, f"{value} ticks is beyond any drive (at most 2^53 in size)", field, line)
    return value


def _times(rows, path) -> np.ndarray:
    t = np.empty(len(rows))
    for i, (line, cells) in enumerate(rows):
        t[i] = fields.number_text(cells[0], path, "t_s", line=line, low=-MAX_TIME_S, high=MAX_TIME_S)
        if i and t[i] < t[i - 1]:
            fail(path, f"time {float(t[i])!r} s is before the previous row's {float(t[i - 1])!r} s (times must "
                 "increase)", "t_s", line)
    return t


def _repeats_dropped(path, rows, t, values):
    """(rows, t, values) without the rows that repeat the previous row exactly (the same time and values: a recorder
    or an export writing one message twice); a row at the previous row's time with other values is refused (which
    of the two held is not known). `values`: one comparable item per row."""
    keep = [0]
    for i in range(1, len(rows)):
        if t[i] != t[i - 1]:
            keep.append(i)
        elif values[i] != values[i - 1]:
            fail(path, f"time {float(t[i])!r} s is also the previous row's, with other values (times must increase; only "
                 "a row repeated exactly is dropped)", "t_s", rows[i][0])
    return [rows[i] for i in keep], t[keep], [values[i] for i in keep]


def read_wheels(path, text: str | None = None):
    """(t_s, left_duty, right_duty) of wheels.csv; duties finite and within [-1, 1]."""
    rows = _rows(path, WHEELS_HEADER, text)
    t = _times(rows, path)
    duties = [tuple(fields.number_text(cells[c], path, WHEELS_HEADER[c], line=line, low=-1.0, high=1.0)
                    for c in (1, 2)) for line, cells in rows]
    _, t, duties = _repeats_dropped(path, rows, t, duties)
    duties = np.array(duties)
    return t, duties[:, 0], duties[:, 1]


def unwrap_int32(ticks: np.ndarray) -> np.ndarray:
    """Cumulative ticks with int32 wrap-arounds undone (Duckietown's WheelEncoderStamped.data is an int32 counted
    since boot: past 2^31 - 1 it goes on from -2^31). Only a column whose every value is an int32 can have wrapped;
    a step of 2^31 or more between two rows is then a wrap (no wheel turns half the counter between two readings:
    see max_tick_step), and the counts go on from the first."""
    if len(ticks) < 2 or ticks.min() < INT32_MIN or ticks.max() > INT32_MAX:
        return ticks
    steps = np.diff(ticks)
    steps = np.where(steps >= 2 ** 31, steps - 2 ** 32, np.where(steps <= -2 ** 31, steps + 2 ** 32, steps))
    return np.concatenate([ticks[:1], ticks[0] + np.cumsum(steps)])


# The longest a count may be held unchanged in a row while its wheel turns: a row-per-message export holds the other
# wheel's count one publication period (Duckietown's encoder nodes: 30 Hz, 33 ms); 8 periods of margin.
HELD_COUNT_MAX_S = 0.25


def max_tick_step(dt_s: np.ndarray, wheels: Wheels, ticks_per_revolution: int) -> np.ndarray:
    """The most ticks a wheel can turn in `dt_s` (s): at the log's limit duty through Duckietown's forward map
    w = u k / (gain - |trim|) with the lowest gain real robots' files hold (MIN_REAL_GAIN: a DB21 at limit 1, k 27:
    90 rad/s, 2.9 m/s on the ground, three times its top speed), and a tick either end for the counts' rounding."""
    rate_radps = wheels.limit * wheels.k / MIN_REAL_GAIN
    return rate_radps * np.asarray(dt_s) * ticks_per_revolution / (2 * math.pi) + 2.0


def impossible_tick_step(t_s, ticks, wheels: Wheels, *, counts_held: bool = True):
    """The first row of a count column (`ticks`: cumulative, int32 wrap-arounds undone, at strictly increasing times
    `t_s`) that steps from the row before by more than the wheel can turn in between (max_tick_step): (its index,
    why), or None. The one check of encoders.csv's reader and of what writes it (write_encoders, the ROS driver's rows
    as they come).

    "In between" starts where the count last changed, up to HELD_COUNT_MAX_S before the row before: a ROS bag export
    writes a row per encoder message with the other wheel's count held, so a wheel's ticks of a whole publication
    period (Duckietown's encoder nodes: 30 Hz) may land a few ms after the row before (the other wheel's message); the
    first row's count may have been held from before the log. `counts_held=False`: every row was formed once both
    wheels had counted since the row before (the ROS driver's rows), so a step spans the rows' interval alone."""
    t_s, ticks = np.asarray(t_s, dtype=float), np.asarray(ticks, dtype=np.int64)
    if wheels.ticks_per_revolution is None or len(ticks) < 2:
        return None
    changed = np.concatenate([[True], np.diff(ticks) != 0])
    held_since = t_s[np.maximum.accumulate(np.where(changed, np.arange(len(ticks)), 0))]
    held_since[held_since == t_s[0]] = -np.inf  # the first count: when it last changed is before the log
    interval_s = np.diff(t_s) + (np.minimum(t_s[:-1] - held_since[:-1], HELD_COUNT_MAX_S) if counts_held else 0.0)
    bound = max_tick_step(interval_s, wheels, wheels.ticks_per_revolution)
    beyond = np.flatnonzero(np.abs(np.diff(ticks)) > bound)
    if not len(beyond):
        return None
    i = int(beyond[0])
    return i + 1, (f"{int(ticks[i + 1] - ticks[i]):+d} ticks since the previous row ({float(t_s[i + 1] - t_s[i]):.4g} "
                   f"s before; the count last changed {float(interval_s[i]):.4g} s before): more than the wheel can "
                   f"turn ({bound[i]:.0f} ticks at most: the limit duty "
                   f"{wheels.limit:g} at k {wheels.k:g} with gain {MIN_REAL_GAIN:g}, "
                   f"{wheels.ticks_per_revolution} ticks a revolution)")


def read_encoders(path, text: str | None = None, wheels: Wheels | None = None):
    """(t_s, left_ticks, right_ticks) of encoders.csv; ticks whole numbers (int64, '12.0' read as 12), int32
    wrap-arounds undone (unwrap_int32). With `wheels` (ticks_per_revolution given): a step between rows larger than
    the wheel can turn (max_tick_step) is refused, naming its line."""
    rows = _rows(path, ENCODERS_HEADER, text)
    t = _times(rows, path)
    ticks = [tuple(_int_cell(cells[c], path, line, ENCODERS_HEADER[c]) for c in (1, 2)) for line, cells in rows]
    rows, t, ticks = _repeats_dropped(path, rows, t, ticks)
    ticks = np.array(ticks, dtype=np.int64)
    left, right = unwrap_int32(ticks[:, 0]), unwrap_int32(ticks[:, 1])
    for name, column in (("left_ticks", left), ("right_ticks", right)):
        found = impossible_tick_step(t, column, wheels) if wheels is not None else None
        if found:
            fail(path, found[1], name, rows[found[0]][0])
    return t, left, right


def read_segments(path, text: str | None = None) -> np.ndarray:
    """The break times of segments.csv, strictly increasing (a row repeated exactly read once)."""
    rows = _rows(path, SEGMENTS_HEADER, text)
    t = _times(rows, path)
    _, t, _ = _repeats_dropped(path, rows, t, [None] * len(rows))
    return t


def frame_file_problem(name: str, log_dir: Path) -> str | None:
    """Why a frames.csv `file` cell cannot name a frame inside LOG, or None. Relative POSIX paths only, no '..',
    and the file (symbolic links followed) must lie inside LOG."""
    if not name or "\\" in name or "\x00" in name or not name.isprintable():
        return "expected a relative path with '/' separators"
    pure = PurePosixPath(name)
    if pure.is_absolute() or ".." in pure.parts:
        return f"{name[:60]!r} leaves the log directory (absolute or '..')"
    if pure.suffix.lower() not in IMAGE_SUFFIXES:
        return f"{name[:60]!r} is not a PNG or JPEG file name ({', '.join(IMAGE_SUFFIXES)})"
    if not inside_log(log_dir, log_dir / pure):
        return f"{name[:60]!r} leads outside the log directory (a symbolic link)"
    return None


def inside_log(log_dir, path) -> bool:
    """Whether `path` (symbolic links followed) lies inside the log directory: a log is read from itself only."""
    real_dir = os.path.realpath(log_dir)
    return os.path.commonpath([real_dir, os.path.realpath(path)]) == real_dir


def decode_image(data: bytes, path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """The PNG or JPEG image in `data` (read from `path`), or DataError naming the file."""
    suffix = Path(path).suffix.lower()
    signature = IMAGE_SIGNATURES.get(suffix)
    if signature is None or not data.startswith(signature):
        fail(path, f"not a {'PNG' if suffix == '.png' else 'JPEG'} image (its first bytes do not say so)")
    said = []  # what libpng / libjpeg print on a damaged file: into our one line, not onto stderr beside it
    with native_stderr_held(said):
        image = cv2.imdecode(np.frombuffer(data, np.uint8), raw_pixels(flags))
    words = " ".join(said[0].split())[:160] if said else ""
    if image is None or image.size == 0:
        fail(path, "not a readable image (the decoder refused it: damaged or truncated"
             + (f": {words})" if words else ")"))
    # libjpeg decodes a damaged JPEG with a warning, grey blocks where the data were lost: a frame with invented
    # pixels. Only 'extraneous bytes before marker' is harmless (padding some cameras, the Pi's among them, write).
    damage = [w for w in said[0].splitlines() if w.strip() and "extraneous bytes" not in w] if said else []
    if damage:
        fail(path, f"a damaged image (the decoder said: {' '.join(damage[0].split())[:160]})")
    return image


def read_frames(path, log_dir: Path, width_px: int, height_px: int, *, check_images: bool = True,
                text: str | None = None):
    """(t_s, files) of frames.csv. Each file must name a distinct PNG/JPEG inside LOG; with `check_images` each is
    decoded and must be width_px x height_px (a frame that is not an image is refused before any work)."""
    rows = _rows(path, FRAMES_HEADER, text)
    rows, t, _ = _repeats_dropped(path, rows, _times(rows, path), [os.path.normpath(cells[1]) for _, cells in rows])
    files, seen = [], {}
    for line, cells in rows:
        name = cells[1]
        problem = frame_file_problem(name, log_dir)
        if problem:
            fail(path, problem, "file", line)
        key = os.path.normpath(name)
        if key in seen:
            fail(path, f"{name[:60]!r} is already the frame of line {seen[key]}", "file", line)
        seen[key] = line
        if check_images:
            image_path = log_dir / name
            image = decode_image(read_bytes(image_path, max_bytes=MAX_IMAGE_BYTES), image_path,
                                 cv2.IMREAD_UNCHANGED)
            if image.shape[:2] != (height_px, width_px):
                fail(image_path, f"image is {image.shape[1]} x {image.shape[0]} px, log.json's camera is "
                                  f"{width_px} x {height_px}")
        files.append(str(PurePosixPath(name)))
    return t, tuple(files)


def read_drive_log(directory, *, check_images: bool = True) -> DriveLog:
    """Read and check the drive log in `directory` (module docstring). DataError (one line naming the file and the
    line or field) on any problem; nothing is written. `check_images`: decode every frame now (default)."""
    directory = Path(directory)
    if not directory.is_dir():
        hint = f" (name its folder, {directory.parent})" if directory.is_file() and (directory.parent / META_FILE).is_file() \
            else ""
        fail(directory, f"not a directory: expected a drive log (log.json, wheels.csv, frames.csv){hint}")
    for name in (META_FILE, WHEELS_FILE, FRAMES_FILE, ENCODERS_FILE, SEGMENTS_FILE):
        if os.path.lexists(directory / name) and not inside_log(directory, directory / name):
            fail(directory / name, "a symbolic link leading outside the log directory (a log is read from itself only)")
    meta = parse_meta(read_json(directory / META_FILE), directory / META_FILE)
    wheel_t, left, right = read_wheels(directory / WHEELS_FILE)
    frame_t, files = read_frames(directory / FRAMES_FILE, directory, meta["width_px"], meta["height_px"],
                                 check_images=check_images)
    encoders = (None, None, None)
    encoders_path = directory / ENCODERS_FILE
    if os.path.lexists(encoders_path):
        if meta["wheels"].ticks_per_revolution is None:
            # optional in the format: a DB21's encoders count 135 a revolution, whatever recorded the log
            if meta["model"] not in ENCODER_MODELS:
                fail(directory / META_FILE, f"{ENCODERS_FILE} is present but the wheels' ticks_per_revolution is not "
                     f"given, nor known for the model {fields.shown(meta['model'])} (known for "
                     f"{', '.join(ENCODER_MODELS)})", "wheels.ticks_per_revolution")
            meta["wheels"] = dataclasses.replace(
                meta["wheels"], ticks_per_revolution=duckiebot(meta["model"]).ticks_per_revolution)
        encoders = read_encoders(encoders_path, wheels=meta["wheels"])
    segments = read_segments(directory / SEGMENTS_FILE) if os.path.lexists(directory / SEGMENTS_FILE) else np.zeros(0)
    return DriveLog(path=directory, **meta, wheel_t_s=wheel_t, left_duty=left, right_duty=right, frame_t_s=frame_t,
                    frame_files=files, encoder_t_s=encoders[0], left_ticks=encoders[1], right_ticks=encoders[2],
                    segment_t_s=segments)


# ------------------------------------------------------------------------------------------------ writing

def csv_text(header, rows) -> str:
    return ",".join(header) + "\n" + "".join(",".join(cells) + "\n" for cells in rows)


def write_drive_log(directory, meta: dict, wheels, frames, encoders=None, segments=None) -> DriveLog:
    """Write a drive log's text files atomically and return it as read back (the frames' image files must already
    be in `directory`). meta: the log.json document; wheels: (t_s, left_duty, right_duty) arrays; frames:
    (t_s, files); encoders: (t_s, left_ticks, right_ticks) or None; segments: the breaks' times or None (no
    segments.csv). Floats as repr(): a round trip is exact.
    Every file's content is checked as the reader would before anything is written (DataError naming it)."""
    directory = Path(directory)
    checked = parse_meta(meta, directory / META_FILE)
    texts = {WHEELS_FILE: csv_text(WHEELS_HEADER, ([repr(float(t)), repr(float(a)), repr(float(b))]
                                                    for t, a, b in zip(*wheels))),
             FRAMES_FILE: csv_text(FRAMES_HEADER, ([repr(float(t)), _csv_cell(f)] for t, f in zip(*frames)))}
    if encoders is not None:
        texts[ENCODERS_FILE] = csv_text(ENCODERS_HEADER, ([repr(float(t)), str(int(a)), str(int(b))]
                                                           for t, a, b in zip(*encoders)))
    if segments is not None:
        texts[SEGMENTS_FILE] = csv_text(SEGMENTS_HEADER, ([repr(float(t))] for t in segments))
    texts[META_FILE] = json.dumps(meta, indent=2) + "\n"
    read_wheels(directory / WHEELS_FILE, texts[WHEELS_FILE])
    read_frames(directory / FRAMES_FILE, directory, checked["width_px"], checked["height_px"],
                text=texts[FRAMES_FILE])
    if encoders is not None:
        read_encoders(directory / ENCODERS_FILE, texts[ENCODERS_FILE], wheels=checked["wheels"])
    if segments is not None:
        read_segments(directory / SEGMENTS_FILE, texts[SEGMENTS_FILE])
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in texts.items():
        atomic_write_text(directory / name, text)
    return read_drive_log(directory)


def write_encoders(log_dir, rows, ticks_per_revolution: int) -> int:
    """Write encoder rows (t_s, left_ticks, right_ticks) as LOG/encoders.csv, and the encoders' resolution into
    LOG/log.json (wheels.ticks_per_revolution, which a log with encoders must give); each file atomically and checked
    as the reader does first. For a finished log: a log.json changed under a resumable run would no longer be its
    own. Returns the rows written (0: nothing written, as for a robot without encoders, the DB18)."""
    rows = list(rows)
    if not rows:
        return 0
    log_dir = Path(log_dir)
    text = csv_text(ENCODERS_HEADER, ([repr(float(t)), str(a), str(b)] for t, a, b in rows))
    meta = read_json(log_dir / META_FILE)
    wheels = dataclasses.replace(parse_meta(meta, log_dir / META_FILE)["wheels"],
                                 ticks_per_revolution=ticks_per_revolution)
    read_encoders(log_dir / ENCODERS_FILE, text, wheels)  # as read_drive_log will: a jump is refused, naming its line
    if meta.get("wheels", {}).get("ticks_per_revolution") != ticks_per_revolution:
        meta["wheels"]["ticks_per_revolution"] = ticks_per_revolution
        parse_meta(meta, log_dir / META_FILE)
        atomic_write_text(log_dir / META_FILE, json.dumps(meta, indent=2) + "\n")
    atomic_write_text(log_dir / ENCODERS_FILE, text)
    return len(rows)


def _csv_cell(text: str) -> str:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="").writerow([text])
    return buffer.getvalue()


def write_frame(directory, name: str, image: np.ndarray) -> None:
    """Write one frame image (PNG or JPEG by `name`'s suffix) atomically into the log directory."""
    suffix = PurePosixPath(name).suffix.lower()
    ok, data = cv2.imencode(".png" if suffix == ".png" else ".jpg", image)
    if not ok:
        raise ValueError(f"cannot encode {name} as {suffix}")
    atomic_write_bytes(Path(directory) / name, data.tobytes())


class DriveLogAppender:
    """A drive log written while it is recorded, each row saved at once: every command and frame is durable when
    `add_wheels` / `add_frame` return (frame image first, then its CSV; each file replaced whole through a temporary
    file, fsync and rename, so a crash leaves the previous version or the new one, never a torn row). Rows are
    checked as the reader would (times strictly increasing across both files' clock, duties finite in [-1, 1]).
    Opening a directory that holds a log continues it (its log.json must be `meta`)."""

    def __init__(self, directory, meta: dict):
        self.directory = Path(directory)
        self.meta = meta
        parse_meta(meta, self.directory / META_FILE)
        self.wheels, self.frames, self.breaks = [], [], []
        if (self.directory / META_FILE).exists():
            stored = read_json(self.directory / META_FILE)
            if stored != json.loads(json.dumps(meta)):
                fail(self.directory / META_FILE, "this log was recorded with another robot or set-up (nothing was "
                                                  "changed)")
            if (self.directory / WHEELS_FILE).exists():
                self.wheels = [tuple(map(float, row)) for row in zip(*read_wheels(self.directory / WHEELS_FILE))]
            if (self.directory / FRAMES_FILE).exists():
                t, files = read_frames(self.directory / FRAMES_FILE, self.directory, 1, 1, check_images=False)
                self.frames = list(zip(t.tolist(), files))
            if (self.directory / SEGMENTS_FILE).exists():
                self.breaks = read_segments(self.directory / SEGMENTS_FILE).tolist()
        else:
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.directory / META_FILE, json.dumps(meta, indent=2) + "\n")

    def last_time_s(self) -> float:
        return max((rows[-1][0] for rows in (self.wheels, self.frames) if rows), default=-math.inf)

    def _check_time(self, t_s: float, rows, what: str) -> None:
        if not math.isfinite(t_s) or (rows and t_s <= rows[-1][0]):
            raise ValueError(f"{what} time {t_s!r} s does not follow the previous row's (times must strictly increase)")

    def add_wheels(self, t_s: float, left_duty: float, right_duty: float) -> None:
        self._check_time(t_s, self.wheels, "wheel command")
        for duty in (left_duty, right_duty):
            if not (math.isfinite(duty) and -1.0 <= duty <= 1.0):
                raise ValueError(f"duty {duty!r} is not within [-1, 1]")
        self.wheels.append((float(t_s), float(left_duty), float(right_duty)))
        atomic_write_text(self.directory / WHEELS_FILE, csv_text(WHEELS_HEADER, (
            [repr(t), repr(a), repr(b)] for t, a, b in self.wheels)))

    def add_break(self, t_s: float) -> None:
        """Start a new segment at t_s, after every row so far: the robot may have moved since the last one."""
        if not (math.isfinite(t_s) and t_s > self.last_time_s()):
            raise ValueError(f"a break at {t_s!r} s does not follow the log's last row ({self.last_time_s()!r} s)")
        self.breaks.append(float(t_s))
        atomic_write_text(self.directory / SEGMENTS_FILE, csv_text(SEGMENTS_HEADER, ([repr(t)] for t in self.breaks)))

    def add_frame(self, t_s: float, name: str, image: np.ndarray) -> None:
        self._check_time(t_s, self.frames, "frame")
        problem = frame_file_problem(name, self.directory)
        if problem:
            raise ValueError(problem)
        write_frame(self.directory, name, image)
        self.frames.append((float(t_s), name))
        atomic_write_text(self.directory / FRAMES_FILE, csv_text(FRAMES_HEADER, (
            [repr(t), _csv_cell(f)] for t, f in self.frames)))


class EncoderJournal:
    """Encoder ticks saved as they come, in encoders.csv's format: `append(rows)` writes the rows (t_s, left_ticks,
    right_ticks) in one append, then fsync, so what was appended survives a crash (DatasetAppender's way: an append
    is cheap at the encoders' 60 rows a second, where rewriting the whole file would not be). Rows are checked as
    the reader would first (times strictly increasing, whole ticks). Opening a file that holds rows continues it
    (`rows`): a torn last line (a crash mid-append) is cut off; anything else the reader refuses is a DataError
    naming it."""

    def __init__(self, path):
        self.path = Path(path)
        self.rows = []
        self._new_file = True  # the next append writes the header first
        if not os.path.lexists(self.path):
            return
        data = read_bytes(self.path)
        keep = data.rfind(b"\n") + 1
        if keep < len(data):  # the append a crash cut short: never saved, so never counted
            with disk_full_as_error(self.path), open(self.path, "r+b") as f:
                f.truncate(keep)
                f.flush()
                os.fsync(f.fileno())
        text = data[:keep].decode("utf-8", errors="replace")
        if text.count("\n") >= 2:  # the header and a row: the reader's checks; else the next append starts it anew
            t, left, right = read_encoders(self.path, text)
            self.rows = list(zip(t.tolist(), left.tolist(), right.tolist()))
            self._new_file = False

    def append(self, rows) -> None:
        rows = [(float(t), int(a), int(b)) for t, a, b in rows]
        if not rows:
            return
        previous = self.rows[-1][0] if self.rows else -math.inf
        for t, a, b in rows:
            if not (math.isfinite(t) and t > previous and abs(a) < MAX_TICKS and abs(b) < MAX_TICKS):
                raise ValueError(f"{self.path}: encoder row ({t!r}, {a!r}, {b!r}) does not follow the previous "
                                 f"row ({previous!r} s) or is beyond any count")
            previous = t
        text = csv_text(ENCODERS_HEADER, ([repr(t), str(a), str(b)] for t, a, b in rows))
        data = (text if self._new_file else text.split("\n", 1)[1]).encode("utf-8")
        append_durably(self.path, data, new_file=self._new_file)
        self._new_file = False
        self.rows += rows
