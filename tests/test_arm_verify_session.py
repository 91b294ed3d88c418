"""verify of a camera calibration on a new camera session of the same simulated dual arm (issue 24): an unchanged
robot is "still good" at 30 poses although 2 % of the new session's corners are mis-detected (identify set its own
aside; verify used to keep them: ratio 3-10, "drifted"), and a joint moved by 0.1 deg or a tool knocked by 1 mm is
"drifted" (what verify sets aside is decided against a refit, which follows a drift); with the markers refitted as
nuisances a knocked tool is "drifted" (their common motion is the tool's mount), and a joint moved too little for the
RMS ratio is "drifted" when the new data place it many standard deviations away (the NAO's rule)."""

import json
import math
import shutil

import pytest

from tests.cli_runner import naocal

EFFECTS = "joint_offsets,link_lengths,tool,points,marker_scale"  # docs/ARM.md's dual-arm walk-through


def cameras_only(source, out):
    """A copy of the simulated dataset `source` without the tracker's rows (docs/ARM.md, "Fit from the cameras")."""
    out.mkdir()
    for name in ("dataset.json", "robot.urdf"):
        shutil.copy(source / name, out / name)
    lines = (source / "observations.csv").read_text().splitlines()
    sensor = lines[0].split(",").index("sensor")
    kept = [lines[0]] + [line for line in lines[1:] if line.split(",")[sensor] != "tracker"]
    (out / "observations.csv").write_text("\n".join(kept) + "\n")
    return out


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """(the calibration from the cameras of 120 stances, the new session's camera data: 30 other stances of the
    same robot, its own noise and mis-detected corners)."""
    from naocal.kinds.arm.sim import simulate_dualarm

    tmp = tmp_path_factory.mktemp("session")
    simulate_dualarm(tmp / "first", seed=3, n_poses=120)
    simulate_dualarm(tmp / "next", seed=3, n_poses=30, stance_seed=1)
    cal = tmp / "cal.json"
    run = naocal("identify", cameras_only(tmp / "first", tmp / "first_cams"), "--effects", EFFECTS, "--cv-folds",
                 "0", "--out", cal)
    assert run.returncode == 0, run.stdout + run.stderr
    return cal, cameras_only(tmp / "next", tmp / "next_cams")


@pytest.fixture(scope="module")
def other_session(tmp_path_factory):
    """The camera data of a third session of the same robot: 30 other stances (stance seed 2)."""
    from naocal.kinds.arm.sim import simulate_dualarm

    tmp = tmp_path_factory.mktemp("other")
    simulate_dualarm(tmp / "next", seed=3, n_poses=30, stance_seed=2)
    return cameras_only(tmp / "next", tmp / "next_cams")


def test_another_session_shares_the_robot_and_none_of_the_stances():
    from naocal.kinds.arm.sim import simulate_dualarm

    first = simulate_dualarm(None, seed=3, n_poses=3, write=False, outlier_fraction=0.0)
    other = simulate_dualarm(None, seed=3, n_poses=3, write=False, outlier_fraction=0.0, stance_seed=1)
    assert first["truth"] == other["truth"] and first["print_scale"] == other["print_scale"]
    assert not (first["observations"].theta[0] == other["observations"].theta[0]).any()


def test_an_unchanged_arm_is_still_good_on_a_new_session_with_mis_detected_corners(sessions):
    cal, next_session = sessions
    run = naocal("verify", next_session, "--offsets", cal, "--json")
    assert run.returncode == 0, run.stdout + run.stderr
    verdict = json.loads(run.stdout)
    assert all(0.8 < s["ratio"] < 1.25 for s in verdict["per_sensor"].values()), verdict["per_sensor"]
    assert max(o["size"] for o in verdict["outliers"]) > 8.0  # the mis-detections (8-40 px), listed
    assert "outliers:" in naocal("verify", next_session, "--offsets", cal).stdout


def _moved(cal, out, name, delta):
    """A copy of the calibration `cal` with parameter `name` moved by `delta` (SI; both of the file's copies)."""
    doc = json.loads(cal.read_text())
    entry = doc["model"]["parameters"][name]
    entry["value"] += delta
    kind, _, key = name.partition(".")
    if kind == "joint_offset":
        doc["joint_offsets_rad"][key] = entry["value"]
    out.write_text(json.dumps(doc))
    return out


@pytest.mark.parametrize("name, delta", [("joint_offset.right_j2", math.radians(0.1)), ("tool.left.x", 1e-3)])
def test_a_moved_joint_or_knocked_tool_is_still_drifted(sessions, tmp_path, name, delta):
    cal, next_session = sessions
    run = naocal("verify", next_session, "--offsets", _moved(cal, tmp_path / "moved.json", name, delta), "--json")
    assert run.returncode == 1, run.stdout + run.stderr
    verdict = json.loads(run.stdout)
    assert verdict["ratio"] > 1.5 and len(verdict["outliers"]) < 0.05 * sum(
        s["n"] for s in verdict["per_sensor"].values()) * 4  # the drift was not set aside as mis-detections


@pytest.mark.parametrize("argv, problem", [(("--robot", "franka_panda", "--stance-seed", "1"), "--stance-seed: only "
                                            "with --robot dualarm"),
                                           (("--robot", "dualarm", "--stance-seed", "-1"), "--stance-seed: a seed")])
def test_simulate_stance_seed_bad_options_are_one_line_exit_2(tmp_path, argv, problem):
    run = naocal("simulate", *argv, "--out", tmp_path / "x")
    assert run.returncode == 2 and problem in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert not (tmp_path / "x" / "dataset.json").exists()


def test_simulate_writes_another_session_of_the_dual_arm(tmp_path):
    run = naocal("simulate", "--robot", "dualarm", "--seed", "3", "--stance-seed", "2", "--poses", "10", "--out",
                 tmp_path / "next")
    assert run.returncode == 0, run.stderr
    meta = json.loads((tmp_path / "next" / "dataset.json").read_text())
    assert "--stance-seed 2" in meta["source"] and meta["robot"]["id"] == "simulated-dualarm-3"


@pytest.mark.parametrize("refit", [(), ("--refit", "sensors,points")])
@pytest.mark.parametrize("session", ["sessions", "other_session"])
def test_an_unchanged_arm_names_nothing_moved_and_no_tool_moved_together(sessions, request, session, refit):
    """No false alarm of the moved test or of the tools' common motion: two sessions of the unchanged robot."""
    cal, next_session = sessions[0], request.getfixturevalue(session)
    next_session = next_session[1] if session == "sessions" else next_session
    run = naocal("verify", next_session, "--offsets", cal, *refit, "--json")
    assert run.returncode == 0, run.stdout + run.stderr
    verdict = json.loads(run.stdout)
    assert verdict["moved"] == [] and all(0.8 < s["ratio"] < 1.25 for s in verdict["per_sensor"].values())
    assert all(e["chi2"] < e["bound"] for e in verdict["together"]), verdict["together"]
    assert len(verdict["together"]) == (2 if refit else 0)  # both tools judged when their markers are refitted


def test_a_knocked_tool_is_drifted_with_its_markers_refitted(sessions, tmp_path):
    """Refitting each marker's position as a nuisance absorbed a 1 mm knock of the left tool (every marker shifted
    by 1 mm, plausible for each marker's gluing: ratio 0.96 / 0.98, "still good"); the markers' common motion is
    now judged as the tool's mount: drifted, naming the tool."""
    cal, next_session = sessions
    knocked = _moved(cal, tmp_path / "knocked.json", "tool.left.x", 1e-3)
    run = naocal("verify", next_session, "--offsets", knocked, "--refit", "sensors,points", "--json")
    assert run.returncode == 1, run.stdout + run.stderr
    verdict = json.loads(run.stdout)
    assert verdict["ratio"] < 1.25  # the residual alone is fooled: the markers absorbed the knock
    left = {e["tool"]: e for e in verdict["together"]}["left"]
    assert left["beyond"] and 0.8e-3 < left["shift"] < 1.3e-3 and left["chi2"] > 10 * left["bound"]
    assert "tool left" in verdict["suspects"]
    assert "the markers of tool left moved together by" in verdict["verdict"]


def test_a_joint_moved_below_the_drift_ratio_is_drifted_naming_it(sessions, tmp_path):
    """right_j2 moved by 0.03 deg: the cameras' RMS stays under DRIFT_RATIO x the reference (ratio about 1.2), but
    the new data place the offset many standard deviations away: drifted, as the NAO's verify rules."""
    cal, next_session = sessions
    run = naocal("verify", next_session, "--offsets", _moved(cal, tmp_path / "moved.json", "joint_offset.right_j2",
                                                             math.radians(0.03)), "--json")
    assert run.returncode == 1, run.stdout + run.stderr
    verdict = json.loads(run.stdout)
    assert verdict["ratio"] < 1.5
    assert [e["parameter"] for e in verdict["moved"]] == ["joint_offset.right_j2"] and verdict["moved"][0]["z"] > 10
    assert verdict["verdict"].startswith("drifted") and "joint right_j2" in verdict["verdict"]
