"""`naocal identify` end to end on a dataset written to disk."""

import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from naocal.solver.dataset import write_dataset
from naocal.solver.offsets import read_offsets
from tests.cli_runner import naocal
from naocal.sim.synthetic import dataset_parts, random_truth, synthesize
from naocal.tools.cli import main

DEG = np.pi / 180


@pytest.fixture(scope="module")
def synthetic_dataset(tmp_path_factory):
    rng = np.random.default_rng(21)
    truth = random_truth(rng)
    data = synthesize(rng, truth, pixel_noise_px=0.1)
    path = tmp_path_factory.mktemp("ds") / "dataset"
    write_dataset(dataset_parts(data, pixel_noise_px=0.1), path)
    return path, truth


def test_json_output_and_offsets_file_with_compensation_sign(synthetic_dataset, tmp_path, capsys):
    path, truth = synthetic_dataset
    out = tmp_path / "offsets.json"
    assert main(["identify", str(path), "--json", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("rms_px", "solve_time_s", "iterations", "effects", "model_parameters", "cv_rms_px"):
        assert key in report
    assert report["effects"] == []
    assert all(abs(r - 0.1) < 0.01 for r in report["rms_px"])
    assert all(abs(r - 0.1) < 0.02 for r in report["cv_rms_px"])
    assert report["model_parameters"]["joint_offset.LKneePitch"]["unit"] == "rad"
    assert "stored offset c" in report["model_parameters_note"]
    for joint, entry in report["joint_offsets_c"].items():  # c, as offsets.json stores it: the parameter itself
        assert entry["c_rad"] == report["model_parameters"][f"joint_offset.{joint}"]["value"]

    offsets = read_offsets(out)
    for joint in ("LHipPitch", "RAnkleRoll", "LKneePitch"):
        # the parameter joint_offset.<J> is the stored c (added to commands)
        assert offsets.joint_offsets_rad[joint] == pytest.approx(truth[f"joint_offset.{joint}"], abs=0.02 * DEG)
        assert offsets.joint_offsets_rad[joint] == report["joint_offsets_c"][joint]["c_rad"]
    assert offsets.camera_rotation_rad["bottom"]["pitch"] == pytest.approx(truth["camera.bottom.pitch"],
                                                                           abs=0.01 * DEG)
    assert offsets.board_mount["L"]["trans_x_m"] == pytest.approx(truth["board.L.trans_x"], abs=3e-4)


def test_table_output_names_the_weak_pitch_chain(synthetic_dataset, capsys):
    path, _ = synthetic_dataset
    assert main(["identify", str(path), "--cv-folds", "0"]) == 0
    text = capsys.readouterr().out
    assert "c LKneePitch" in text and "weakest directions" in text
    # without --out nothing is written, and the table does not say otherwise (it said "stored in offsets.json")
    assert "joint offsets c (not stored: --out FILE writes them; ADDED to commands" in text
    assert "stored in" not in text


def test_the_table_prints_the_stored_offset_c_labelled_as_everywhere(synthetic_dataset, tmp_path, capsys):
    """One vocabulary: the table shows c = -alpha as offsets.json stores it (and offsets show prints it)."""
    path, truth = synthetic_dataset
    out = tmp_path / "offsets.json"
    assert main(["identify", str(path), "--cv-folds", "0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"joint offsets c (stored in {out}; ADDED to commands, SUBTRACTED from readings" in text
    assert "joint_offset." not in text  # the model's alpha names stay inside the model (and --json)
    stored = read_offsets(out).joint_offsets_rad
    for joint, c in stored.items():
        assert f"  {joint:14s} c = {np.degrees(c):+8.4f} deg" in text, joint
    assert main(["offsets", "show", str(out)]) == 0
    shown = capsys.readouterr().out
    assert f"  {'LHipPitch':<16}{np.degrees(stored['LHipPitch']):>10.4f}" in shown


def test_unknown_effect_is_one_clear_line(synthetic_dataset):
    path, _ = synthetic_dataset
    proc = naocal("identify", str(path), "--effects", "gremlins")
    assert proc.returncode == 2
    assert "unknown effect 'gremlins'" in proc.stderr and "Traceback" not in proc.stderr


def test_missing_dataset_is_one_clear_line(tmp_path):
    proc = naocal("identify", str(tmp_path / "nothing"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "nothing" in proc.stderr


def test_time_lag_without_velocities_is_refused(synthetic_dataset):
    path, _ = synthetic_dataset
    proc = naocal("identify", str(path), "--effects", "time_lag")
    assert proc.returncode == 2 and "vel_" in proc.stderr


def test_degenerate_dataset_exits_3_and_writes_nothing(tmp_path):
    rng = np.random.default_rng(22)
    data = synthesize(rng, random_truth(rng), n_stances_per_leg=1)
    path = tmp_path / "dataset"
    write_dataset(dataset_parts(data), path)
    out = tmp_path / "offsets.json"
    proc = naocal("identify", str(path), "--out", str(out))
    assert proc.returncode == 3, proc.stderr
    assert "cannot determine" in proc.stderr and not out.exists()


def test_quantised_readings_use_the_command_inside_the_cell(tmp_path, capsys):
    """0.1 deg encoder steps: readings alone, fitted by ordinary least squares, leave the leg offsets ~0.1-0.3 deg
    off; auto recovers them (and so does GLS on the readings: its own test in test_gls.py)."""
    rng = np.random.default_rng(23)
    truth = random_truth(rng)
    data = synthesize(rng, truth, pixel_noise_px=0.05, encoder_resolution_rad=0.1 * DEG)
    path = tmp_path / "dataset"
    write_dataset(dataset_parts(data), path)
    errors = {}
    for mode in ("measured", "auto"):
        assert main(["identify", str(path), "--json", "--cv-folds", "0", "--angles", mode, "--no-gls"]) == 0
        report = json.loads(capsys.readouterr().out)
        errors[mode] = max(abs(report["model_parameters"][f"joint_offset.{j}"]["value"] - truth[f"joint_offset.{j}"])
                           for j in ("LHipPitch", "LKneePitch", "LAnklePitch", "RHipPitch", "RKneePitch"))
        if mode == "auto":
            assert "quantised to 0.1 deg" in report["angles"]
    assert errors["auto"] < 0.02 * DEG < errors["measured"]


@pytest.mark.parametrize("preset, expected", [(None, "1"), ("2", "2")])
def test_the_command_line_uses_one_blas_thread_unless_told(preset, expected):
    """Small matrices: threads only hurt when NAOqi keeps the other core busy. A user's setting wins."""
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                            "MKL_NUM_THREADS")}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = "import os, tools.cli, numpy; print(os.environ['OPENBLAS_NUM_THREADS'])"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.strip() == expected, proc.stderr


@pytest.mark.parametrize("effects", [",,,", "elasticity,,backlash", "elasticity,", " , "])
@pytest.mark.parametrize("verb", ["identify", "diagnose"])
def test_a_list_option_with_an_empty_name_is_refused_not_the_default(synthetic_dataset, capsys, verb, effects):
    """`--effects ,,,` silently fitted the base model (issue 21): a list that says nothing is bad input."""
    path, _ = synthetic_dataset
    assert main([verb, str(path), "--effects", effects]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert f"--effects {effects!r}: an empty name" in captured.err


def test_the_arms_list_options_refuse_an_empty_name_too(tmp_path, capsys):
    from naocal.solver.errors import NaocalError
    from naocal.kinds.arm.verbs import parse_arm_effects

    with pytest.raises(NaocalError, match="--effects ',,': an empty name"):
        parse_arm_effects(",,")
    assert main(["simulate", "--robot", "kuka_iiwa", "--out", str(tmp_path / "x"), "--hidden", ",,"]) == 2
    assert "--hidden ',,': an empty name" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
