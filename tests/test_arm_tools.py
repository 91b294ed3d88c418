"""An arm's calibration file through the command line (docs/ARM.md): naocal verify of new data under it, naocal
offsets show / diff / validate / export of it, on synthetic data of the Franka Panda with a hidden truth."""

import json
import math

import numpy as np
import pytest

from test_arm import synthetic, true_errors, write
from tools.cli import main


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory):
    """Two datasets of one arm with hidden link lengths and joint offsets (even and odd poses of one simulation),
    and the calibration identified from the first."""
    root = tmp_path_factory.mktemp("arm")
    model, obs, _, sensors = synthetic(("joint_offsets", "link_lengths"), true_errors(seed=8), n_poses=60, seed=9)
    first = write(root / "first", model, obs.subset(obs.pose % 2 == 0), sensors)
    second = write(root / "second", model, obs.subset(obs.pose % 2 == 1), sensors)
    assert main(["identify", str(first), "--out", str(root / "cal.json"), "--json"]) == 0
    return root, first, second, root / "cal.json"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def edited(path, out, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    out.write_text(json.dumps(doc))
    return out


def shift(doc, name, delta):
    doc["model"]["parameters"][name]["value"] += delta
    section, key = name.split(".", 1)
    table = {"joint_offset": "joint_offsets_rad", "link_length": "link_lengths_m"}[section]
    doc[table][key] += delta


# ------------------------------------------------------------------------------------------------ verify


def test_verify_new_data_of_the_same_arm_is_still_good(two_sessions, capsys):
    root, _, second, cal = two_sessions
    code, out, err = run(capsys, "verify", second, "--offsets", cal, "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["good"] and report["ratio"] < 1.3 and not report["moved"]
    assert set(report["per_sensor"]) == {"tracker", "camera"}
    assert report["per_sensor"]["tracker"]["unit"] == "m" and report["per_sensor"]["camera"]["unit"] == "px"
    assert report["per_sensor"]["tracker"]["rms"] == pytest.approx(1e-4, rel=0.2)
    code, out, _ = run(capsys, "verify", second, "--offsets", cal)
    assert code == 0 and out.strip().splitlines()[-1].startswith("still good")


@pytest.mark.parametrize("name, delta, unit", [("joint_offset.panda_joint4", math.radians(0.3), "deg"),
                                               ("link_length.panda_link4", 1e-3, "mm")])
def test_verify_names_what_moved_when_the_arm_drifted(two_sessions, capsys, tmp_path, name, delta, unit):
    root, _, second, cal = two_sessions
    drifted = edited(cal, tmp_path / "drifted.json", lambda doc: shift(doc, name, delta))
    code, out, err = run(capsys, "verify", second, "--offsets", drifted, "--json")
    assert code == 1, err
    report = json.loads(out)
    assert not report["good"] and report["ratio"] > 3
    assert report["moved"][0]["parameter"] == name
    # the data say the calibrated value is `delta` too large
    assert report["moved"][0]["change"] == pytest.approx(-delta, rel=0.05)
    assert report["moved"][0]["display"][1] == unit and report["verdict"].startswith("drifted")


def test_verify_without_stated_noise_takes_a_refit_as_the_noise_floor(two_sessions, capsys, tmp_path):
    root, _, second, cal = two_sessions
    import shutil

    quiet = tmp_path / "quiet"
    shutil.copytree(second, quiet)
    edited(quiet / "dataset.json", quiet / "dataset.json",
           lambda doc: [s.pop("noise_m", None) or s.pop("noise_px", None) for s in doc["sensors"].values()])
    code, out, err = run(capsys, "verify", quiet, "--offsets", cal, "--json")
    assert code == 0, err
    tracker = json.loads(out)["per_sensor"]["tracker"]
    assert tracker["noise_source"] == "refit" and tracker["noise_floor"] == pytest.approx(1e-4, rel=0.25)


def test_verify_bad_input_is_one_line_exit_2(two_sessions, capsys, tmp_path):
    root, first, second, cal = two_sessions
    nao = tmp_path / "nao.json"
    nao.write_text(json.dumps({"schema": "naocal.offsets/2"}))
    other_tip = edited(cal, tmp_path / "tip.json", lambda doc: doc["robot"].update(tip="panda_link7"))
    other_arm = edited(cal, tmp_path / "id.json", lambda doc: doc["robot"].update(id="another"))
    damaged = edited(cal, tmp_path / "bad.json",
                     lambda doc: doc["model"]["parameters"]["joint_offset.panda_joint2"].update(value="x"))
    unit = edited(cal, tmp_path / "unit.json",
                  lambda doc: doc["model"]["parameters"]["link_length.panda_link3"].update(unit="mm"))
    for offsets, message in ((nao, "naocal.arm_calibration/1"), (other_tip, "robot.tip"), (other_arm, "robot.id"),
                             (damaged, "model.parameters.joint_offset.panda_joint2.value"),
                             (unit, "model.parameters.link_length.panda_link3.unit"),
                             (tmp_path / "missing.json", "missing.json")):
        code, out, err = run(capsys, "verify", second, "--offsets", offsets)
        assert code == 2 and message in err and err.count("\n") == 1, (offsets, err)
    code, _, err = run(capsys, "verify", tmp_path / "nowhere", "--offsets", cal)
    assert code == 2 and "nowhere" in err
