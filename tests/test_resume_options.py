"""`naocal calibrate --resume` (issue 21): every option that defines the capture is in run.json and compared, none
can be forgotten, and the temporary files a killed session left are removed (ours only, after the lock)."""

import json
import os

import pytest

from tests import fuzz_inputs as fz

BASE = ["calibrate", "--backend", "mock", "--seed", "3", "--mock", "ideal", "--stances-per-leg", "5", "--no-progress"]
RUN_JSON = {"schema": "naocal.run/1", "verb": "calibrate", "backend": "mock", "mock_seed": 3, "mock": "ideal",
            "effects": {}, "plan": "paper", "plan_seed": 0, "stances_per_leg": 5, "probe": True, "speed": 0.4,
            "images": False}


def started_run(directory, **changes):
    """A run directory as a session killed during its measurement leaves it (run.json, a dataset started)."""
    directory.mkdir()
    (directory / "run.json").write_text(json.dumps({**RUN_JSON, **changes}))
    (directory / "dataset").mkdir()
    return directory


def snapshot(directory):
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("extra, recorded, message", [
    (["--no-images", "--speed", "0.8"], {}, "--speed 0.8 (the run: 0.4)"),
    ([], {}, "no --no-images (the run: --no-images)"),
    (["--no-images"], {"images": True}, "--no-images (the run: with its images)"),
])
def test_resume_with_another_speed_or_images_is_refused_unchanged(tmp_path, extra, recorded, message):
    out = started_run(tmp_path / "run", **recorded)
    before = snapshot(out)
    outcome = fz.run_forked([*BASE, *extra, "--out", str(out), "--resume"], deadline_s=60)
    assert outcome.returncode == 2, fz.describe(outcome)
    line = outcome.stderr.strip()
    assert "\n" not in line and message in line and "nothing was changed" in line, line
    assert snapshot(out) == before


def test_every_calibrate_option_defines_the_run_or_is_declared_free_per_session():
    from naocal.agent.rundir import RECORD_OPTIONS, SESSION_OPTIONS
    from naocal.tools.cli import build_parser

    parser = build_parser()
    calibrate = parser._subparsers._group_actions[0].choices["calibrate"]
    options = {o for action in calibrate._actions for o in action.option_strings if o.startswith("--")}
    from naocal import kinds

    # the NAO's in agent.rundir; another kind declares its own calibrate options (kinds' `run_options`)
    declared = set(RECORD_OPTIONS.values()) | set(SESSION_OPTIONS)
    declared |= {o for kind in kinds.registered() for o in getattr(kind, "run_options", {})}
    assert options - declared == set(), "options neither run-defining nor free per session"
    assert declared - options - {"--verbose"} == set(), "declared options calibrate does not have"


def test_resume_removes_the_temporary_files_a_killed_session_left(tmp_path, monkeypatch):
    import naocal.kinds.nao.calibrate as cmd
    from naocal.tools.cli import main

    out = started_run(tmp_path / "run")
    images = out / "dataset" / "images"
    images.mkdir()
    stale = [images / ".000003.png.k2x_9qab.tmp", out / ".progress.json.a1b2c3d4.tmp",
             out / ".offsets.json.bak.0f1e2d3c.tmp"]
    kept = [images / "000002.png", images / ".000004.png.tmp", images / "notes.tmp"]  # not our temporaries' names
    for path in stale + kept:
        path.write_bytes(b"x")
    seen = {}

    def calibrate_stub(args, out_dir, record, effects, *, resume_hint):
        seen["lock held"] = (out_dir / ".naocal.lock").exists()
        seen["left"] = sorted(p.name for p in out_dir.rglob("*") if p.is_file() and p.name != ".naocal.lock")
        return 0

    monkeypatch.setattr(cmd, "_calibrate", calibrate_stub)
    assert main([*BASE, "--no-images", "--out", str(out), "--resume"]) == 0
    assert seen["lock held"] and seen["left"] == sorted(["run.json"] + [p.name for p in kept])
    assert all(os.path.exists(p) for p in kept) and not any(os.path.exists(p) for p in stale)


def test_a_backup_link_left_by_a_killed_write_is_a_temporary_file(tmp_path, monkeypatch):
    """The hard link that keeps NAME.bak is made under a temporary name too (it was NAME.bak.tmp, which --resume
    took for a foreign file)."""
    from naocal.solver.fileio import atomic_write_text, is_temporary

    path = tmp_path / "offsets.json"
    atomic_write_text(path, "1")
    names, real_link = [], os.link
    monkeypatch.setattr(os, "link", lambda source, target: (names.append(os.path.basename(target)),
                                                            real_link(source, target)))
    atomic_write_text(path, "2", backup_suffix=".bak")
    assert names and all(is_temporary(n) for n in names)
    assert (tmp_path / "offsets.json.bak").read_text() == "1"


@pytest.mark.parametrize("name, field, value", [
    ("progress.json", "robot_time_s", "soon"), ("progress.json", "robot_time_s", 1e308),
    ("progress.json", "sessions", -1), ("progress.json", "skipped", ["3"]),
    ("truth.json", "effects", {"elasticity": "much"})])
def test_resume_names_a_damaged_value_of_the_run_it_continues(tmp_path, name, field, value):
    """progress.json and (runs from before run.json) truth.json are read on --resume: a value a run cannot have
    written is one line naming the field (was a ValueError or AttributeError traceback)."""
    out = started_run(tmp_path / "run")
    if name == "truth.json":
        (out / "run.json").unlink()
        (out / "truth.json").write_text(json.dumps({"effects": value}))
    else:
        (out / "progress.json").write_text(json.dumps({"schema": "naocal.progress/1", "robot_time_s": 1.0,
                                                       "skipped": {}, "sessions": 1, field: value}))
    before = snapshot(out)
    outcome = fz.run_forked([*BASE, "--no-images", "--out", str(out), "--resume"], deadline_s=120)
    line = outcome.stderr.strip()
    assert outcome.returncode == 2 and "\n" not in line and "Traceback" not in line, fz.describe(outcome)
    assert f"{out / name}" in line and f"field '{field}" in line, line
    assert snapshot(out) == before
