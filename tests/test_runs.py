"""Run directories: one run per --out, no mismatched --resume, Ctrl-C, a full disk; nothing saved lost or changed."""

import errno
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from naocal.agent.calibrate import calibrate
from naocal.agent.plan import read_plan
from naocal.agent.planner import PlanSettings
from naocal.agent.rundir import LOCK_NAME, RunLock, RunLocked
from naocal.agent.states import AgentSettings
from naocal.solver.dataset import read_dataset, write_dataset
from naocal.sim.synthetic import dataset_parts, random_truth, synthesize
from tests.agent_fakes import FakeBackend
from naocal.tools import cli

ROOT = Path(__file__).resolve().parents[1]
# The ideal mock: the interrupted and resumed runs are compared capture by capture.
BASE = ["--backend", "mock", "--seed", "3", "--mock", "ideal", "--stances-per-leg", "5", "--no-images", "--no-progress"]


def _sigint_default():
    # A test run started in the background (`pytest &`) ignores SIGINT, and its children inherit that: Python
    # then never turns the signal into KeyboardInterrupt. Ctrl-C on a real terminal always arrives.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def naocal_process(*argv, **kw):
    return subprocess.Popen([sys.executable, "-m", "naocal", *argv], cwd=ROOT, text=True,
                            preexec_fn=_sigint_default, **kw)


def snapshot(directory: Path) -> dict:
    """Every file under `directory` with its bytes (the lock file aside: it is not saved data)."""
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*"))
            if p.is_file() and p.name != LOCK_NAME}


def captured_lines(path: Path) -> int:
    return path.read_bytes().count(b"\n") if path.exists() else 0


def wait_for(condition, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def path_of_fd(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""


def disk_fills(monkeypatch, full):
    """os.fsync raises ENOSPC for the files `full(path, calls so far)` says, as on a full disk."""
    real_fsync = os.fsync
    calls = {}

    def fsync(fd):
        path = path_of_fd(fd)
        calls[path] = calls.get(path, 0) + 1
        if full(path, calls[path]):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)


# --- one run per --out ----------------------------------------------------------------------------------------------

def test_the_lock_refuses_a_second_holder_and_goes_with_its_holder(tmp_path):
    first = RunLock(tmp_path / "run", "naocal calibrate --out run")
    first.acquire()
    holder = json.loads((tmp_path / "run" / LOCK_NAME).read_text())
    assert holder["pid"] == os.getpid() and holder["command"] == "naocal calibrate --out run"
    with pytest.raises(RunLocked) as info:
        RunLock(tmp_path / "run", "another").acquire()
    assert f"pid {os.getpid()}" in str(info.value) and "naocal calibrate --out run" in str(info.value)
    first.release()
    assert not (tmp_path / "run").exists()  # made for the lock, left empty: removed
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / LOCK_NAME).write_text("left by a killed run")  # a file is not a lock
    with RunLock(tmp_path / "run", "third"):
        assert json.loads((tmp_path / "run" / LOCK_NAME).read_text())["command"] == "third"
    assert (tmp_path / "run").is_dir() and not (tmp_path / "run" / LOCK_NAME).exists()


@pytest.mark.slow
def test_a_second_run_on_the_same_out_is_refused_at_once_naming_the_holder(tmp_path):
    out = tmp_path / "run"
    holder = naocal_process("calibrate", *BASE, "--out", str(out), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: '"pid"' in ((out / LOCK_NAME).read_text() if (out / LOCK_NAME).exists() else ""), 60,
                 "the first run to take the lock")
        for argv in (["calibrate", *BASE, "--out", str(out), "--resume"], ["calibrate", *BASE, "--out", str(out)],
                     ["simulate", "--out", str(out), "--no-progress"]):
            started = time.monotonic()
            second = naocal_process(*argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            _, err = second.communicate(timeout=60)
            assert second.returncode == 2, err
            assert time.monotonic() - started < 20  # at once: no mock built, no plan made
            assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
            assert f"pid {holder.pid}" in err and "in use by another run" in err and "calibrate" in err
        assert holder.poll() is None, "the first run went on"
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with RunLock(out, "after the holder died"):  # the OS dropped the dead holder's lock
        pass


# --- Ctrl-C, then resume: with other options refused, with the printed command completed --------------------------

@pytest.fixture(scope="module")
def interrupted(tmp_path_factory):
    """A mock calibration stopped by SIGINT during its measurement: (DIR, return code, stdout, stderr)."""
    out = tmp_path_factory.mktemp("interrupted") / "run"
    proc = naocal_process("calibrate", *BASE, "--out", str(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        obs = out / "dataset" / "observations.csv"
        wait_for(lambda: captured_lines(obs) > 1 + 24 * 8 or proc.poll() is not None, 300, "8 captures")
        assert proc.poll() is None, "the run ended before it could be interrupted"
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return out, proc.returncode, stdout, stderr


@pytest.mark.slow
def test_ctrl_c_writes_the_summary_and_prints_the_resume_command(interrupted):
    out, code, stdout, stderr = interrupted
    assert code == 130
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    assert lines[0].startswith("naocal calibrate: interrupted during measurement (")
    command = lines[0].split("continue with: ", 1)[1]
    assert shlex.split(command) == ["naocal", "calibrate", *BASE, "--out", str(out), "--resume"]
    summary = (out / "summary.txt").read_text()
    assert summary.startswith("naocal calibrate: interrupted - measurement")
    assert f"to continue (captures already saved are kept, not repeated): {command}" in summary
    saved = len(np.unique(read_dataset(out / "dataset").columns["image"]))
    planned = len(read_plan(out / "plan.json").image_indices())  # 44: 38 still (bottom and top), 6 in the probe
    assert f"measurement (not finished): {saved} of {planned} images saved" in summary
    assert summary in stdout
    assert not (out / LOCK_NAME).exists()


def terminated_run(argv, ready, what: str) -> str:
    """Run `naocal ARGV` as a process, send it SIGTERM once `ready()` holds (within 300 s), and return its stderr
    after checking it ended as interrupted (exit 130)."""
    proc = naocal_process(*argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: ready() or proc.poll() is not None, 300, what)
        assert proc.poll() is None, "the run ended before it could be stopped"
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr
    return stderr


def test_sigterm_ends_a_run_as_ctrl_c_does(tmp_path):
    """systemd's stop, `kill` or a closed terminal must not kill a run between two writes."""
    out = tmp_path / "run"
    stderr = terminated_run(["calibrate", *BASE, "--out", str(out)],
                            lambda: captured_lines(out / "dataset" / "observations.csv") > 1 + 24 * 2, "2 captures")
    assert stderr.strip().startswith("naocal calibrate: interrupted during ") and "Traceback" not in stderr
    # what stopped it is recorded as it was: SIGTERM, not Ctrl-C
    assert "(SIGTERM; " in stderr and "Ctrl-C" not in stderr, stderr
    assert "note:" not in stderr  # the ideal mock has no deliberate errors to explain
    summary = (out / "summary.txt").read_text()
    assert summary.startswith("naocal calibrate: interrupted - ") and summary.splitlines()[0].endswith(
        ": interrupted (SIGTERM)") and "Ctrl-C" not in summary
    assert not (out / LOCK_NAME).exists()


def test_the_realistic_mock_says_once_that_its_errors_are_deliberate(tmp_path):
    """The first run warned of an 11 deg offset, skipped captures and corners set aside, with no word that the
    realistic mock (the default) has them on purpose."""
    out = tmp_path / "run"
    stderr = terminated_run(["calibrate", "--backend", "mock", "--seed", "1", "--no-progress", "--out", str(out)],
                            lambda: (out / "plan.json").exists(), "the plan")
    notes = [line for line in stderr.splitlines() if "note:" in line]
    assert len(notes) == 1 and stderr.startswith(notes[0]), stderr  # once, before any warning
    for words in ("realistic mock", "on purpose", "12 deg", "1.5 % of the corners", "docs/MOCK.md", "--mock ideal"):
        assert words in notes[0], words
    robot = next(line for line in (out / "summary.txt").read_text().splitlines() if line.startswith("robot: "))
    assert robot.endswith("backend mock (seed 1, realistic: real robots' errors on purpose, docs/MOCK.md)"), robot


MISMATCHES = [
    (["--seed", "4"], "--seed 4 (the run: 3)"),
    (["--effect", "elasticity=0.03"], "--effect elasticity=0.03 (the run: none)"),
    (["--plan", "optimal"], "--plan optimal (the run: paper)"),
    (["--plan-seed", "5"], "--plan-seed 5 (the run: 0)"),
    (["--stances-per-leg", "6"], "--stances-per-leg 6 (the run: 5)"),
    (["--no-probe"], "--no-probe (the run: with the lag probe)"),
    (["--mock", "realistic"], "--mock realistic (the run: ideal)"),
]


@pytest.mark.slow
@pytest.mark.parametrize("extra, message", MISMATCHES)
@pytest.mark.parametrize("record", ["run.json", "older run without run.json"])
def test_resume_with_other_options_is_refused_before_anything_is_written(interrupted, tmp_path, capsys, extra,
                                                                         message, record):
    out = interrupted[0]
    if record != "run.json":
        out = shutil.copytree(out, tmp_path / "old")
        (out / "run.json").unlink()
    before = snapshot(out)
    code = cli.main(["calibrate", *BASE, "--out", str(out), "--resume", *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1 and "nothing was changed" in err
    assert ("run.json" in err) == (record == "run.json")
    assert shlex.split(err.rsplit("(nothing was changed): ", 1)[1]) == [
        "naocal", "calibrate", *BASE, "--out", str(out), "--resume"]
    assert snapshot(out) == before


def test_the_mock_realism_is_recorded_and_another_refused(tmp_path):
    from naocal.agent.rundir import calibrate_record, mismatches, recorded_run, write_record

    def record(mock):
        return calibrate_record(backend="mock", mock_seed=3, mock=mock, effects={}, plan="paper", plan_seed=0,
                                stances_per_leg=5, probe=True, speed=0.4, images=True)

    write_record(tmp_path, record("realistic"))
    recorded, source = recorded_run(tmp_path)
    assert recorded["mock"] == "realistic" and source.endswith("run.json")
    assert mismatches(recorded, record("realistic")) == []
    assert mismatches(recorded, record("ideal")) == ["--mock ideal (the run: realistic)"]
    # run.json from before --mock, and a run from before run.json: the ideal mock, the only one there was
    older = {k: v for k, v in record("ideal").items() if k != "mock"}
    (tmp_path / "run.json").write_text(json.dumps(older))
    assert mismatches(recorded_run(tmp_path)[0], record("realistic")) == ["--mock realistic (the run: ideal)"]
    (tmp_path / "run.json").unlink()
    (tmp_path / "truth.json").write_text(json.dumps({"effects": {}}))
    assert recorded_run(tmp_path)[0]["mock"] == "ideal"
    (tmp_path / "truth_effects.json").write_text(json.dumps({"realism": {"settings": {"name": "realistic"}}}))
    assert recorded_run(tmp_path)[0]["mock"] == "realistic"


@pytest.mark.slow
def test_a_run_is_not_continued_without_resume(interrupted, capsys):
    out = interrupted[0]
    before = snapshot(out)
    assert cli.main(["calibrate", *BASE, "--out", str(out)]) == 2
    assert "--resume" in capsys.readouterr().err
    assert snapshot(out) == before


@pytest.mark.slow
def test_the_printed_resume_command_completes_the_run_with_both_seeds_recorded(interrupted):
    out, _, _, stderr = interrupted
    argv = shlex.split(stderr.split("continue with: ", 1)[1])
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    done = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    # Seed 3's top camera is 7.3 deg off: the plausibility warning is right to say so; nothing else may be said.
    assert all("WARNING: camera.top.pitch" in line and "unusually large" in line
               for line in done.stderr.splitlines()), done.stderr
    counts = np.bincount(read_dataset(out / "dataset").columns["image"])
    planned = len(read_plan(out / "plan.json").image_indices())
    assert np.count_nonzero(counts) == planned and np.all(counts[counts > 0] == 24), "every capture exactly once"
    source = json.loads((out / "offsets.json").read_text())["source"]
    assert source["mock_seed"] == 3 and source["plan_seed"] == 0 and "seed" not in source
    assert json.loads((out / "progress.json").read_text())["sessions"] == 2


@pytest.mark.parametrize("resume", [False, True])
def test_a_finished_run_says_so_and_is_not_run_again(tmp_path, capsys, resume):
    """A finished run's re-run offered --resume, and --resume moved the robot again to re-verify."""
    fake = FakeBackend(3, resolution_rad=0.0)
    settings = AgentSettings(seed=1, plan=PlanSettings(stances_per_leg=6), progress_bar=False)
    out = tmp_path / "run"
    assert calibrate(fake, out, settings, detector=fake.detector)[0].ok
    before = snapshot(out)
    code = cli.main(["calibrate", *BASE, "--out", str(out)] + (["--resume"] if resume else []))
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "holds a finished calibration" in err and "nothing was changed" in err
    assert "--resume" not in err and "continue" not in err, err
    assert snapshot(out) == before
    # the check it offers instead runs as printed, and moves nothing: it reads the run's held-out captures
    check = shlex.split(err.split("without moving the robot (its held-out captures under them): ", 1)[1]
                        .rsplit(" (nothing was changed)", 1)[0])
    assert check[:2] == ["naocal", "verify"]
    assert cli.main(check[1:]) in (0, 1), capsys.readouterr().err  # still good or drifted: a verdict
    assert "still good" in capsys.readouterr().out
    assert snapshot(out) == before


@pytest.mark.slow
def test_calibrate_report_is_the_diagnose_report_of_its_dataset(tmp_path, capsys):
    """calibrate had no --report: the report took a second command."""
    out, report = tmp_path / "run", tmp_path / "report"
    assert cli.main(["calibrate", *BASE, "--out", str(out), "--report", str(report)]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"report: {report / 'index.html'}")
    assert cli.main(["diagnose", str(out), "--report", str(tmp_path / "diagnosed")]) == 0
    written = {p.name: p.read_bytes() for p in report.iterdir()}
    assert "index.html" in written and "vectors.png" in written
    assert written == {p.name: p.read_bytes() for p in (tmp_path / "diagnosed").iterdir()}


@pytest.mark.parametrize("where", ["inside the run", "a file"])
def test_a_report_directory_that_cannot_be_is_refused_before_the_run(tmp_path, capsys, where):
    out = tmp_path / "run"
    report = out / "report" if where == "inside the run" else tmp_path / "notes.txt"
    if where == "a file":
        report.write_text("mine")
    code = cli.main(["calibrate", *BASE, "--out", str(out), "--report", str(report)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(report) in err, err
    assert not out.exists()
    if where == "a file":
        assert report.read_text() == "mine"
    else:
        assert f"--report {tmp_path / 'run-report'}" in err  # where to put it instead


# --- a dataset directory is not a run directory ---------------------------------------------------------------------

@pytest.mark.parametrize("resume", [False, True])
def test_calibrate_into_a_simulated_dataset_is_refused_and_changes_nothing(tmp_path, capsys, resume):
    rng = np.random.default_rng(0)
    write_dataset(dataset_parts(synthesize(rng, random_truth(rng), pixel_noise_px=0.1)), tmp_path / "sim")
    (tmp_path / "sim" / "truth.json").write_text('{"schema": "naocal.truth/1"}\n')
    before = snapshot(tmp_path / "sim")
    code = cli.main(["calibrate", *BASE, "--out", str(tmp_path / "sim")] + (["--resume"] if resume else []))
    err = capsys.readouterr().err
    assert code == 2 and "holds a dataset" in err and "nothing was changed" in err
    assert snapshot(tmp_path / "sim") == before and sorted(p.name for p in (tmp_path / "sim").iterdir()) == [
        "dataset.json", "observations.csv", "truth.json"]


def test_resume_into_a_foreign_directory_is_refused(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    assert cli.main(["calibrate", *BASE, "--out", str(tmp_path), "--resume"]) == 2
    assert "notes.txt" in capsys.readouterr().err
    assert cli.main(["calibrate", *BASE, "--out", str(tmp_path)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert snapshot(tmp_path) == {"notes.txt": b"mine"}


# --- a full disk ----------------------------------------------------------------------------------------------------

def one_error_line(err: str, verb: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.startswith(f"naocal {verb}: ")]
    assert "Traceback" not in err and "Logging error" not in err, err
    assert lines, err
    return lines[-1]


@pytest.mark.slow
def test_calibrate_on_a_full_disk_ends_in_one_line_and_keeps_every_capture(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    disk_fills(monkeypatch, lambda path, n: path.endswith("observations.csv") and n > 3)
    code = cli.main(["calibrate", *BASE, "--stances-per-leg", "2", "--out", str(out)])
    monkeypatch.undo()
    captured = capsys.readouterr()
    line = one_error_line(captured.err, "calibrate")
    assert code == 3
    assert line.startswith("naocal calibrate: failed: measurement: cannot write ")
    assert f"{out / 'dataset' / 'observations.csv'}: no space left on the device (" in line and "bytes free" in line
    assert line.endswith("--out " + str(out) + " --resume")
    assert len(np.unique(read_dataset(out / "dataset").columns["image"])) == 3  # the 4th capture was cut back
    summary = (out / "summary.txt").read_text()
    assert "no space left" in summary and "to continue" in summary and summary in captured.out
    assert json.loads((out / "run.json").read_text())["mock_seed"] == 3


def test_a_summary_the_full_disk_refuses_is_returned_and_the_failure_named(tmp_path, monkeypatch):
    fake = FakeBackend(3)
    settings = AgentSettings(seed=1, plan=PlanSettings(stances_per_leg=2), progress_bar=False,
                             resume_command="naocal calibrate ... --resume")
    disk_fills(monkeypatch, lambda path, n: "/dataset/" in path and n > 4 or "summary.txt" in path)
    result, ctx = calibrate(fake, tmp_path, settings, detector=fake.detector)
    monkeypatch.undo()
    assert not result.ok and "no space left" in result.reason and "bytes free" in result.reason
    assert not (tmp_path / "summary.txt").exists()
    assert "summary.txt" in ctx.summary_error and "bytes free" in ctx.summary_error
    assert ctx.summary.startswith("naocal calibrate: failed - measurement: cannot write")
    assert "to continue (captures already saved are kept, not repeated): naocal calibrate ... --resume" in ctx.summary


def test_calibrate_refused_by_a_full_disk_at_its_start_leaves_nothing(tmp_path, monkeypatch, capsys):
    disk_fills(monkeypatch, lambda path, n: True)
    code = cli.main(["calibrate", *BASE, "--out", str(tmp_path / "run")])
    monkeypatch.undo()
    line = one_error_line(capsys.readouterr().err, "calibrate")
    assert code == 3 and f"cannot write {tmp_path / 'run' / 'run.json'}: no space left" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_simulate_on_a_full_disk_ends_in_one_line(tmp_path, monkeypatch, capsys):
    out = tmp_path / "sim"
    disk_fills(monkeypatch, lambda path, n: path.endswith("observations.csv") and n > 2)
    code = cli.main(["simulate", "--out", str(out), "--seed", "3", "--stances-per-leg", "2", "--no-images",
                     "--no-progress"])
    monkeypatch.undo()
    line = one_error_line(capsys.readouterr().err, "simulate")
    assert code == 3 and f"cannot write {out / 'observations.csv'}: no space left" in line and "bytes free" in line
    assert len(np.unique(read_dataset(out).columns["image"])) == 2


def test_identify_out_on_a_full_disk_keeps_the_old_offsets(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(1)
    write_dataset(dataset_parts(synthesize(rng, random_truth(rng), pixel_noise_px=0.1)), tmp_path / "ds")
    offsets = tmp_path / "offsets.json"
    assert cli.main(["identify", str(tmp_path / "ds"), "--out", str(offsets), "--cv-folds", "0"]) == 0
    capsys.readouterr()
    before = offsets.read_bytes()
    disk_fills(monkeypatch, lambda path, n: True)
    code = cli.main(["identify", str(tmp_path / "ds"), "--out", str(offsets), "--cv-folds", "0"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert code == 3 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"naocal identify: error: cannot write {offsets}: no space left") and "bytes free" in err
    assert offsets.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["ds", "offsets.json"]


# --- offsets.json names both seeds ----------------------------------------------------------------------------------

def test_offsets_record_the_mock_seed_and_the_plan_seed_by_name(tmp_path):
    fake = FakeBackend(3, resolution_rad=0.0)
    settings = AgentSettings(seed=1, plan=PlanSettings(stances_per_leg=6), progress_bar=False, mock_seed=7)
    result, _ = calibrate(fake, tmp_path / "mock", settings, detector=fake.detector)
    assert result.ok, result.reason
    source = json.loads((tmp_path / "mock" / "offsets.json").read_text())["source"]
    assert source["mock_seed"] == 7 and source["plan_seed"] == 1 and "seed" not in source
    from types import SimpleNamespace

    from naocal.agent.states import offsets_source

    robot = SimpleNamespace(settings=AgentSettings(seed=1), dataset_dir=tmp_path, plan=None)  # no mock: no mock seed
    assert offsets_source(robot) == {"tool": "naocal calibrate", "dataset": str(tmp_path), "plan_seed": 1,
                                     "plan": None}


def test_an_older_offsets_file_with_one_seed_still_reads(tmp_path, capsys):
    from naocal.solver.joints import LEG_JOINTS
    from naocal.solver.offsets import offsets_from_alpha, read_offsets, write_offsets

    path = tmp_path / "offsets.json"
    source = {"tool": "naocal calibrate --backend mock", "dataset": "runs/x/dataset", "seed": 0, "plan": "paper"}
    write_offsets(offsets_from_alpha({j: 0.01 for j in LEG_JOINTS}, (0.0, -0.05, 0.0), {"L": (0, 0, 0), "R": (0, 0, 0)},
                                     robot={"id": "mock-1"}, fit={"rms_px": [0.1, 0.1], "n_vertices": 24,
                                                                  "n_images": 1},
                                     source=source), path)  # as naocal wrote it before both seeds were named
    assert read_offsets(path).source == source
    assert cli.main(["offsets", "show", str(path)]) == 0
    assert "seed: 0" in capsys.readouterr().out


def test_resume_on_another_robot_is_refused_before_anything_is_written(tmp_path):
    from naocal.solver.errors import DataError

    fake = FakeBackend(3)
    settings = AgentSettings(seed=1, plan=PlanSettings(stances_per_leg=2), progress_bar=False)
    calibrate(fake, tmp_path, settings, detector=fake.detector)
    (tmp_path / "verification.json").unlink()  # as if stopped during its verification: a run to resume
    before = snapshot(tmp_path)
    other = FakeBackend(3)
    other.robot_identity = lambda: {"id": "another", "model": "NAO H25 V5 (fake)", "body_id": "b2", "head_id": "h2"}
    settings.resume = True
    with pytest.raises(DataError) as info:
        calibrate(other, tmp_path, settings, detector=other.detector)
    assert "dataset.json" in str(info.value) and "another" in str(info.value) and "nothing was changed" in str(info.value)
    assert snapshot(tmp_path) == before


def test_a_fifo_in_place_of_run_json_is_refused_not_waited_on(tmp_path):
    """--resume reads DIR/run.json: a named pipe there blocked the reader for ever."""
    out = tmp_path / "run"
    out.mkdir()
    os.mkfifo(out / "run.json")
    result = subprocess.run([sys.executable, "-m", "naocal", "calibrate", "--backend", "mock", "--out", str(out),
                             "--resume"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "run.json" in result.stderr and "FIFO" in result.stderr
