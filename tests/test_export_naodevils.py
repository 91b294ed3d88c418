"""Nao Devils export: per-joint {offset; minAngle; maxAngle} records and lower/upper/body camera corrections, read back
with tests/cfg_reader.py; merges keep the limits and everything naocal did not calibrate (fixtures in
tests/data/export/naodevils, modelled on their code release; sources in its README)."""

import math
import shutil
from pathlib import Path

import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.limits import joint_limits
from tests.cfg_reader import parse_cfg, rad
from tests.test_export_bhuman import KEYS_2024, key_of, offsets_file

DATA = Path(__file__).parent / "data" / "export" / "naodevils"
ROBOT = {"id": "nao-5", "body_id": "Nao", "head_id": "Nao"}


def export(capsys, *argv):
    code = tools.cli.main(["offsets", "export", *map(str, argv), "--format", "naodevils"])
    out, err = capsys.readouterr()
    return code, out, err


def test_fresh_files_round_trip(capsys, tmp_path):
    path, joints, bottom, _ = offsets_file(tmp_path)
    code, _, err = export(capsys, path, "--out", tmp_path / "Config")
    assert code == 0, err
    cfg = parse_cfg((tmp_path / "Config/Robots/Dante/Body/jointCalibration.cfg").read_text())
    assert list(cfg) == KEYS_2024
    limits = joint_limits()
    for key, record in cfg.items():
        joint = key[0].upper() + key[1:]
        assert set(record) == {"offset", "minAngle", "maxAngle"}
        assert rad(record["offset"]) == pytest.approx(-joints.get(joint, 0.0), abs=1e-8)  # added to requests: c
        low, high = limits[joint]
        assert low <= rad(record["minAngle"]) < rad(record["maxAngle"]) <= high  # never wider than the robot
        assert rad(record["maxAngle"]) - rad(record["minAngle"]) > high - low - math.radians(0.02)
    camera = parse_cfg((tmp_path / "Config/Robots/Dante/Dante/cameraCalibration.cfg").read_text())
    assert [rad(camera["lowerCameraRotationCorrection"][a]) for a in "xyz"] == pytest.approx(list(bottom), abs=1e-8)
    assert set(camera) == {"lowerCameraRotationCorrection", "upperCameraRotationCorrection", "bodyRotationCorrection"}


@pytest.fixture
def team_config(tmp_path):
    config = tmp_path / "Config"
    shutil.copytree(DATA, config)
    return config


def test_merge_keeps_limits_arms_upper_camera_and_body_rotation(capsys, tmp_path, team_config):
    path, joints, bottom, _ = offsets_file(tmp_path, robot=ROBOT)
    v5 = team_config / "Robots/V5/jointCalibration.cfg"
    camera_file = team_config / "Robots/Nao/Nao/cameraCalibration.cfg"
    v5_before, camera_before = v5.read_text(), camera_file.read_text()
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", team_config)
    assert code == 0, err

    assert v5.read_text() == v5_before  # the version default is not the robot's file: untouched
    written = team_config / "Robots/Nao/Body/jointCalibration.cfg"
    before, after = parse_cfg(v5_before), parse_cfg(written.read_text())
    for key in KEYS_2024:
        joint = key[0].upper() + key[1:]
        assert (after[key]["minAngle"], after[key]["maxAngle"]) == (before[key]["minAngle"], before[key]["maxAngle"])
        if joint in joints:
            assert rad(after[key]["offset"]) == pytest.approx(-joints[joint], abs=1e-8)
        else:
            assert after[key]["offset"] == before[key]["offset"]
    changed = [a for a, b in zip(v5_before.splitlines(), written.read_text().splitlines()) if a != b]
    assert len(changed) == len(joints) and all(line.strip().startswith("offset =") for line in changed)
    assert "started from Robots/V5/jointCalibration.cfg" in err

    camera = parse_cfg(camera_file.read_text())
    assert [rad(camera["lowerCameraRotationCorrection"][a]) for a in "xyz"] == pytest.approx(list(bottom), abs=1e-8)
    old_lines, new_lines = camera_before.splitlines(), camera_file.read_text().splitlines()
    assert new_lines[1:] == old_lines[1:]  # upper and body rotation: byte for byte
    assert {key_of(j) for j in joints} <= set(after)


def test_damaged_team_file_is_refused(capsys, tmp_path, team_config):
    path, *_ = offsets_file(tmp_path, robot=ROBOT)
    v5 = team_config / "Robots/V5/jointCalibration.cfg"
    v5.write_text(v5.read_text().replace("  offset = -11.5deg;\n", "", 1))
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", tmp_path / "out")
    assert code == 2 and err.count("\n") == 1 and "lHipYawPitch.offset" in err and "missing" in err
    assert not (tmp_path / "out").exists()
