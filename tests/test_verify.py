"""`naocal verify`: a fixed calibration on new data, without refitting (issue 13)."""

import json
import os
import shutil

import numpy as np
import pytest

from conftest import ROOT
from solver.dataset import write_dataset
from sim.synthetic import dataset_parts, random_truth, synthesize
from tools.cli import main

DEG = np.pi / 180
V1 = ROOT / "tests" / "data" / "v1"


def write(data, path, robot_id="nao-7"):
    write_dataset(dataset_parts(data, robot_id=robot_id, pixel_noise_px=0.1), path)
    return path


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A robot's calibration (naocal identify --out) and the truth it was made from."""
    root = tmp_path_factory.mktemp("verify")
    rng = np.random.default_rng(31)
    truth = random_truth(rng)
    dataset = write(synthesize(rng, truth, n_stances_per_leg=10), root / "calibration")
    offsets = root / "offsets.json"
    assert main(["identify", str(dataset), "--cv-folds", "0", "--out", str(offsets)]) == 0
    return root, truth, dataset, offsets


def verify_json(capsys, dataset, offsets):
    code = main(["verify", str(dataset), "--offsets", str(offsets), "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_the_data_a_calibration_was_made_from_is_good(calibrated, capsys):
    _, _, dataset, offsets = calibrated
    code, report = verify_json(capsys, dataset, offsets)
    assert code == 0 and report["good"] and report["verdict"].startswith("still good")
    assert report["ratio"] == pytest.approx(1.0, abs=0.01)  # the same residuals as the fit's own
    assert report["moved"] == [] and report["suspects"] == []


def test_new_data_of_the_same_robot_are_good(calibrated, capsys):
    root, truth, _, offsets = calibrated
    new = write(synthesize(np.random.default_rng(32), truth, n_stances_per_leg=6), root / "same")
    code, report = verify_json(capsys, new, offsets)
    assert code == 0 and report["good"], report["verdict"]
    assert report["overall"]["rms_px"] == pytest.approx(0.1, abs=0.01)
    for key in ("per_camera", "per_target", "per_image"):
        assert report[key]
    assert set(report["per_target"]) == {"L", "R"} and set(report["per_camera"]) == {"bottom"}
    image = report["per_image"][0]
    assert {"image", "camera", "target", "rms_px", "median_px", "p95_px", "max_px"} <= set(image)


def test_a_calibration_run_directory_is_read_as_its_dataset(calibrated, capsys, tmp_path):
    _, _, dataset, offsets = calibrated
    run = tmp_path / "run"  # `naocal calibrate --out run` keeps its dataset in run/dataset
    shutil.copytree(dataset, run / "dataset")
    code, report = verify_json(capsys, run, offsets)
    assert code == 0 and report["good"], report["verdict"]
    assert "no dataset here" in one_line_error(capsys, tmp_path, "--offsets", offsets)


def test_a_fifo_for_a_file_is_refused_without_blocking(calibrated, capsys, tmp_path):
    _, _, dataset, offsets = calibrated
    fifo = tmp_path / "offsets.json"
    os.mkfifo(fifo)
    assert "offsets.json" in one_line_error(capsys, dataset, "--offsets", fifo)
    copy = shutil.copytree(dataset, tmp_path / "copy")
    (copy / "observations.csv").unlink()
    os.mkfifo(copy / "observations.csv")
    assert "observations.csv" in one_line_error(capsys, copy, "--offsets", offsets)


@pytest.mark.parametrize("joint", ["LKneePitch", "RHipRoll"])
def test_a_joint_offset_that_changed_by_half_a_degree_is_drifted_and_named(calibrated, capsys, joint):
    root, truth, _, offsets = calibrated
    changed = dict(truth)
    changed[f"joint_offset.{joint}"] += 0.5 * DEG
    new = write(synthesize(np.random.default_rng(33), changed, n_stances_per_leg=6), root / f"moved-{joint}")
    code, report = verify_json(capsys, new, offsets)
    assert code == 1 and not report["good"]
    assert report["verdict"].startswith("drifted") and f"joint {joint}" in report["verdict"]
    assert report["suspects"][0] == f"joint {joint}"
    top = report["moved"][0]
    assert top["parameter"] == f"joint_offset.{joint}"
    assert top["change"] == pytest.approx(0.5 * DEG, abs=0.03 * DEG)  # the stored c must grow by 0.5 deg
    # text output says the same, with the exit code
    assert main(["verify", str(new), "--offsets", str(offsets)]) == 1
    assert f"joint {joint}" in capsys.readouterr().out.splitlines()[-1]


def test_a_camera_that_turned_is_named(calibrated, capsys):
    root, truth, _, offsets = calibrated
    changed = dict(truth)
    changed["camera.bottom.roll"] += 0.5 * DEG
    new = write(synthesize(np.random.default_rng(34), changed, n_stances_per_leg=6), root / "camera")
    code, report = verify_json(capsys, new, offsets)
    assert code == 1 and report["suspects"][0] == "camera bottom"


def test_version_1_files(calibrated, capsys):
    _, _, dataset, offsets = calibrated
    code, report = verify_json(capsys, V1 / "mock_dataset", V1 / "offsets_base.json")  # dataset/1, offsets/1
    assert code == 0 and report["ratio"] == pytest.approx(1.0, abs=0.01)
    assert main(["verify", str(V1 / "synthetic_dataset"), "--offsets", str(offsets)]) == 2  # another robot's
    assert "another robot's calibration" in capsys.readouterr().err


def one_line_error(capsys, *args):
    code = main(["verify", *map(str, args)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_bad_inputs_give_one_line_and_exit_2(calibrated, capsys, tmp_path):
    root, truth, dataset, offsets = calibrated
    assert "not found" in one_line_error(capsys, tmp_path / "missing", "--offsets", offsets)
    assert "missing.json" in one_line_error(capsys, dataset, "--offsets", tmp_path / "missing.json")
    assert "offsets.json" not in one_line_error(capsys, dataset, "--offsets", dataset)  # a directory

    doc = json.loads(offsets.read_text())
    other = tmp_path / "other_robot.json"
    other.write_text(json.dumps({**doc, "robot": {**doc["robot"], "body_id": "nao-9", "head_id": "nao-9"}}))
    assert "body 'nao-9'" in one_line_error(capsys, dataset, "--offsets", other)
    schema = tmp_path / "schema.json"
    schema.write_text(json.dumps({**doc, "schema": "naocal.offsets/9"}))
    assert "schema" in one_line_error(capsys, dataset, "--offsets", schema)
    description = tmp_path / "description.json"
    description.write_text(json.dumps({**doc, "robot": {**doc["robot"], "description": "kuka"}}))
    one_line_error(capsys, dataset, "--offsets", description)

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "dataset.json").write_text((dataset / "dataset.json").read_text())
    (empty / "observations.csv").write_text((dataset / "observations.csv").read_text().splitlines()[0] + "\n")
    assert "no observations" in one_line_error(capsys, empty, "--offsets", offsets)
