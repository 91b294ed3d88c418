"""Damaged input files by seeded mutation of valid ones, and a runner that feeds them to the CLI.

Used by tests/test_fuzz_inputs.py (a quick seeded run) and benchmarks/fuzz_inputs.py (a larger one).

A case copies a valid dataset directory (dataset.json + observations.csv) or a valid offsets file, damages one
file, runs a verb of `tools.cli.main` on it in a forked child (warm imports, so a case costs milliseconds) with a
deadline and a memory limit, and checks what a user would see: exit 0 or 2 (3 where a failed identification is
allowed), on failure exactly one line on stderr starting `naocal VERB: error:` and naming the damaged file, no
traceback, no warning, no hang.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import io
import json
import os
import random
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

META = "dataset.json"
OBSERVATIONS = "observations.csv"
OFFSETS = "offsets.json"
NOBODY_UID = 65534

# Values a damaged number field may take, as JSON text (the fuzzer writes them verbatim).
NASTY_JSON_VALUES = (
    "[" * 1000 + "]" * 1000,  # nested deeper than CPython's recursion limit
    "[" * 50 + "1" + "]" * 50,
    "1" * 400, "-" + "7" * 400, "9" * 5000,  # 5000 digits: beyond Python's int max-str-digits
    "1e308", "-1e308", "1e400", "-1e400", "NaN", "Infinity", "-Infinity", "1e-320",
    "9223372036854775808", "-9223372036854775809", "18446744073709551616",
    "null", "true", "false", '""', '"abc"', '"1.5"', "[]", "{}", "[1, 2, 3]", '{"a": 1}',
    "0", "-1", "0.5", "1e19", "-1e19", "3.0", "1000000", '"' + "x" * 100_000 + '"', '"\\u0000"', '"\\ud800"',
)

# Values a damaged CSV cell may take.
NASTY_CELLS = (
    "1e308", "-1e308", "1e19", "-1e19", "1e400", "nan", "NaN", "inf", "-inf", "Infinity", "", " ", "abc",
    "1" * 400, "9" * 5000, "9223372036854775808", "-9223372036854775809", "1e-320", "1_000", "0x10", " 1 ",
    "\u0661\u0662", "+2", "-0", "2", "-1", "0.5", "3.7", "L", "R", "X", "\x00", "1e5", "-1e5", "100", "-100",
    "4294967296", "1.0000000000000002", "\u00a0", "\t",
)

# The observations.csv columns the fuzzer damages: indices, leg, pixels, sole points, times, angles, a direction.
# the columns damaged (those of the file's version: 2 has camera, target and x_mount_m; 1 has leg and x_sole_m)
CSV_COLUMNS = ("image", "camera", "target", "leg", "stance", "head_posture", "vertex", "u_px", "v_px", "x_mount_m",
               "y_mount_m", "z_mount_m", "x_sole_m", "y_sole_m", "z_sole_m", "t_image_s", "t_joints_s", "LHipPitch",
               "cmd_LKneePitch", "dir_RAnkleRoll", "HeadPitch", "cmd_HeadYaw", "RHipYawPitch")


@dataclass
class Case:
    name: str  # what was damaged, for the failure report
    target: str  # the damaged file, relative to the case directory ("": the directory): errors must name it
    damage: Callable[[Path], None]  # applied to the case directory (a fresh copy of the valid inputs)
    as_nobody: bool = False  # run the verb without root's right to read anything (permission-denied cases)


@dataclass
class Outcome:
    returncode: int | None  # None: killed at the deadline
    stdout: str
    stderr: str
    seconds: float


# ------------------------------------------------------------------------------------------- file damage


def _replace_with_dir(path: Path):
    path.unlink()
    path.mkdir()


def _replace_with_fifo(path: Path):
    path.unlink()
    os.mkfifo(path)


def _replace_with_symlink(target):
    def damage(path: Path):
        path.unlink()
        path.symlink_to(target)
    return damage


def _symlink_loop(path: Path):
    path.unlink()
    path.symlink_to(path.name)


def _huge(path: Path):
    with open(path, "r+b") as f:  # sparse: costs no disk
        f.truncate(4 * 1024 ** 3)


def _unreadable(path: Path):
    path.chmod(0)


def _edit_bytes(edit):
    def damage(path: Path):
        path.write_bytes(edit(path.read_bytes()))
    return damage


def file_damages(rng: random.Random, text_lines: int) -> list[tuple[str, Callable[[Path], None], bool]]:
    """(label, damage of one file, run as nobody) for damage that does not depend on the format."""
    cut = rng.random()
    insert_at = rng.random()
    line = rng.randrange(max(text_lines, 1))
    out = [
        ("empty", _edit_bytes(lambda b: b""), False),
        ("whitespace only", _edit_bytes(lambda b: b" \n\t\r\n"), False),
        ("byte order mark", _edit_bytes(lambda b: b"\xef\xbb\xbf" + b), False),
        ("CRLF line ends", _edit_bytes(lambda b: b.replace(b"\n", b"\r\n")), False),
        ("CR line ends", _edit_bytes(lambda b: b.replace(b"\n", b"\r")), False),
        (f"truncated at {cut:.3f}", _edit_bytes(lambda b: b[:int(len(b) * cut)]), False),
        (f"non-UTF-8 byte at {insert_at:.3f}",
         _edit_bytes(lambda b: b[:int(len(b) * insert_at)] + b"\xff\xfe" + b[int(len(b) * insert_at):]), False),
        (f"NUL byte at {insert_at:.3f}",
         _edit_bytes(lambda b: b[:int(len(b) * insert_at)] + b"\x00" + b[int(len(b) * insert_at):]), False),
        (f"line {line} doubled", _edit_bytes(lambda b: _lines_edit(b, line, lambda ls: ls[:line + 1] + ls[line:])),
         False),
        (f"line {line} deleted", _edit_bytes(lambda b: _lines_edit(b, line, lambda ls: ls[:line] + ls[line + 1:])),
         False),
        ("random bytes", _edit_bytes(lambda b: bytes(rng.randrange(256) for _ in range(2000))), False),
        ("directory in place of the file", _replace_with_dir, False),
        ("FIFO in place of the file", _replace_with_fifo, False),
        ("symlink to /dev/zero", _replace_with_symlink("/dev/zero"), False),
        ("symlink to /dev/null", _replace_with_symlink("/dev/null"), False),
        ("symlink to /dev/urandom", _replace_with_symlink("/dev/urandom"), False),
        ("symlink loop", _symlink_loop, False),
        ("dangling symlink", _replace_with_symlink("no-such-file"), False),
        ("missing", lambda p: p.unlink(), False),
        ("4 GiB (sparse)", _huge, False),
        ("permission denied", _unreadable, True),
    ]
    flips = [rng.random() for _ in range(4)]
    values = [rng.randrange(256) for _ in range(4)]
    out.append((f"4 random bytes changed at {[round(f, 3) for f in flips]}",
                _edit_bytes(lambda b: _flip(b, flips, values)), False))
    return out


def _flip(data: bytes, where, values) -> bytes:
    data = bytearray(data)
    for w, v in zip(where, values):
        if data:
            data[int(w * (len(data) - 1))] = v
    return bytes(data)


def _lines_edit(data: bytes, line: int, edit) -> bytes:
    lines = data.split(b"\n")
    if line >= len(lines):
        return data
    return b"\n".join(edit(lines))


# ------------------------------------------------------------------------------------------- JSON damage


def _json_paths(doc, prefix=()):
    """Every path (tuple of keys and indices) to a value in a JSON document."""
    paths = [prefix]
    if isinstance(doc, dict):
        for key, value in doc.items():
            paths += _json_paths(value, prefix + (key,))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            paths += _json_paths(value, prefix + (i,))
    return paths


_PLACEHOLDER = "@@NASTY@@"


def _json_with(doc, path, raw_value: str | None, *, add_key=None) -> bytes:
    """The document with the value at `path` replaced by the raw JSON text `raw_value` (None: deleted)."""
    doc = json.loads(json.dumps(doc))
    if not path:
        return (raw_value if raw_value is not None else "").encode("utf-8", "surrogatepass")
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if raw_value is None:
        del parent[path[-1]]
    elif add_key is not None and isinstance(parent[path[-1]], dict):
        parent[path[-1]][add_key] = _PLACEHOLDER
    else:
        parent[path[-1]] = _PLACEHOLDER
    text = json.dumps(doc, indent=2)
    return text.replace(json.dumps(_PLACEHOLDER), raw_value or "null").encode("utf-8", "surrogatepass")


def json_damages(rng: random.Random, doc: dict, n: int) -> list[tuple[str, Callable[[Path], None], bool]]:
    """n seeded damages of a JSON document: a value replaced by a nasty one, a key deleted, added or doubled."""
    paths = _json_paths(doc)
    out = []
    for _ in range(n):
        path = rng.choice(paths)
        where = ".".join(str(p) for p in path) or "(top level)"
        kind = rng.random()
        if kind < 0.70 or not path:
            value = rng.choice(NASTY_JSON_VALUES)
            data = _json_with(doc, path, value)
            label = f"{where} = {value[:24]}{'...' if len(value) > 24 else ''}"
        elif kind < 0.80:
            data = _json_with(doc, path, None)
            label = f"{where} deleted"
        elif kind < 0.90:
            data = _json_with(doc, path[:-1] or path, rng.choice(NASTY_JSON_VALUES[:12]), add_key="extra") \
                if len(path) > 1 else _json_with(doc, path, "{}")
            label = f"unknown key beside {where}"
        else:
            key = path[0]
            text = json.dumps(doc, indent=2)
            dup = f'"{key}": {rng.choice(NASTY_JSON_VALUES[5:20])},\n  '
            data = text.replace(f'"{key}":', dup + f'"{key}":', 1).encode()
            label = f"duplicate key {key}"
        out.append((f"{label}", _edit_bytes(lambda _b, d=data: d), False))
    return out


# -------------------------------------------------------------------------------------------- CSV damage


def csv_damages(rng: random.Random, text: str, n: int) -> list[tuple[str, Callable[[Path], None], bool]]:
    """n seeded damages of observations.csv: one cell, a whole column, one image's value, or the header."""
    lines = text.split("\n")
    header = lines[0].split(",")
    rows = [i for i in range(1, len(lines)) if lines[i]]
    columns = [name for name in CSV_COLUMNS if name in header]
    out = []
    for _ in range(n):
        column = rng.choice(columns)
        j = header.index(column)
        value = rng.choice(NASTY_CELLS)
        kind = rng.random()
        if kind < 0.5:
            picked = [rng.choice(rows)]
            label = f"{column} on line {picked[0] + 1} = {value[:24]!r}"
        elif kind < 0.7:
            image = lines[rng.choice(rows)].split(",")[header.index("image")]
            picked = [i for i in rows if lines[i].split(",")[header.index("image")] == image]
            label = f"{column} of image {image} = {value[:24]!r}"
        elif kind < 0.85:
            picked = rows
            label = f"every {column} = {value[:24]!r}"
        else:
            new_header = list(header)
            choice = rng.randrange(3)
            if choice == 0:
                new_header[j] = value or "renamed"
                label = f"header: {column} renamed {value[:24]!r}"
            elif choice == 1:
                new_header[j] = header[(j + 1) % len(header)]
                label = f"header: {column} duplicated"
            else:
                new_header = header[:j] + header[j + 1:]
                label = f"header: {column} dropped"
            data = "\n".join([",".join(new_header)] + lines[1:]).encode("utf-8")
            out.append((label, _edit_bytes(lambda _b, d=data: d), False))
            continue
        changed = list(lines)
        for i in picked:
            fields = changed[i].split(",")
            fields[j] = value
            changed[i] = ",".join(fields)
        data = "\n".join(changed).encode("utf-8")
        out.append((label, _edit_bytes(lambda _b, d=data: d), False))
    return out


# ------------------------------------------------------------------------------------------- valid inputs


def make_valid_inputs(directory: Path, seed: int = 3) -> tuple[Path, Path]:
    """(dataset directory, directory holding offsets.json and reference.json): small, valid, identifiable."""
    import numpy as np

    from naocal.solver.dataset import read_dataset, write_dataset
    from naocal.solver.identify import identify
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.registry import Registry
    from naocal.sim.synthetic import dataset_parts, random_truth, synthesize
    from naocal.kinds.nao.identify import write_offsets_file

    rng = np.random.default_rng(seed)
    data = synthesize(rng, random_truth(rng), n_stances_per_leg=8, n_head_postures=2, pixel_noise_px=0.2)
    dataset = directory / "dataset"
    write_dataset(dataset_parts(data, robot_id="nao-fuzz", pixel_noise_px=0.2), dataset)
    read_back = read_dataset(dataset)
    result = identify(model_data_from_dataset(read_back), Registry())
    offsets = directory / "offsets"
    offsets.mkdir()
    write_offsets_file(offsets / OFFSETS, result, read_back, dataset)
    shutil.copy(offsets / OFFSETS, offsets / "reference.json")
    for path in (dataset, offsets):
        os.chmod(path, 0o755)
        for child in path.iterdir():
            os.chmod(child, 0o644)
    return dataset, offsets


@contextlib.contextmanager
def work_directory(prefix: str):
    """A fresh temporary directory that nobody (the permission-denied cases' user) can reach, removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    os.chmod(path, 0o755)
    try:
        yield path
    finally:
        remove_tree(path)


def remove_tree(path: Path):
    """Remove a work tree the cases left with unreadable files, FIFOs and symlinks in it."""
    for root, dirs, _ in os.walk(path):
        for d in dirs:
            full = os.path.join(root, d)
            if not os.path.islink(full):
                os.chmod(full, 0o755)
    shutil.rmtree(path, ignore_errors=True)


# ------------------------------------------------------------------------------------------------ cases


def dataset_cases(valid_dir: Path, seed: int, n_json: int, n_csv: int) -> list[Case]:
    """Damaged copies of the dataset at `valid_dir`: every file damage for both files, then seeded mutations."""
    rng = random.Random(seed)
    meta = json.loads((valid_dir / META).read_text())
    csv_text = (valid_dir / OBSERVATIONS).read_text()
    cases = []
    for target, n_lines in ((META, 30), (OBSERVATIONS, csv_text.count("\n"))):
        for label, damage, nobody in file_damages(rng, n_lines):
            cases.append(Case(f"{target}: {label}", target, _on(target, damage), nobody))
    for label, damage, nobody in json_damages(rng, meta, n_json):
        cases.append(Case(f"{META}: {label}", META, _on(META, damage), nobody))
    for label, damage, nobody in csv_damages(rng, csv_text, n_csv):
        cases.append(Case(f"{OBSERVATIONS}: {label}", OBSERVATIONS, _on(OBSERVATIONS, damage), nobody))
    cases += [
        Case("dataset directory is a FIFO", "", _replace_dir_with_fifo),
        Case("dataset directory is a symlink to /dev/zero", "", _replace_dir_with_symlink),
        Case("images is a file", "images", lambda d: (d / "images").write_text("not a directory")),
    ]
    return cases


def offsets_cases(valid_file: Path, seed: int, n_json: int) -> list[Case]:
    rng = random.Random(seed)
    doc = json.loads(valid_file.read_text())
    cases = [Case(f"{OFFSETS}: {label}", OFFSETS, _on(OFFSETS, damage), nobody)
             for label, damage, nobody in file_damages(rng, valid_file.read_text().count("\n"))]
    cases += [Case(f"{OFFSETS}: {label}", OFFSETS, _on(OFFSETS, damage), nobody)
              for label, damage, nobody in json_damages(rng, doc, n_json)]
    return cases


IMAGES = ("board.png", "board.jpg", "board.bmp")
REAL_IMAGE = Path(__file__).parent / "data" / "realdata" / "mrlspl-nao-2009" / "image_0.png"


def make_valid_images(directory: Path) -> Path:
    """A directory with one real board image as PNG, JPEG and BMP (IMAGES)."""
    import cv2

    directory.mkdir(parents=True, exist_ok=True)
    image = cv2.imread(str(REAL_IMAGE))
    for name in IMAGES:
        cv2.imwrite(str(directory / name), image)
    return directory


def _set_bytes(data: bytes, where, values) -> bytes:
    data = bytearray(data)
    for w, v in zip(where, values):
        if w < len(data):
            data[w] = v
    return bytes(data)


def image_cases(valid_dir: Path, seed: int, n_header: int) -> list[Case]:
    """Damaged copies of the images at `valid_dir`: every file damage, then seeded changes of 1-4 bytes among the
    first 64 (the header: sizes, markers, segment lengths)."""
    rng = random.Random(seed)
    cases = []
    for name in IMAGES:
        cases += [Case(f"{name}: {label}", name, _on(name, damage), nobody)
                  for label, damage, nobody in file_damages(rng, 1)]
        for _ in range(n_header):
            where = sorted(rng.sample(range(64), rng.randint(1, 4)))
            values = [rng.choice((0, 1, 0x7F, 0x80, 0xFF, rng.randrange(256))) for _ in where]
            cases.append(Case(f"{name}: header bytes {where} set to {values}", name,
                              _on(name, _edit_bytes(lambda b, w=where, v=values: _set_bytes(b, w, v))), False))
    return cases


def image_verbs(directory: Path, out_dir: Path) -> list[list[str]]:
    """Every way `naocal detect` reads images (each run reads all three: the damaged one must be named)."""
    images = [str(directory / name) for name in IMAGES]
    return [["detect", *images], ["detect", *images, "--json"], ["detect", *images, "--overlay", str(out_dir)]]


def _on(name, damage):
    return lambda directory: damage(directory / name)


def _replace_dir_with_fifo(directory: Path):
    for child in directory.iterdir():
        child.unlink()
    directory.rmdir()
    os.mkfifo(directory)


def _replace_dir_with_symlink(directory: Path):
    shutil.rmtree(directory)
    directory.symlink_to("/dev/zero")


def prepare(case: Case, valid: Path, work: Path) -> Path:
    """A fresh copy of `valid` (a directory) under `work`, damaged by `case`; returns the copy."""
    copy = work / "ds"
    if copy.exists() or copy.is_symlink():
        _remove(copy)
    shutil.copytree(valid, copy)
    os.chmod(copy, 0o755)
    for child in copy.iterdir():
        os.chmod(child, 0o755 if child.is_dir() else 0o644)
    case.damage(copy)
    return copy


def _remove(path: Path):
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        path.unlink()
        return
    for child in path.iterdir():
        if child.is_dir() and not child.is_symlink():
            child.chmod(0o755)
        elif not child.is_symlink():
            child.chmod(0o644)
    shutil.rmtree(path)


# ----------------------------------------------------------------------------------------------- running


def _address_space_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


@functools.cache
def _import_every_module() -> None:
    """Import all of naocal in this (root) process before a child drops to nobody: the verbs import their modules
    when they run, and nobody may not read the checkout (CI's clone sits in a mode-0700 temporary directory), which
    would fail the import instead of the damaged file's read that the case is about."""
    import pkgutil

    for layer in ("agent", "backends", "body", "kinds", "sim", "solver", "tools"):
        package = importlib.import_module(f"naocal.{layer}")
        for module in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
            try:
                importlib.import_module(module.name)
            except ImportError:  # an optional driver's library (qi) is missing: its verbs are not fuzzed
                pass
    importlib.import_module("naocal.kinds").registered()  # the kinds, found by listing the checkout, kept


def run_forked(argv, *, deadline_s: float = 10.0, as_nobody: bool = False,
               memory_headroom_bytes: int = 2 * 1024 ** 3) -> Outcome:
    """Run `tools.cli.main(argv)` in a forked child as the `naocal` command would run it; kill it at the deadline.

    The child has its stdout/stderr in temporary files, the default warning filters and no logging handlers (as
    in a fresh interpreter), `memory_headroom_bytes` of address space beyond what it inherits (so that reading
    /dev/zero ends in MemoryError, not in the machine's swap), and, with `as_nobody`, root's rights dropped.
    """
    from naocal.tools.cli import main

    if as_nobody:
        _import_every_module()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        sys.stdout.flush(), sys.stderr.flush()
        start = time.perf_counter()
        pid = os.fork()
        if pid == 0:  # the child: never returns
            code = 1
            try:
                os.dup2(out.fileno(), 1)
                os.dup2(err.fileno(), 2)
                sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", closefd=False), write_through=True)
                sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", closefd=False), write_through=True)
                import logging
                import warnings

                warnings.resetwarnings()
                warnings.simplefilter("default")
                logging.getLogger().handlers.clear()
                signal.signal(signal.SIGINT, signal.default_int_handler)
                _, hard = resource.getrlimit(resource.RLIMIT_AS)
                limit = _address_space_bytes() + memory_headroom_bytes
                resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY else min(limit, hard),
                                                        hard))
                if as_nobody and os.geteuid() == 0:
                    os.setgid(NOBODY_UID)
                    os.setuid(NOBODY_UID)
                try:
                    code = main(list(argv))
                except SystemExit as exit_:
                    code = exit_.code if isinstance(exit_.code, int) else 1
                except BaseException:  # what the interpreter would print for an uncaught exception
                    traceback.print_exc()
                    code = 1
                sys.stdout.flush(), sys.stderr.flush()
            finally:
                os._exit(code if isinstance(code, int) else 1)
        returncode = None
        while time.perf_counter() - start < deadline_s:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                returncode = os.waitstatus_to_exitcode(status)
                break
            time.sleep(0.002)
        else:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        seconds = time.perf_counter() - start
        out.seek(0), err.seek(0)
        return Outcome(returncode, out.read().decode("utf-8", "replace"), err.read().decode("utf-8", "replace"),
                       seconds)


# An identification that exits 0 must be plausible: no joint offset beyond this (the offsets file's own limit).
MAX_JOINT_OFFSET_DEG = 10.0


def problems(outcome: Outcome, verb: str, target: str, *, allow_failed_fit: bool,
             json_out: bool = False) -> list[str]:
    """What is wrong with what the user saw; [] if the run behaved. `target`: the path the error must name;
    `json_out`: stdout is identify's --json report, whose joint offsets must be plausible if it exits 0."""
    found = []
    allowed = (0, 2, 3) if allow_failed_fit else (0, 2)
    verdict = verb in ("verify", "detect")  # exit 1 is a verdict (drifted; no board), as exit 0: a report, no error
    if verdict:
        allowed += (1,)
    if outcome.returncode is None:
        return [f"hang: killed after {outcome.seconds:.1f} s"]
    if outcome.returncode not in allowed:
        found.append(f"exit code {outcome.returncode}")
    if "Traceback" in outcome.stderr:
        found.append("traceback")
    lines = outcome.stderr.splitlines()
    if outcome.returncode == 0 or (verdict and outcome.returncode == 1):
        # notes are allowed (an export says which values it wrote as 0); errors, warnings and tracebacks are not
        noisy = [line for line in lines if "error" in line.lower() or "warning" in line.lower()]
        if noisy:
            found.append(f"exit 0 but stderr says {noisy[0][:160]!r}")
        if json_out:
            found += _absurd_offsets(outcome.stdout)
        return found
    if len(lines) != 1:
        found.append(f"{len(lines)} lines on stderr")
    first = lines[0] if lines else ""
    if not first.startswith(f"naocal {verb}: error: "):
        found.append(f"stderr does not start 'naocal {verb}: error:'")
    if outcome.returncode == 2 and target not in first:
        found.append(f"error does not name {target}")
    return found


def _absurd_offsets(stdout: str) -> list[str]:
    import math

    try:
        parameters = json.loads(stdout)["model_parameters"]
    except (ValueError, KeyError, TypeError):
        return ["exit 0 but stdout is not the --json report"]
    for name, entry in parameters.items():
        if name.startswith("joint_offset.") and not abs(math.degrees(entry["value"])) <= MAX_JOINT_OFFSET_DEG:
            return [f"exit 0 with {name} = {math.degrees(entry['value']):.4g} deg"]
    return []


def describe(outcome: Outcome) -> str:
    tail = outcome.stderr.strip().splitlines()[-1:] or [""]
    return f"exit {outcome.returncode}, {outcome.seconds:.2f} s, stderr {len(outcome.stderr.splitlines())} " \
           f"line(s), last: {tail[0][:200]!r}"



# ------------------------------------------------------------------------------------------------- verbs


def dataset_verbs(dataset: Path, out_dir: Path, offsets: Path | None = None) -> list[list[str]]:
    """Every verb that reads a dataset, as argv lists (`offsets`: a valid calibration for `verify` to judge by)."""
    verbs = [
        ["identify", str(dataset), "--cv-folds", "0"],
        ["identify", str(dataset), "--json", "--cv-folds", "2", "--out", str(out_dir / "identified.json")],
        ["diagnose", str(dataset)],
        ["diagnose", str(dataset), "--json", "--angles", "measured"],
    ]
    if offsets is not None:
        verbs.append(["verify", str(dataset), "--offsets", str(offsets), "--json"])
    return verbs


def offsets_verbs(offsets: Path, reference: Path) -> list[list[str]]:
    """Every verb that reads an offsets file, as argv lists."""
    return [
        ["offsets", "show", str(offsets)],
        ["offsets", "validate", str(offsets)],
        ["offsets", "diff", str(offsets), str(reference)],
        ["offsets", "diff", str(reference), str(offsets)],
        ["offsets", "export", str(offsets), "--format", "json"],
        ["offsets", "export", str(offsets), "--format", "bhuman"],
        ["offsets", "export", str(offsets), "--format", "urdf", "--strip-meshes"],
        ["offsets", "apply", str(offsets), "--command", "LHipPitch=-20", "RKneePitch=40"],
        ["offsets", "apply", str(offsets), "--reading", "--rad", "LAnkleRoll=0.1"],
    ]


@dataclass
class Failure:
    case: str
    argv: list
    problems: list
    outcome: Outcome

    def __str__(self):
        return f"{self.case} | naocal {' '.join(a[:40] for a in self.argv[:2])} ...: {'; '.join(self.problems)} " \
               f"({describe(self.outcome)})"


def run_cases(cases, valid: Path, work: Path, verbs_of, *, every_verb: bool, deadline_s: float = 10.0,
              progress=None) -> tuple[int, list[Failure]]:
    """Run each case (with every verb, or one verb per case in turn); (number of runs, failures)."""
    runs, failures = 0, []
    work.mkdir(parents=True, exist_ok=True)
    os.chmod(work, 0o755)  # the permission-denied cases run as nobody, who must reach the files
    out_dir = work / "out"
    out_dir.mkdir(exist_ok=True)
    for k, case in enumerate(cases):
        case_dir = prepare(case, valid, work)
        all_verbs = verbs_of(case_dir, out_dir)
        chosen = all_verbs if every_verb else [all_verbs[k % len(all_verbs)]]
        for argv in chosen:
            if case.as_nobody and ("--out" in argv or "--overlay" in argv):  # outputs are checked first
                continue
            outcome = run_forked(argv, deadline_s=deadline_s, as_nobody=case.as_nobody)
            runs += 1
            # A damaged dataset.json can make observations.csv wrong (a smaller board): any file of the dataset.
            target = str(case_dir / case.target) if case.target != META else str(case_dir)
            verb = argv[0]
            found = problems(outcome, verb, target, allow_failed_fit=verb in ("identify", "diagnose", "verify"),
                             json_out=verb == "identify" and "--json" in argv)
            if found:
                failures.append(Failure(case.name, argv, found, outcome))
            if progress:
                progress(case, argv, outcome, found)
    return runs, failures
