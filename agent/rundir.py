"""The output directory of a run (DIR): one run at a time, what a run was started with, where its dataset lies.

- `RunLock`: an exclusive lock on DIR (fcntl.flock on DIR/.naocal.lock; the OS releases it when the process ends,
  however it ends). A second run on DIR is refused at once, naming the holder written into the lock file.
- DIR/run.json (`naocal.run/1`): the options that define a calibration run (backend, mock seed and effects, plan
  and plan seed, stances, probe, speed, images kept or not), written before anything else. `--resume` must repeat them: every mismatch is
  refused before anything is written. Runs from before run.json existed are compared with what their plan.json,
  truth.json and dataset/dataset.json say.
- `find_dataset`: a dataset directory, or a calibration run directory holding one in DIR/dataset.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from datetime import datetime, timezone
from pathlib import Path

from naocal.solver import fields
from naocal.solver.errors import DataError, NaocalError
from naocal.solver.fileio import atomic_write_text, disk_full_as_error

LOCK_NAME = ".naocal.lock"
RECORD_NAME = "run.json"
RECORD_SCHEMA = "naocal.run/1"
DATASET_SUBDIR = "dataset"
BRIDGE_TOKEN_NAME = "bridge.token"  # the bridge's motion lease token, so --resume takes the robot back (mode 0600)
# Everything `naocal calibrate` writes into DIR (agent.calibrate, agent.states, kinds.nao.calibrate).
CALIBRATE_ENTRIES = frozenset({
    LOCK_NAME, RECORD_NAME, "plan.json", DATASET_SUBDIR, "progress.json", "offsets.json", "offsets.json.bak",
    "verification", "verification.prev", "verification.json", "summary.txt", "calibrate.log", "truth.json",
    "truth_effects.json", BRIDGE_TOKEN_NAME})
HOLDER_WAIT_S = 1.0  # a holder writes its name right after locking: wait this long for it


class RunLocked(NaocalError):
    """Another process holds DIR's lock."""


class RunLock:
    """Exclusive lock of a run directory, held from `acquire()` (or `with`) to `release()`.

    The lock file holds the holder's pid, host, start time and command (JSON) for the message a second run
    prints. It is removed on release; a lock file left by a killed run is not a lock (the OS dropped its flock).
    """

    def __init__(self, directory, command: str):
        self.directory = Path(directory)
        self.path = self.directory / LOCK_NAME
        self.command = command
        self._fd: int | None = None
        self._created_directory = False

    def __enter__(self) -> "RunLock":
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def acquire(self) -> None:
        if self.directory.exists() and not self.directory.is_dir():
            raise NaocalError(f"{self.directory}: exists and is not a directory")
        with disk_full_as_error(self.directory):
            if not self.directory.exists():
                self.directory.mkdir(parents=True)
                self._created_directory = True
        try:
            self._fd = self._lock_file()
        except BaseException:
            self._remove_created_directory()
            raise
        holder = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), "command": self.command}
        with disk_full_as_error(self.path):  # no fsync: after a crash the lock is gone anyway
            try:
                os.ftruncate(self._fd, 0)
                os.pwrite(self._fd, (json.dumps(holder) + "\n").encode("utf-8"), 0)
            except BaseException:
                self.release()
                raise

    def _lock_file(self) -> int:
        for _ in range(20):
            with disk_full_as_error(self.path):
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as err:
                os.close(fd)
                if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise RunLocked(f"{self.directory} is in use by another run: {self.holder()} (lock "
                                    f"{self.path}); wait for it to end or choose another --out "
                                    "(nothing was changed)") from None
                raise NaocalError(f"{self.path}: cannot lock the run directory ({err.strerror})") from None
            # A holder that just ended removes the file it locked: the lock that counts is on the file at the path.
            try:
                if os.path.samestat(os.fstat(fd), os.stat(self.path)):
                    return fd
            except FileNotFoundError:
                pass
            os.close(fd)
        raise NaocalError(f"{self.path}: the lock file keeps changing; is another run starting and ending?")

    def holder(self) -> str:
        """Who holds the lock, as a phrase, from the lock file (read while someone else holds it)."""
        deadline = time.monotonic() + HOLDER_WAIT_S
        while True:
            try:
                info = json.loads(self.path.read_text(encoding="utf-8"))
                return (f"pid {int(info['pid'])} on {info['host']}, started {info['started']}: "
                        f"{info['command']}")
            except (OSError, ValueError, KeyError, TypeError):
                if time.monotonic() > deadline:
                    return "holder unknown"
                time.sleep(0.05)

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            os.unlink(self.path)  # while still locked: nobody can lock this file and then lose it to us
        except OSError:
            pass
        os.close(self._fd)  # drops the flock
        self._fd = None
        self._remove_created_directory()

    def _remove_created_directory(self) -> None:
        if self._created_directory:
            try:
                self.directory.rmdir()  # only if empty: a refused run leaves no trace
            except OSError:
                pass


# ------------------------------------------------------------------------------------------------- what a run is


def entries(directory: Path) -> list[str]:
    """Names in `directory` other than the lock file (none if it does not exist)."""
    if not directory.is_dir():
        return []
    return sorted(p.name for p in directory.iterdir() if p.name != LOCK_NAME)


def calibrate_record(*, backend: str, mock_seed: int | None, effects: dict, plan: str, plan_seed: int,
                     stances_per_leg: int, probe: bool, speed: float, images: bool, mock: str | None = None) -> dict:
    """The options that define a calibration run (DIR/run.json); `mock` the mock's realism (None: no mock)."""
    return {"schema": RECORD_SCHEMA, "verb": "calibrate", "backend": backend, "mock_seed": mock_seed, "mock": mock,
            "effects": {k: float(v) for k, v in sorted(effects.items())}, "plan": plan, "plan_seed": plan_seed,
            "stances_per_leg": stances_per_leg, "probe": probe, "speed": float(speed), "images": bool(images)}


# Every option of `naocal calibrate` is in one of these two tables (tests/test_runs.py checks it), so that a new
# option cannot be forgotten: either it defines what is captured and how, and --resume must repeat it, or it may
# change from one session of a run to the next.
RECORD_OPTIONS = {  # record key -> how the command line says it
    "backend": "--backend", "mock_seed": "--seed", "mock": "--mock", "effects": "--effect", "plan": "--plan",
    "plan_seed": "--plan-seed", "stances_per_leg": "--stances-per-leg", "probe": "--no-probe",
    "speed": "--speed",  # the motion blur and servo lag of every capture
    "images": "--no-images",  # a dataset has its images for every capture or for none
    "robot": "--robot"}  # the robot kind, whose run it is (the NAO's record leaves it out: the default kind)
NEGATED_FLAGS = {"probe": "with the lag probe", "images": "with its images"}  # recorded True: the flag not given
SESSION_OPTIONS = {  # options free to change on --resume, and why
    "--out": "names the run", "--resume": "continues it", "--help": "prints help",
    "--endpoint": "the robot's address may change between sessions",
    "--max-joint-offset-deg": "a limit on the result, checked after the identification of the whole dataset",
    "--max-camera-rotation-deg": "a limit on the result, checked after the identification of the whole dataset",
    "--no-progress": "what stderr shows", "--verbose": "what stderr shows",
    "--report": "a report of the dataset written after the run: it changes no capture"}


def write_record(directory: Path, record: dict) -> None:
    atomic_write_text(directory / RECORD_NAME, json.dumps(record, indent=1) + "\n")


def recorded_run(directory: Path) -> tuple[dict, str]:
    """What the run in `directory` was started with, and where that was read: run.json, or for a run from before
    run.json the parts its plan.json, truth.json and dataset/dataset.json tell."""
    from naocal.agent.plan import read_plan

    plan_path = directory / "plan.json"
    plan = read_plan(plan_path) if plan_path.exists() else None  # a damaged plan is refused here, not mid-run
    from naocal.agent.record import read_progress

    read_progress(directory / "progress.json")  # so is a damaged progress file
    record_path = directory / RECORD_NAME
    if record_path.exists():
        doc = _read_json(record_path)
        if not isinstance(doc, dict) or doc.get("schema") != RECORD_SCHEMA:
            raise NaocalError(f"{record_path}: not a {RECORD_SCHEMA} file; is {directory} a calibration run?")
        record = {k: doc[k] for k in RECORD_OPTIONS if k in doc}
        if record.get("backend") == "mock" and "mock" not in record:
            record["mock"] = _recorded_realism(directory)  # run.json from before --mock
        return record, str(record_path)
    record, sources = {}, []
    if plan is not None:
        record.update(plan_seed=plan.seed, plan=plan.kind)
        for key in ("stances_per_leg", "probe"):
            if key in plan.settings:
                record[key] = plan.settings[key]
        sources.append(str(plan_path))
    truth_path = directory / "truth.json"
    if truth_path.exists():
        truth = _read_json(truth_path)
        record["backend"] = "mock"
        record["mock"] = _recorded_realism(directory)
        if isinstance(truth, dict) and isinstance(truth.get("effects"), dict):
            effects = dict(sorted(truth["effects"].items()))
            # compared with --effect's (finite) sizes
            record["effects"] = {k: fields.number(v, truth_path, f"effects.{k}") for k, v in effects.items()}
        sources.append(str(truth_path))
    meta_path = directory / DATASET_SUBDIR / "dataset.json"
    if record.get("backend") == "mock" and meta_path.exists():
        meta = _read_json(meta_path)
        robot_id = str(meta.get("robot", {}).get("id", "")) if isinstance(meta, dict) else ""
        if robot_id.startswith("mock-") and robot_id[5:].isdigit():
            record["mock_seed"] = int(robot_id[5:])
            sources.append(str(meta_path))
    return record, " and ".join(sources)


def _recorded_realism(directory: Path) -> str:
    """The realism of the mock a run without `mock` in run.json used: truth_effects.json names a realistic one,
    anything else was the ideal mock (the only one before --mock)."""
    path = directory / "truth_effects.json"
    doc = _read_json(path) if path.exists() else None
    settings = doc.get("realism", {}).get("settings", {}) if isinstance(doc, dict) else {}
    name = settings.get("name", "ideal") if isinstance(settings, dict) else "ideal"
    return name if name in ("ideal", "realistic") else "ideal"


def check_resumable(out: Path, names: list[str], *, resume: bool, own_entries, what: str) -> None:
    """The run-directory checks every kind's calibrate makes on a non-empty `out` holding `names`, before anything
    is written: without --resume it is refused (a run of its own: continue it; anything else: choose another);
    with it, a file the run does not write (`own_entries`, temporaries aside) says it is not the run's directory.
    `what` names the run ("a calibration run")."""
    from naocal.solver.fileio import is_temporary

    if not resume:
        if any(n in own_entries for n in names):
            raise NaocalError(f"{out} already holds {what}: continue it with --resume, or choose another --out "
                              "(nothing was changed)")
        raise NaocalError(f"{out} is not empty (it holds {names[0]}): choose a new or empty directory for --out "
                          "(nothing was changed)")
    foreign = [n for n in names if n not in own_entries and not is_temporary(n)]
    if foreign:
        raise NaocalError(f"{out} holds {foreign[0]}, which {what} does not write: is it the right directory? "
                          "(nothing was changed)")


def refuse_other_options(source, differ: list[str], resume_command: str) -> None:
    """A --resume whose options differ from the run's (`differ`: 'OPTION X (the run: Y)' phrases) is refused,
    naming the command that resumes it as it was started."""
    if differ:
        raise NaocalError(f"{source}: this run was started with other options: {'; '.join(differ)}. Resume it with "
                          f"the same options (nothing was changed): {resume_command}")


def mismatches(recorded: dict, wanted: dict) -> list[str]:
    """The options in which `wanted` differs from `recorded`, as 'OPTION X (the run: Y)' phrases."""
    out = []
    for key, option in RECORD_OPTIONS.items():
        if key not in recorded or recorded[key] == wanted.get(key):
            continue
        if key in NEGATED_FLAGS:
            out.append(f"{option} (the run: {NEGATED_FLAGS[key]})" if recorded[key] else
                       f"no {option} (the run: {option})")
        else:
            out.append(f"{option} {_shown(key, wanted.get(key))} (the run: {_shown(key, recorded[key])})")
    return out


def _shown(key, value) -> str:
    if key == "effects":
        return " ".join(f"{k}={v!r}" for k, v in value.items()) if value else "none"
    if key in ("mock_seed", "mock") and value is None:
        return "none (no mock)"
    return str(value)


def _read_json(path: Path):
    from naocal.solver.fileio import read_json  # the safe reader: a regular file only (a FIFO would block), size capped

    try:
        return read_json(path)
    except NaocalError as err:
        raise NaocalError(f"{err}; is {path.parent} a calibration run?") from None


# ------------------------------------------------------------------------------------------------- datasets


def _there(path: Path) -> bool:
    """Whether `path` exists (a dangling symlink too); DataError when that cannot be told (a directory we may not
    search is "permission denied", not "no dataset here")."""
    try:
        os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError as err:
        from naocal.solver.fileio import os_problem

        raise DataError(path, os_problem(err)) from None
    return True


def dataset_files(path) -> list[Path]:
    """The files a dataset reader reads in the dataset directory `path` (an output must not replace them)."""
    from naocal.solver.dataset import META_FILE, OBSERVATIONS_FILE

    return [Path(path) / META_FILE, Path(path) / OBSERVATIONS_FILE]


def find_dataset(path) -> Path:
    """The dataset directory `path` means: `path` itself (dataset.json inside, e.g. from `naocal simulate`) or
    `path`/dataset (a `naocal calibrate --out` directory). NaocalError naming both places looked at."""
    path = Path(path)
    # there at all, not is_file: a dataset.json that is a FIFO or a directory is read_dataset's to refuse by name
    if _there(path / "dataset.json") or not path.is_dir():
        return path  # read_dataset names what is wrong with it
    inner = path / DATASET_SUBDIR
    if _there(inner / "dataset.json"):
        return inner
    raise NaocalError(f"{path}: no dataset here: looked for {path / 'dataset.json'} (a dataset directory) and "
                      f"{inner / 'dataset.json'} (a naocal calibrate run)")
