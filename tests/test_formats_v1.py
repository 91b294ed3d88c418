"""Files written by naocal.dataset/1 and naocal.offsets/1 (tests/data/v1, made by commit 0a4df14's code: see
make_fixtures.py there) still read, as strictly as then, and give the same numbers."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.dataset import read_dataset
from naocal.solver.errors import DataError
from naocal.solver.offsets import SCHEMA_V1, format_offsets, read_offsets, validate

V1 = Path(__file__).parent / "data" / "v1"


def run_json(capsys, *argv):
    assert tools.cli.main([*map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def v2_name(name: str) -> str:
    group, _, rest = name.partition(".")
    return f"{group}.bottom.{rest}" if group in ("camera", "intrinsics", "distortion") else name


def test_identify_on_a_version_1_dataset_gives_the_same_numbers(capsys, tmp_path):
    """The same values as then; the standard deviations now also hold the readings' quantisation (0.1 deg
    steps), so they are larger."""
    case = "effects"
    old = json.loads((V1 / f"identify_{case}.json").read_text())
    new = run_json(capsys, "identify", V1 / "mock_dataset", "--effects", "time_lag,head_offsets", "--angles", "cell",
                   "--cv-folds", 0, "--out", tmp_path / "o.json")
    np.testing.assert_allclose(new["rms_px"], old["rms_px"], rtol=1e-9)
    assert "the command inside the reading's step (as asked)" in new["angles"]
    assert len(new["model_parameters"]) == len(old["parameters"])
    for name, entry in old["parameters"].items():
        sign = -1.0 if name.startswith(("joint_offset.", "head_offset.")) else 1.0  # version 1 reported alpha = -c
        got = new["model_parameters"][v2_name(name)]
        if sign < 0:  # the c table says the same
            assert new["joint_offsets_c"][name.split(".", 1)[1]]["c_rad"] == got["value"], name
        assert got["value"] == pytest.approx(sign * entry["value"], abs=1e-9 * max(1.0, abs(entry["value"]))), name
        assert got["std"] >= entry["std"] * (1 - 1e-6), name
        assert got["unit"] == entry["unit"]
    # ... and the file it writes (version 2) holds the same offsets as the version 1 file of that time
    written, then = read_offsets(tmp_path / "o.json"), read_offsets(V1 / f"offsets_{case}.json")
    assert written.read_schema == "naocal.offsets/2" and then.read_schema == SCHEMA_V1
    for joint, c in then.joint_offsets_rad.items():
        assert written.joint_offsets_rad[joint] == pytest.approx(c, abs=1e-12), joint
    for angle in ("roll", "pitch", "yaw"):
        assert written.camera_rpy()[("roll", "pitch", "yaw").index(angle)] == pytest.approx(
            then.camera_rpy()[("roll", "pitch", "yaw").index(angle)], abs=1e-12)
    for leg in ("L", "R"):
        for key, value in then.board_mount[leg].items():
            assert written.board_mount[leg][key] == pytest.approx(value, abs=1e-12)
    for name, entry in then.model["parameters"].items():
        assert written.model["parameters"][name]["value"] == pytest.approx(entry["value"], abs=1e-12), name


def test_the_base_fit_of_a_version_1_dataset_sets_its_moving_captures_aside(capsys):
    """Then, the base model was fitted to the lag probe's moving captures too (angles off by velocity x lag: RMS
    0.13/0.32 px); now they wait for the time_lag effect and the base fit is at the noise."""
    old = json.loads((V1 / "identify_base.json").read_text())
    new = run_json(capsys, "identify", V1 / "mock_dataset", "--cv-folds", 0)
    assert new["moving_captures_set_aside"] == 6
    assert max(new["rms_px"]) < 0.06 < min(old["rms_px"])


def test_a_version_1_dataset_reads_as_written():
    dataset = read_dataset(V1 / "mock_dataset")
    assert dataset.version == 1 and dataset.meta["schema"] == "naocal.dataset/1"
    assert dataset.has_velocities and dataset.n_rows == 720
    assert dataset.meta["gravity_torso_mps2"] == [-9.81, 0.0, 0.0]


def test_diagnose_on_a_version_1_dataset_with_the_angles_as_then(capsys):
    """The diagnostics of the synthetic version 1 dataset with measured (or commanded) angles are those of that
    time; with 'auto', version 1's per-joint step search missed RAnklePitch (5 readings, a gap of more than 100
    steps) and used the command for 260 of 280 readings: the one step search now finds all 280."""
    old = json.loads((V1 / "diagnose_synthetic.json").read_text())
    new = run_json(capsys, "diagnose", V1 / "synthetic_dataset", "--no-tie-hip-yaw-pitch")  # made with two offsets
    assert new["rms_px"][0] < old["rms_px"][0] and new["rms_px"][1] < old["rms_px"][1]  # the fix: at the noise
    assert total(new["rms_px"]) < 1.1 * 0.05
    for mode in ("measured", "commanded"):
        ours = run_json(capsys, "identify", V1 / "synthetic_dataset", "--angles", mode, "--cv-folds", 0)
        assert "(as asked)" in ours["angles"] and ours["angle_choice"]["chosen"] == mode
    auto = run_json(capsys, "identify", V1 / "synthetic_dataset", "--cv-folds", 0, "--no-tie-hip-yaw-pitch")
    assert auto["angle_choice"]["chosen"] == "cell" and "quantised to 0.1 deg" in auto["angles"]


def total(xy):
    return math.sqrt((xy[0] ** 2 + xy[1] ** 2) / 2)


@pytest.mark.parametrize("name", ["offsets_base.json", "offsets_effects.json", "offsets_top.json"])
def test_version_1_offsets_read_with_their_numbers_and_rewrite_as_version_2(tmp_path, name):
    doc = json.loads((V1 / name).read_text())
    offsets = read_offsets(V1 / name)
    assert offsets.joint_offsets_rad == doc["joint_offsets_rad"]  # c, exactly
    assert offsets.camera_rotation_rad == doc["camera_rotation_rad"]  # both cameras where the file has them
    assert offsets.board_mount == doc["board_mount"]
    assert offsets.fit == doc["fit"] and offsets.source == doc["source"] and offsets.created == doc["created"]
    for old_name, entry in doc["model"]["parameters"].items():
        new = offsets.parameter(v2_name(old_name))
        sign = -1.0 if old_name.startswith(("joint_offset.", "head_offset.")) else 1.0  # alpha then, c now
        assert new == {**entry, "value": sign * entry["value"]}, old_name
    # written again: version 2, the same numbers
    (tmp_path / "again.json").write_text(format_offsets(offsets))
    again = read_offsets(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text())["schema"] == "naocal.offsets/2"
    for field in ("joint_offsets_rad", "camera_rotation_rad", "board_mount", "fit", "source", "created"):
        assert getattr(again, field) == getattr(offsets, field), field
    assert again.model == offsets.model


def damaged_v1(tmp_path, change):
    doc = json.loads((V1 / "offsets_effects.json").read_text())
    change(doc)
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError) as info:
        read_offsets(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    return info.value


@pytest.mark.parametrize("change,field,problem", [
    (lambda d: d["joint_offsets_rad"].update(LHipPitch=0.62), "joint_offsets_rad.LHipPitch", "degrees instead"),
    (lambda d: d["joint_offsets_rad"].pop("RKneePitch"), "joint_offsets_rad.RKneePitch", "missing"),
    (lambda d: d["camera_rotation_rad"].update(middle={"roll": 0, "pitch": 0, "yaw": 0}),
     "camera_rotation_rad.middle", "unknown field"),
    (lambda d: d["board_mount"]["L"].update(trans_x_m=2.0), "board_mount.L.trans_x_m", "mm instead of m"),
    (lambda d: d["model"]["parameters"]["camera.pitch"].update(unit="deg"), "model.parameters.camera.pitch.unit",
     "unknown unit"),
    (lambda d: d["model"]["parameters"].update({"camera.bottom.pitch": {"value": 0, "std": 0, "unit": "rad"}}),
     "model.parameters.camera.bottom.pitch", "unknown model parameter name"),  # version 2's name in a v1 file
    (lambda d: d.update(body={}), "body", "unknown field"),
])
def test_version_1_files_are_checked_as_strictly_as_then(tmp_path, change, field, problem):
    err = damaged_v1(tmp_path, change)
    assert err.field == field, str(err)
    assert problem in str(err)


def test_validate_accepts_both_versions():
    validate(json.loads((V1 / "offsets_top.json").read_text()))
    validate(read_offsets(V1 / "offsets_top.json").to_dict())
