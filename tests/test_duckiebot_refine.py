"""Online refinement of trim from a lane pass (kinds/duckiebot/refine.py, issue 23's "Online refinement"), on logs
of the independent renderer (kinds/duckiebot/render.py)."""

from pathlib import Path

import numpy as np
import pytest

from naocal.kinds.duckiebot.calibration import CalibrationFile, checked_document
from naocal.kinds.duckiebot.fit import CAMERA, KINEMATIC, DriveFit, Sightings, pose_parameters
from naocal.kinds.duckiebot.identify import DuckiebotCalibration
from naocal.kinds.duckiebot.intrinsics import LensCamera, LensFit
from naocal.kinds.duckiebot.kinematics import inverse_kinematics
from naocal.kinds.duckiebot.refine import RefinementRefused, refine_trim
from naocal.kinds.duckiebot.render import DriveStep, hidden_robot, render_drive_log
from naocal.kinds.duckiebot.robot import Kinematics

ROOT = Path(__file__).resolve().parent.parent
SEED = 3  # trim -0.12 (in its k): a calibration compensating it curves hard when started from trim 0
CHANGE = 0.01  # the robot's trim moved this much since its calibration
LOG_K = 27.0  # render_drive_log's


def true_kinematics():
    kin = hidden_robot(SEED).kinematics
    return Kinematics(gain=kin.gain * LOG_K / kin.k, trim=kin.trim * LOG_K / kin.k, k=LOG_K,
                      baseline_m=kin.baseline_m)


def calibration(kinematics: Kinematics) -> CalibrationFile:
    """A calibration file (as read) with the hidden robot's true camera and pose on the body, and `kinematics`."""
    return checked_document(fitted_calibration(kinematics), "rendered.json")[1]


def fitted_calibration(kinematics: Kinematics) -> DuckiebotCalibration:
    robot = hidden_robot(SEED)
    none = Sightings(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))
    values = np.r_[kinematics.gain, kinematics.trim, kinematics.baseline_m, pose_parameters(robot.T_base_camera)]
    drive_fit = DriveFit(list(KINEMATIC + CAMERA), values, np.full(9, 1e-4), np.zeros(9), np.zeros(9, bool), 0, np.zeros((0, 2)), none, none, 0.0, True, "", 0, 1.0, [], 0.0)
    lens = LensFit(LensCamera.from_intrinsics(robot.camera), 0.0, 0.0, 1)
    return DuckiebotCalibration("rendered", kinematics, lens, {"plumb_bob": lens}, drive_fit)


def lane_pass(directory, frames: int, face_markers: bool = True):
    """The robot, calibrated with trim off by CHANGE, driving straight at 0.2 m/s in normal operation (frames
    grabbed while moving), along the marker line (or away from it)."""
    truth = true_kinematics()
    old = Kinematics(gain=truth.gain, trim=truth.trim - CHANGE, k=LOG_K, baseline_m=truth.baseline_m)
    u_left, u_right = inverse_kinematics(0.2, 0.0, old)
    steps = [DriveStep(0.0, -0.3, 0.3, grab=False, face_rad=np.pi)] if face_markers else []
    steps += [DriveStep(0.25, float(u_left), float(u_right), settle_s=0.0)] * frames
    render_drive_log(directory, seed=SEED, steps=steps)
    return old


@pytest.fixture(scope="module")
def lane(tmp_path_factory):
    path = tmp_path_factory.mktemp("lane")
    return path, lane_pass(path, 10)


def test_a_lane_pass_refines_a_changed_trim_within_its_std(lane):
    path, old = lane
    refined = refine_trim(path, calibration(old), max_step=0.05)
    truth = true_kinematics().trim
    assert not refined.step_bounded and refined.trim_before == old.trim
    assert abs(refined.trim - truth) <= 2 * refined.trim_std < 0.001  # moved CHANGE = 0.01
    assert refined.kinematics.k == old.k and refined.kinematics.baseline_m == old.baseline_m
    assert "trim" in refined.describe()


def test_gain_and_trim_are_in_the_calibrations_k_and_radius(lane):
    """The same robot described with twice the k and a 10 % larger radius: its gain and trim scale by 2.2."""
    path, old = lane
    base = refine_trim(path, calibration(old), max_step=0.05)
    scaled = Kinematics(gain=old.gain * 2.2, trim=old.trim * 2.2, k=2 * LOG_K, radius_m=old.radius_m * 1.1,
                        baseline_m=old.baseline_m)
    refined = refine_trim(path, calibration(scaled), max_step=0.05 * 2.2)
    assert refined.trim == pytest.approx(base.trim * 2.2, abs=1e-6)
    assert refined.trim_std == pytest.approx(base.trim_std * 2.2, rel=1e-3)
    assert refined.kinematics.k == 2 * LOG_K


def test_the_step_is_bounded(lane):
    path, old = lane
    refined = refine_trim(path, calibration(old), max_step=0.004)
    assert refined.step_bounded and refined.trim == pytest.approx(old.trim + 0.004)
    assert refined.trim_estimate == pytest.approx(true_kinematics().trim, abs=0.001)


def test_a_pass_without_markers_or_too_short_is_refused(tmp_path):
    old = lane_pass(tmp_path / "away", 3, face_markers=False)
    with pytest.raises(RefinementRefused, match="0 frames with a marker.*trim is unchanged"):
        refine_trim(tmp_path / "away", calibration(old))
    lane_pass(tmp_path / "short", 5)
    with pytest.raises(RefinementRefused, match="5 frames with a marker.*at least 8"):
        refine_trim(tmp_path / "short", calibration(old))


def test_weak_evidence_is_refused(lane, monkeypatch):
    """A pass whose trim std is above the bound gives no new value (the bound lowered below this pass's std)."""
    import naocal.kinds.duckiebot.refine as refine
    path, old = lane
    monkeypatch.setattr(refine, "MAX_TRIM_STD", 1e-6)
    with pytest.raises(RefinementRefused, match=r"determines trim only to \+-0\.0000.*trim is unchanged"):
        refine_trim(path, calibration(old))


# ------------------------------------------------------------------ naocal identify LOG --refine CAL.json --out NEW.json

def calibration_file(path, kinematics: Kinematics):
    import json

    doc = checked_document(fitted_calibration(kinematics), path)[0]
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return path


def test_the_command_line_writes_the_refined_calibration_never_over_its_input(lane, tmp_path, capsys):
    import json

    from naocal.kinds.duckiebot.calibration import read_calibration_file
    from naocal.tools.cli import main

    path, old = lane
    cal, new = calibration_file(tmp_path / "cal.json", old), tmp_path / "new.json"
    before = cal.read_bytes()
    assert main(["identify", str(path), "--refine", str(cal), "--out", str(new), "--max-step", "0.05"]) == 0
    out = capsys.readouterr().out
    refined = read_calibration_file(new)
    truth = true_kinematics().trim
    assert abs(refined.kinematics.trim - truth) <= 2 * refined.std("trim") < 0.001
    assert refined.value("trim") == refined.kinematics.trim and refined.kinematics.baseline_m == old.baseline_m
    assert f"trim {old.trim:+.4f} -> {refined.kinematics.trim:+.4f} +- {refined.std('trim'):.4f}" in out
    assert refined.T_base_camera == pytest.approx(read_calibration_file(cal).T_base_camera)  # the rest is CAL's
    assert "--refine" in refined.source and cal.read_bytes() == before
    # --json without --out: the same refinement as one object, nothing written
    assert main(["identify", str(path), "--refine", str(cal), "--json", "--max-step", "0.05"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["kinematics"]["trim"] == refined.kinematics.trim and shown["out"] is None
    assert shown["refinement"]["trim_std"] == refined.std("trim") and not shown["refinement"]["step_bounded"]
    # the default bound (0.02) holds a change of 0.01; --out over CAL itself is refused, CAL kept
    assert main(["identify", str(path), "--refine", str(cal), "--out", str(cal)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(cal) in err and cal.read_bytes() == before


def test_weak_evidence_on_the_command_line_is_exit_3_and_nothing_written(lane, tmp_path, capsys, monkeypatch):
    import naocal.kinds.duckiebot.refine as refine
    from naocal.tools.cli import main

    path, old = lane
    cal, new = calibration_file(tmp_path / "cal.json", old), tmp_path / "new.json"
    monkeypatch.setattr(refine, "MAX_TRIM_STD", 1e-6)
    assert main(["identify", str(path), "--refine", str(cal), "--out", str(new)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "determines trim only to" in err and "trim is unchanged" in err
    assert not new.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["cal.json"]


def test_a_bad_refine_file_or_option_is_one_line_exit_2(lane, tmp_path, capsys):
    import json

    from naocal.tools.cli import main

    path, old = lane
    cal, new = calibration_file(tmp_path / "cal.json", old), tmp_path / "new.json"
    doc = json.loads(cal.read_text())
    doc["kinematics"]["trim"] = "0.1"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    cases = [(["--refine", str(bad)], f"{bad}, field 'kinematics.trim'"),
             (["--refine", str(tmp_path / "none.json")], "none.json"),
             (["--refine", str(cal), "--max-step", "nan"], "--max-step must be within"),
             (["--refine", str(cal), "--max-step", "0"], "--max-step must be within"),
             (["--refine", str(cal), "--effects", "slip"], "--effects is not for --refine"),
             (["--max-step", "0.01"], "give it with --refine")]
    for extra, message in cases:
        assert main(["identify", str(path), *extra, "--out", str(new)]) == 2, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, (extra, err)
        assert not new.exists()
    # --refine names the Duckiebot: another robot's dataset is read as a drive log and refused, never fitted
    nao = ROOT / "tests" / "data" / "v1" / "synthetic_dataset"
    assert main(["identify", str(nao), "--refine", str(cal), "--out", str(new)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(nao) in err and not new.exists()
