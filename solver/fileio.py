"""Atomic file writes: a reader sees either the old file or the complete new one, never a torn file.

Safe reads: only regular files of bounded size, JSON of bounded nesting and number size (errors name the file).
A write that fails for want of space or quota raises solver.errors.DiskFullError (naming the file and the free
bytes; exit code 3), so every writer reports a full disk in one line.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
import signal
import stat
import tempfile
import threading
from pathlib import Path

from naocal.solver.errors import DataError, DiskFullError

DISK_FULL_ERRNOS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "disk quota exceeded"}


def free_bytes(path) -> int | None:
    """Free bytes on the file system holding `path` (or its nearest existing parent), None if unknown."""
    path = Path(path).absolute()
    for candidate in (path, *path.parents):
        try:
            return shutil.disk_usage(candidate).free
        except OSError:
            continue
    return None


@contextlib.contextmanager
def interrupts_deferred():
    """Hold Ctrl-C / SIGTERM (Python-level handlers only) until the block ends, then deliver it.

    For a write and its bookkeeping that must happen together: a capture on disk that the run does not count
    as saved would make the summary one image short (and --resume would refuse the image as already saved).
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach Python in the main thread only
        return
    held = []
    previous = {}
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        handler = signal.getsignal(signum)
        if callable(handler):
            previous[signum] = handler
            signal.signal(signum, lambda number, frame: held.append((number, frame)))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if held:
            number, frame = held[0]
            previous[number](number, frame)


@contextlib.contextmanager
def disk_full_as_error(path):
    """Turn an OSError ENOSPC/EDQUOT raised inside the block into DiskFullError naming `path`."""
    try:
        yield
    except OSError as err:
        if err.errno not in DISK_FULL_ERRNOS:
            raise
        raise DiskFullError(path, free_bytes(path), DISK_FULL_ERRNOS[err.errno]) from err


def atomic_write_bytes(path, data: bytes, *, backup_suffix: str | None = None, mode: int | None = None) -> Path:
    """Write `data` to `path` through a temporary file in the same directory, fsync, then rename.

    If `backup_suffix` is given and `path` exists, the old file is kept as `path + backup_suffix`
    (by hard link, so it is never missing even if we crash between the steps).
    `mode`: the file's permissions; by default those of the file it replaces, or what open() would give a new
    file (0666 less the umask). A secret passes 0o600.
    """
    path = Path(path)
    with disk_full_as_error(path):
        _atomic_write(path, data, backup_suffix, mode)
    return path


def _umask() -> int:
    try:  # Linux >= 4.7 tells it without changing it (os.umask would, for every thread)
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    current = os.umask(0o022)
    os.umask(current)
    return current


def _new_file_mode(path: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~_umask()


# The temporary files of atomic writes: ".NAME.XXXXXXXX.tmp" beside NAME (mkstemp's 8 random characters). A process
# killed between creating one and the rename leaves it behind: remove_stale_temporaries clears them.
TEMPORARY_NAME = re.compile(r"\.(?P<name>.+)\.[a-z0-9_]{8}\.tmp\Z")


def is_temporary(name: str) -> bool:
    """Whether the file name `name` is one of an atomic write's temporary files."""
    return TEMPORARY_NAME.match(name) is not None


def remove_stale_temporaries(directory) -> list[Path]:
    """Remove the atomic writes' temporary files (regular files named as TEMPORARY_NAME) under `directory`, left by
    a process killed mid-write; the removed paths. Only for a directory this process holds the lock of: a write
    in progress there would lose its temporary file."""
    removed = []
    for parent, _, names in os.walk(directory):  # symlinks to directories are not followed
        for name in names:
            path = Path(parent) / name
            if is_temporary(name) and stat.S_ISREG(os.lstat(path).st_mode):
                path.unlink()
                removed.append(path)
    return removed


def _atomic_write(path: Path, data: bytes, backup_suffix: str | None, mode: int | None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = _new_file_mode(path) if mode is None else mode
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)  # 0600 until chmod
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as tmp:
            tmp.write(data)
            tmp.flush()
            os.fsync(tmp.fileno())
        if backup_suffix and path.exists():
            backup = path.with_name(path.name + backup_suffix)
            backup_tmp = backup.with_name(f".{backup.name}.{secrets.token_hex(4)}.tmp")  # a TEMPORARY_NAME
            os.link(path, backup_tmp)
            os.replace(backup_tmp, backup)
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise
    fsync_directory(path.parent)


def atomic_write_text(path, text: str, **kwargs) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), **kwargs)


def fsync_directory(directory) -> None:
    """Make a rename or a new file in `directory` durable."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------------- reading
# Every input file goes through read_bytes: a FIFO, a device, a socket or a directory in place of a file is refused
# before anything is read (opened with O_NONBLOCK, so not even the open can block), and size is capped, so no
# input can hang naocal or exhaust its memory.

MAX_TEXT_BYTES = 64 * 1024 ** 2  # observations.csv of ~2700 captures; a real calibration has ~150 (3.6 MB)
MAX_JSON_BYTES = 4 * 1024 ** 2  # naocal's JSON files hold kilobytes (a 500-stance plan: about 0.3 MB)
MAX_JSON_DEPTH = 32  # naocal's documents nest at most 5 deep; CPython's parser recurses (RecursionError at ~1000)
MAX_JSON_INT_DIGITS = 20  # int64 needs 19; Python refuses to parse more than 4300 (ValueError) and float() of
# a 400-digit integer overflows

_FILE_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def append_durably(path, data: bytes, *, new_file: bool = False) -> None:
    """Append `data` to the file at `path` and fsync it (`new_file`: truncate it first and fsync its directory after):
    what a journal appends is on disk when this returns, or nothing of it is (a failed write, e.g. a full disk, is
    cut off again; DiskFullError for a full disk)."""
    path = Path(path)
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | (os.O_TRUNC if new_file else 0)
    with disk_full_as_error(path):
        fd = os.open(path, flags, 0o644)
        size_before = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:  # one write for a regular file; loop only in case of a short write
                view = view[os.write(fd, view):]
            os.fsync(fd)
        except OSError:
            try:  # no half record left behind; else the reader's next open cuts it off
                os.ftruncate(fd, size_before)
                os.fsync(fd)
            except OSError:
                pass
            raise
        finally:
            os.close(fd)
    if new_file:
        fsync_directory(path.parent)


def _kind(mode: int) -> str:
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")


def os_problem(err: OSError) -> str:
    if isinstance(err, FileNotFoundError):
        return "file not found"
    if isinstance(err, PermissionError):
        return "permission denied"
    return (err.strerror or str(err)).lower()


def read_bytes(path, *, max_bytes: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of the regular file `path` (symlinks followed), or DataError naming it and what is wrong."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except OSError as err:
        raise DataError(path, os_problem(err)) from None
    if not stat.S_ISREG(mode):
        raise DataError(path, f"is {_kind(mode)}, expected a regular file")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:
        raise DataError(path, os_problem(err)) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):  # replaced between the stat and the open
            raise DataError(path, f"is {_kind(info.st_mode)}, expected a regular file")
        if info.st_size > max_bytes:
            raise DataError(path, f"too large: {info.st_size} bytes (at most {max_bytes} expected)")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(max_bytes + 1 - total, 1 << 20) or 1)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:  # it grew while we read
                raise DataError(path, f"too large: more than {max_bytes} bytes")
        return b"".join(chunks)
    except OSError as err:
        raise DataError(path, os_problem(err)) from None
    finally:
        os.close(fd)


def read_text(path, *, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of the regular file `path` (a leading byte order mark dropped); DataError otherwise."""
    return decode_text(read_bytes(path, max_bytes=max_bytes), path)


def decode_text(data: bytes, path) -> str:
    """UTF-8 `data` read from `path` as text (a leading byte order mark dropped), or DataError naming the line."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        raise DataError(path, f"not UTF-8 text ({err.reason} at byte {err.start})", line=line) from None


class _JsonRefusal(Exception):
    def __init__(self, problem, *, token=None, field=None):
        super().__init__(problem)
        self.problem, self.token, self.field = problem, token, field


def _json_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_JSON_INT_DIGITS:
        raise _JsonRefusal(f"integer of {digits} digits, at most {MAX_JSON_INT_DIGITS} expected", token=text)
    return int(text)


def _json_object(pairs) -> dict:
    obj = {}
    for key, value in pairs:
        if key in obj:
            raise _JsonRefusal("the same key twice in one object", field=key)
        obj[key] = value
    return obj


# A string (skipped whole, never backtracked into: the lookahead and its back-reference are the atomic group
# `(?>...)` of Python 3.11+, which the Duckiebot's Python 3.8 lacks) or a bracket.
_JSON_NESTING = re.compile(r'"(?=((?:[^"\\]+|\\.)*))\1"|[\[\]{}]')


def _too_deep(text: str, max_depth: int) -> int | None:
    """Offset of the first bracket nested deeper than `max_depth` (brackets inside strings ignored), or None."""
    depth = 0
    for match in _JSON_NESTING.finditer(text):
        char = match.group()
        if char in "[{":
            depth += 1
            if depth > max_depth:
                return match.start()
        elif char in "]}":
            depth -= 1
    return None


def _line_column(text: str, offset: int) -> tuple[int, int]:
    line = text.count("\n", 0, offset) + 1
    return line, offset - (text.rfind("\n", 0, offset) + 1) + 1


def _bad_string(obj, where=""):
    """Field path of the first string (or key) holding a lone surrogate (not Unicode: cannot be printed)."""
    if isinstance(obj, str):
        try:
            obj.encode("utf-8")
        except UnicodeEncodeError:
            return where or "(top level)"
    elif isinstance(obj, dict):
        for key, value in obj.items():
            hit = _bad_string(key, where or "(top level)") or _bad_string(value, f"{where}.{key}" if where else key)
            if hit:
                return hit
    elif isinstance(obj, list):
        for i, value in enumerate(obj):
            hit = _bad_string(value, f"{where}[{i}]")
            if hit:
                return hit
    return None


def parse_json_text(text: str, path):
    """A JSON document from `text`, or DataError naming `path`, the line and column (or field) of the problem.

    Refused besides invalid JSON: nesting deeper than MAX_JSON_DEPTH, integers of more than MAX_JSON_INT_DIGITS
    digits, a key twice in one object, strings that are not Unicode (lone surrogates). NaN and Infinity are
    parsed (the format's validator names their field).
    """
    if not text.strip():
        raise DataError(path, "empty file: expected a JSON object")
    offset = _too_deep(text, MAX_JSON_DEPTH)
    if offset is not None:
        line, column = _line_column(text, offset)
        raise DataError(path, f"nested deeper than {MAX_JSON_DEPTH} levels (column {column})", line=line)
    try:
        doc = json.loads(text, parse_int=_json_int, object_pairs_hook=_json_object)
    except json.JSONDecodeError as err:
        truncated = err.pos >= len(text.rstrip()) or err.msg.startswith("Unterminated string")
        kind = "truncated JSON" if truncated else "invalid JSON"
        raise DataError(path, f"{kind}: {err.msg} (column {err.colno})", line=err.lineno) from None
    except _JsonRefusal as err:
        line = None
        if err.token is not None:
            found = re.search(r"(?<![\w.+-])" + re.escape(err.token) + r"(?![\w.])", text)
            if found:
                line, column = _line_column(text, found.start())
                err.problem += f" (column {column})"
        raise DataError(path, err.problem, line=line, field=err.field) from None
    except (RecursionError, ValueError) as err:  # defence in depth: the checks above should have caught it
        raise DataError(path, f"cannot parse JSON: {err}") from None
    bad = _bad_string(doc)
    if bad:
        raise DataError(path, "text that is not valid Unicode (a lone surrogate escape)", field=bad)
    return doc


def read_json(path, *, max_bytes: int = MAX_JSON_BYTES):
    """The JSON document in the regular file `path` (see read_bytes and parse_json_text)."""
    return parse_json_text(read_text(path, max_bytes=max_bytes), path)


# ------------------------------------------------------------------------------------------ output paths
# Checked before any work, so that a run does not compute for a minute and then fail to save, and so that
# nothing that is not ours (a directory, a FIFO, a device) nor any of the command's inputs is replaced.


def _existing_ancestor(path: Path) -> Path:
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def _check_can_create_in(path: Path) -> None:
    """`path` (absent) can be created: its nearest existing ancestor is a writable directory."""
    ancestor = _existing_ancestor(path.parent)
    if not ancestor.is_dir():
        raise DataError(path, f"cannot be created: {ancestor} is not a directory")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise DataError(path, f"cannot be created: no permission to write in {ancestor}")


def check_not_an_input(path, inputs) -> None:
    """Raise DataError if the output `path` is one of the files `inputs` read: the same file (device and inode)
    under whatever name, symlink or hard link leads to it. An output never replaces what it is made from."""
    try:
        written = os.stat(path)
    except OSError:
        return  # not there (or not reachable): it replaces nothing; check_output_file names other problems
    for source in inputs:
        if source is None:
            continue
        try:
            same = os.path.samestat(written, os.stat(source))
        except OSError:
            continue
        if same:
            shown = "" if os.fspath(source) == os.fspath(path) else f" ({source})"
            raise DataError(path, f"is an input of this command{shown}: refusing to write over it; give another "
                                  "output name (nothing was changed)")


def check_output_file(path, *, inputs=()) -> Path:
    """Raise DataError unless `path` can be written as a file (replacing an existing regular file only, and never
    one of the files `inputs` the command reads: check_not_an_input)."""
    path = Path(path)
    check_not_an_input(path, inputs)
    if os.path.lexists(path):
        try:
            mode = os.stat(path).st_mode
        except OSError as err:
            raise DataError(path, os_problem(err)) from None
        if not stat.S_ISREG(mode):
            raise DataError(path, f"is {_kind(mode)}; expected a file name (an existing file is replaced)")
        if not os.access(path.parent, os.W_OK | os.X_OK):
            raise DataError(path, f"cannot be replaced: no permission to write in {path.parent}")
        return path
    _check_can_create_in(path)
    return path


def check_output_directory(path) -> Path:
    """Raise DataError unless `path` is, or can be created as, a directory we may write in."""
    path = Path(path)
    if os.path.lexists(path):
        if not path.is_dir():
            raise DataError(path, "exists and is not a directory; expected a directory for the output")
        if not os.access(path, os.W_OK | os.X_OK):
            raise DataError(path, "no permission to write in this directory")
        return path
    _check_can_create_in(path)
    return path


def json_safe(obj):
    """NaN and infinity become null (JSON has neither); numpy scalars become Python numbers."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj

# -------------------------------------------------------------------------------------------------- images
# An image's size is read from its header before it is decoded: a 400 KB PNG can claim 20000 x 20000 pixels
# (1.2 GB decoded, minutes of corner search) or 60000 x 60000 (beyond OpenCV's own limit: a cv2.error).

MAX_IMAGE_PIXELS = 4096 * 4096  # 16.8 Mpx: a 12-Mpx phone photo of a board fits, the NAO's cameras give 1.2 Mpx;
# `naocal detect` of a 4096 x 4096 board: 4.0 s CPU, 664 MiB peak (benchmarks/bench_image_budget.py)
IMAGE_FORMATS = "PNG, JPEG, BMP, PPM, PGM, PBM, PAM"
_JPEG_FRAMES = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # start-of-frame markers (not DHT, JPG, DAC)
_PNM_MAGIC = re.compile(rb"P[1-6]")


def image_header_size(data: bytes) -> tuple[str, int, int] | None:
    """(format, width, height) as the header of the image file `data` claims it, None if no header of
    IMAGE_FORMATS is there; nothing is decoded."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR" and len(data) >= 24:
        return "PNG", int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    if data[:2] == b"BM" and len(data) >= 26:
        if int.from_bytes(data[14:18], "little") == 12:  # BITMAPCOREHEADER: 16-bit sizes
            return "BMP", int.from_bytes(data[18:20], "little"), int.from_bytes(data[20:22], "little")
        width, height = (int.from_bytes(data[k:k + 4], "little", signed=True) for k in (18, 22))
        return "BMP", abs(width), abs(height)  # a negative height: rows stored top-down
    if _PNM_MAGIC.match(data[:2]):
        fields = re.sub(rb"#[^\n\r]*", b" ", data[2:4096]).split()[:2]  # comments anywhere in the header
        if len(fields) == 2 and all(f.isdigit() and len(f) <= 12 for f in fields):
            return "PNM", int(fields[0]), int(fields[1])
        return None
    if data[:3] == b"P7\n":
        header = data[:4096].split(b"ENDHDR", 1)[0]
        size = dict(re.findall(rb"^(WIDTH|HEIGHT)[ \t]+(\d{1,12})\s*$", header, re.M))
        return ("PAM", int(size[b"WIDTH"]), int(size[b"HEIGHT"])) if len(size) == 2 else None
    return None


def _jpeg_size(data: bytes) -> tuple[str, int, int] | None:
    """The size in a JPEG's first start-of-frame segment (markers walked by their lengths), None if none."""
    offset = 2
    while offset + 4 <= len(data):
        if data[offset] != 0xFF:
            return None
        marker = data[offset + 1]
        if marker == 0xFF:  # fill byte
            offset += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a segment
            offset += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no frame header before
            return None
        length = int.from_bytes(data[offset + 2:offset + 4], "big")
        if marker in _JPEG_FRAMES:
            if offset + 9 > len(data):
                return None
            height = int.from_bytes(data[offset + 5:offset + 7], "big")
            width = int.from_bytes(data[offset + 7:offset + 9], "big")
            return ("JPEG", width, height) if height else None  # height 0: given later (DNL), not supported
        if length < 2:
            return None
        offset += 2 + length
    return None


def read_image_bytes(path) -> tuple[bytes, tuple[int, int]]:
    """The bytes of the image file `path` and its (width, height) from its header, checked before any decoding:
    one of IMAGE_FORMATS, at least 1 x 1 and at most MAX_IMAGE_PIXELS; DataError naming the file otherwise."""
    data = read_bytes(path)
    header = image_header_size(data)
    if header is None:
        raise DataError(path, f"not an image naocal reads: no {IMAGE_FORMATS} header")
    kind, width, height = header
    if width < 1 or height < 1:
        raise DataError(path, f"{kind} header claims {width} x {height} pixels: an empty image")
    if width * height > MAX_IMAGE_PIXELS:
        raise DataError(path, f"{kind} header claims {width} x {height} pixels ({width * height / 1e6:.0f} Mpx): "
                              f"at most {MAX_IMAGE_PIXELS / 1e6:.1f} Mpx are read (4096 x 4096; docs/CONVENTIONS.md)")
    return data, (width, height)


@contextlib.contextmanager
def native_stderr_held(said: list):
    """Hold what C libraries write to file descriptor 2 during the block (libpng's 'libpng error: ...' on a damaged
    file) and append it to `said`, so that the user sees one line; Python's sys.stderr is flushed first."""
    import os
    import sys
    import tempfile

    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            said.append(held.read(4096).decode("utf-8", "replace"))
