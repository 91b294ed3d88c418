"""`naocal calibrate` from the command line: bad input, and a run killed with SIGKILL then resumed."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.cli_runner import naocal_process as naocal
from naocal.tools import cli

ROOT = Path(__file__).resolve().parents[1]


def run_in_process(argv, capsys):
    code = cli.main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("argv, message", [
    (["calibrate", "--backend", "bridge", "--out", "X"], "--endpoint"),
    (["calibrate", "--backend", "mock", "--endpoint", "tcp://h:1", "--out", "X"], "--endpoint is for"),
    (["calibrate", "--backend", "mock", "--seed", "-1", "--out", "X"], "--seed"),
    (["calibrate", "--backend", "mock", "--stances-per-leg", "0", "--out", "X"], "--stances-per-leg"),
    (["calibrate", "--backend", "mock", "--speed", "1.5", "--out", "X"], "--speed"),
    (["calibrate", "--backend", "bridge", "--endpoint", "tcp://h:1", "--effect", "backlash=0.01", "--out", "X"],
     "--effect"),
    (["calibrate", "--backend", "mock", "--effect", "wobble=1", "--out", "X"], "unknown effect"),
    (["calibrate", "--backend", "mock", "--effect", "backlash=lots", "--out", "X"], "not a number"),
])
def test_bad_arguments_give_one_line_and_exit_2(argv, message, tmp_path, capsys):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    code, out, err = run_in_process(argv, capsys)
    assert code == 2
    assert message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "X").exists() or not any((tmp_path / "X").iterdir())


def test_an_existing_run_is_not_overwritten_without_resume(tmp_path, capsys):
    (tmp_path / "dataset").mkdir()
    (tmp_path / "dataset" / "observations.csv").write_text("image\n")
    code, out, err = run_in_process(["calibrate", "--backend", "mock", "--out", str(tmp_path)], capsys)
    assert code == 2 and "--resume" in err
    assert (tmp_path / "dataset" / "observations.csv").read_text() == "image\n"
    (tmp_path / "x").write_text("")
    code, out, err = run_in_process(["calibrate", "--backend", "mock", "--out", str(tmp_path / "x")], capsys)
    assert code == 2 and "not a directory" in err


def test_resume_with_another_plan_seed_is_refused(tmp_path, capsys):
    (tmp_path / "plan.json").write_text(json.dumps({"schema": "naocal.plan/1"}))
    code, out, err = run_in_process(["calibrate", "--backend", "mock", "--out", str(tmp_path), "--resume"], capsys)
    assert code == 2 and "plan.json" in err


def test_help_lists_the_options():
    text = cli.build_parser()._subparsers._group_actions[0].choices["calibrate"].format_help()
    for option in ("--backend", "--endpoint", "--seed", "--out", "--resume", "--effect"):
        assert option in text


def test_help_says_what_the_tools_do_today():
    """--help still described the ideal mock as the default and a calibration of the bottom camera alone."""
    parser = cli.build_parser()
    verbs = parser._subparsers._group_actions[0].choices
    described = " ".join(parser.format_help().split())
    assert "bottom camera." not in described and "cameras (top and bottom)" in described and "serial arm" in described
    for verb in ("calibrate", "simulate"):
        mock = next(a for a in verbs[verb]._actions if a.dest == "mock")
        assert "realistic (default" in mock.help and "ideal (default" not in mock.help, verb


def image_counts(dataset: Path) -> np.ndarray:
    header, *rows = (dataset / "observations.csv").read_text().splitlines()
    column = header.split(",").index("image")
    return np.bincount([int(r.split(",")[column]) for r in rows])


def offsets(directory: Path) -> tuple[dict, dict]:
    """(joint offsets c, their standard deviations) of a run."""
    doc = json.loads((directory / "offsets.json").read_text())
    c = doc["body"]["joint_offsets_rad"]  # naocal.offsets/2
    std = {j: doc["model"]["parameters"][f"joint_offset.{j}"]["std"] for j in c}
    return c, std


@pytest.mark.slow
def test_killed_during_measurement_and_resumed_holds_every_capture_once(tmp_path):
    args = ["calibrate", "--backend", "mock", "--mock", "ideal", "--seed", "2", "--stances-per-leg", "4",
            "--no-progress", "--no-images"]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "naocal", *args, "--out", str(killed)], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    obs = killed / "dataset" / "observations.csv"
    deadline = time.monotonic() + 300
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if obs.exists() and obs.read_bytes().count(b"\n") > 1 + 24 * 10:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    before = image_counts(killed / "dataset")
    assert 10 <= np.count_nonzero(before) < 30

    resumed = naocal(*args, "--out", str(killed), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    plan = json.loads((killed / "plan.json").read_text())
    planned = [i for step in plan["steps"] for i in (step["images"] if step["kind"] == "sweep" else [step["image"]])]
    counts = image_counts(killed / "dataset")
    assert np.all(counts[planned] == 24) and counts.sum() == 24 * len(planned), "every capture exactly once"
    assert json.loads((killed / "progress.json").read_text())["sessions"] == 2

    straight = naocal(*args, "--out", str(tmp_path / "straight"))
    assert straight.returncode == 0, straight.stderr
    (a, std_a), (b, std_b) = offsets(killed), offsets(tmp_path / "straight")
    for joint in a:
        # The resumed mock restarts its clock, so its images carry other noise: the runs agree within their
        # precision (4 stances per leg: a few hundredths of a degree), not to the bit.
        tolerance = max(np.radians(0.02), 3.0 * np.hypot(std_a[joint], std_b[joint]))
        assert a[joint] == pytest.approx(b[joint], abs=tolerance), joint
