"""B-Human export: release-aware key sets, the Robots/<head>/<body>/ layout, numbers and signs read back with a reader
written from the format (tests/cfg_reader.py), and merges into a team's 2025 configuration that change only what
naocal calibrated (fixtures in tests/data/export, modelled on the code release's files; sources in its README)."""

import fcntl
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.joints import HEAD_JOINTS, LEG_JOINTS
from naocal.solver.offsets import offsets_from_alpha, write_offsets
from tests.cfg_reader import parse_cfg, rad

DATA = Path(__file__).parent / "data" / "export"
ROBOT = {"id": "nao-17", "body_id": "Dante", "head_id": "Dante"}
FIT = {"rms_px": [0.3, 0.3], "n_vertices": 3456, "n_images": 144}
# B-Human's Joints::Joint enum (Src/Libs/RobotParts/Joints.h), written out here from the release, not from the code.
KEYS_2024 = ("headYaw headPitch lShoulderPitch lShoulderRoll lElbowYaw lElbowRoll lWristYaw lHand rShoulderPitch "
             "rShoulderRoll rElbowYaw rElbowRoll rWristYaw rHand lHipYawPitch lHipRoll lHipPitch lKneePitch "
             "lAnklePitch lAnkleRoll rHipYawPitch rHipRoll rHipPitch rKneePitch rAnklePitch rAnkleRoll").split()
KEYS_2025 = KEYS_2024[:2] + ["waistYaw"] + KEYS_2024[2:]
ARMS = [k for k in KEYS_2024 if k[1:].startswith(("Shoulder", "Elbow", "Wrist", "Hand"))]


def alphas(seed, head=True):
    rng = np.random.default_rng(seed)
    joints = {j: float(rng.normal(0, 0.03)) for j in LEG_JOINTS + (HEAD_JOINTS if head else ())}
    return joints, tuple(rng.normal(0, 0.04, 3)), tuple(rng.normal(0, 0.04, 3))


def offsets_file(tmp_path, seed=1, *, head=True, top=False, robot=ROBOT, name="nao-17.json"):
    joints, bottom, upper = alphas(seed, head)
    offsets = offsets_from_alpha(joints, bottom, {"L": (0, 0, 0), "R": (0, 0, 0)}, robot=robot, fit=FIT,
                                 created="2025-03-20T10:00:00Z", top_camera_rpy=upper if top else None)
    path = tmp_path / name
    write_offsets(offsets, path)
    return path, joints, bottom, upper


def export(capsys, *argv):
    code = tools.cli.main(["offsets", "export", *map(str, argv), "--format", "bhuman"])
    out, err = capsys.readouterr()
    return code, out, err


def key_of(joint):
    return joint[0].lower() + joint[1:]


@pytest.mark.parametrize("release,keys", [(2025, KEYS_2025), (2026, KEYS_2025), (2024, KEYS_2024),
                                          (2017, KEYS_2024)])
def test_fresh_files_round_trip_with_the_release_keys(capsys, tmp_path, release, keys):
    path, joints, bottom, _ = offsets_file(tmp_path)
    code, _, err = export(capsys, path, "--out", tmp_path / "Config", "--bhuman-release", release)
    assert code == 0, err
    joint_cfg = parse_cfg((tmp_path / "Config/Robots/Dante/Body/jointCalibration.cfg").read_text())
    assert list(joint_cfg) == ["offsets"] and list(joint_cfg["offsets"]) == keys  # every key, in B-Human's order
    for key, literal in joint_cfg["offsets"].items():
        joint = key[0].upper() + key[1:]
        # B-Human stores the offset it adds to requests and subtracts from readings: c = -alpha, same sign.
        assert rad(literal) == pytest.approx(-joints.get(joint, 0.0), abs=1e-8), key
    camera_cfg = parse_cfg((tmp_path / "Config/Robots/Dante/Dante/cameraCalibration.cfg").read_text())
    lower = (camera_cfg["cameraRotationCorrections"]["lower"] if release >= 2019
             else camera_cfg["lowerCameraRotationCorrection"])
    assert [rad(lower[a]) for a in "xyz"] == pytest.approx(list(bottom), abs=1e-8)  # x roll, y pitch, z yaw
    assert "0deg" in err or "0 (nominal)" in err or "written as 0deg" in err  # says what it zeroed


def test_readings_corrected_with_the_export_are_the_true_angles(capsys, tmp_path):
    """B-Human's NaoProvider: reading = sensor - offset, request sent = request + offset. With the model
    q_true = theta + alpha, the corrected reading must be q_true and a request must land on the true angle."""
    path, joints, _, _ = offsets_file(tmp_path, seed=4)
    export(capsys, path, "--out", tmp_path / "Config")
    offsets = parse_cfg((tmp_path / "Config/Robots/Dante/Body/jointCalibration.cfg").read_text())["offsets"]
    for joint, alpha in joints.items():
        offset = rad(offsets[key_of(joint)])
        theta = 0.3  # encoder reading
        assert theta - offset == pytest.approx(theta + alpha, abs=1e-8)
        request = -0.2
        sent = request + offset  # the servo ends with its encoder at `sent`
        assert sent + alpha == pytest.approx(request, abs=1e-8)


def test_releases_before_the_offsets_layout_are_refused(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path)
    code, _, err = export(capsys, path, "--bhuman-release", "2016")
    assert code == 2 and err.count("\n") == 1 and "before 2017" in err


def test_stdout_without_out(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path)
    code, out, _ = export(capsys, path)
    assert code == 0 and "// ---- Robots/Dante/Body/jointCalibration.cfg" in out and "waistYaw = 0deg;" in out


@pytest.fixture
def team_config(tmp_path):
    """A copy of the team's 2025 Config directory (robot Dante: its own joint and camera files)."""
    config = tmp_path / "Config"
    shutil.copytree(DATA / "bhuman2025", config)
    return config


def lines(path):
    return Path(path).read_text().splitlines()


def test_merge_into_2025_keeps_arms_waist_upper_camera_and_body_rotation(capsys, tmp_path, team_config):
    path, joints, bottom, _ = offsets_file(tmp_path)
    joint_file = team_config / "Robots/Dante/Body/jointCalibration.cfg"
    camera_file = team_config / "Robots/Dante/Dante/cameraCalibration.cfg"
    joint_before, camera_before = joint_file.read_text(), camera_file.read_text()
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", team_config,
                          "--bhuman-release", "2025")
    assert code == 0, err

    after = lines(joint_file)
    calibrated_keys = {key_of(j) for j in joints}
    for old, new in zip(joint_before.splitlines(), after):
        key = old.strip().split(" ")[0]
        if key in calibrated_keys:
            assert new != old
        else:
            assert new == old  # arms, hands, waistYaw, comments: byte for byte
    assert len(after) == len(joint_before.splitlines())
    assert "  rKneePitch = " in joint_file.read_text() and "// replaced gear 2025-02" in joint_file.read_text()
    offsets = parse_cfg(joint_file.read_text())["offsets"]
    for joint, alpha in joints.items():
        assert rad(offsets[key_of(joint)]) == pytest.approx(-alpha, abs=1e-8)
    for key in ARMS + ["waistYaw"]:
        assert offsets[key] == parse_cfg(joint_before)["offsets"][key]

    camera = parse_cfg(camera_file.read_text())
    assert [rad(camera["cameraRotationCorrections"]["lower"][a]) for a in "xyz"] == pytest.approx(list(bottom),
                                                                                                   abs=1e-8)
    old_lines, new_lines = camera_before.splitlines(), lines(camera_file)
    changed = [i for i, (a, b) in enumerate(zip(old_lines, new_lines)) if a != b]
    assert [old_lines[i].strip().split(" ")[0] for i in changed] == ["lower"]  # upper, body, comment: untouched
    # The previous files are kept, and the notes say what was kept.
    assert (joint_file.parent / "jointCalibration.cfg.bak").read_text() == joint_before
    assert (camera_file.parent / "cameraCalibration.cfg.bak").read_text() == camera_before
    assert "kept as they were: waistYaw" in err and "upper camera not calibrated" in err
    assert "bodyRotationCorrection" in err


def test_merge_twice_changes_nothing_the_second_time(capsys, tmp_path, team_config):
    path, *_ = offsets_file(tmp_path)
    export(capsys, path, "--merge-from", team_config, "--out", team_config)
    snapshot = {p: p.read_bytes() for p in team_config.rglob("*")  if p.is_file()}
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", team_config)
    assert code == 0 and err.count("unchanged") == 2
    assert {p: p.read_bytes() for p in team_config.rglob("*") if p.is_file()} == snapshot


def test_merge_without_head_offsets_keeps_the_team_head_and_sets_the_upper_camera(capsys, tmp_path, team_config):
    path, joints, _, upper = offsets_file(tmp_path, head=False, top=True)
    before = parse_cfg((team_config / "Robots/Dante/Body/jointCalibration.cfg").read_text())["offsets"]
    assert export(capsys, path, "--merge-from", team_config, "--out", team_config)[0] == 0
    after = parse_cfg((team_config / "Robots/Dante/Body/jointCalibration.cfg").read_text())["offsets"]
    assert (after["headYaw"], after["headPitch"]) == (before["headYaw"], before["headPitch"])
    camera = parse_cfg((team_config / "Robots/Dante/Dante/cameraCalibration.cfg").read_text())
    assert [rad(camera["cameraRotationCorrections"]["upper"][a]) for a in "xyz"] == pytest.approx(list(upper),
                                                                                                   abs=1e-8)


def test_merge_refuses_a_release_that_does_not_match_the_file(capsys, tmp_path, team_config):
    path, *_ = offsets_file(tmp_path)
    snapshot = {p: p.read_bytes() for p in team_config.rglob("*") if p.is_file()}
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", team_config, "--bhuman-release", "2024")
    assert code == 2 and err.count("\n") == 1
    assert "Robots/Dante/Body/jointCalibration.cfg" in err and "waistYaw" in err and "2024" in err
    assert {p: p.read_bytes() for p in team_config.rglob("*") if p.is_file()} == snapshot


def test_merge_for_a_robot_without_files_starts_from_default_and_writes_its_own(capsys, tmp_path, team_config):
    path, joints, _, _ = offsets_file(tmp_path)
    default = (team_config / "Robots/Default/jointCalibration.cfg").read_text()
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", tmp_path / "out",
                          "--head-id", "Kurt", "--body-id", "Otto")
    assert code == 0, err
    written = tmp_path / "out/Robots/Otto/Body/jointCalibration.cfg"
    offsets = parse_cfg(written.read_text())["offsets"]
    assert list(offsets) == KEYS_2025 and rad(offsets["lHipPitch"]) == pytest.approx(-joints["LHipPitch"], abs=1e-8)
    assert (tmp_path / "out/Robots/Kurt/Otto/cameraCalibration.cfg").exists()
    assert (team_config / "Robots/Default/jointCalibration.cfg").read_text() == default  # defaults untouched
    assert "started from Robots/Default/jointCalibration.cfg" in err


def test_merge_into_a_2024_config_keeps_26_keys(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path)
    code, _, err = export(capsys, path, "--merge-from", DATA / "bhuman2024", "--out", tmp_path / "out")
    assert code == 0, err
    assert list(parse_cfg((tmp_path / "out/Robots/Dante/Body/jointCalibration.cfg").read_text())["offsets"]) \
        == KEYS_2024


@pytest.mark.parametrize("damage,problem", [
    (lambda p: p.write_text(p.read_text().replace("  lHipRoll = 0.7deg;\n", "")), "offsets.lHipRoll"),
    (lambda p: p.write_text(p.read_text().replace("lKneePitch = -0.9deg;", "lKneePitch = -0.9deg")), "line 21"),
    (lambda p: p.write_text(p.read_text().replace("waistYaw", "hipYaw")), "offsets.hipYaw"),
    (lambda p: (p.unlink(), os.mkfifo(p)), "not a regular file"),
])
def test_damaged_team_files_are_refused_in_one_line(capsys, tmp_path, team_config, damage, problem):
    path, *_ = offsets_file(tmp_path)
    damage(team_config / "Robots/Dante/Body/jointCalibration.cfg")
    code, _, err = export(capsys, path, "--merge-from", team_config, "--out", tmp_path / "out")
    assert code == 2 and err.count("\n") == 1 and problem in err and "jointCalibration.cfg" in err, err
    assert not (tmp_path / "out").exists()


def test_merge_from_a_directory_without_the_files(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path)
    (tmp_path / "empty").mkdir()
    code, _, err = export(capsys, path, "--merge-from", tmp_path / "empty", "--out", tmp_path / "out")
    assert code == 2 and err.count("\n") == 1 and "no jointCalibration.cfg" in err


def test_a_second_export_into_the_same_directory_is_refused_while_one_runs(capsys, tmp_path, team_config):
    path, *_ = offsets_file(tmp_path)
    fd = os.open(team_config, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # what a running export holds
        code, _, err = export(capsys, path, "--merge-from", team_config, "--out", team_config)
    finally:
        os.close(fd)
    assert code == 2 and "another naocal export" in err
    assert not (team_config / "Robots/Dante/Body/jointCalibration.cfg.bak").exists()


def test_values_written_to_a_millionth_of_a_degree(capsys, tmp_path):
    path, joints, _, _ = offsets_file(tmp_path, seed=9)
    _, out, _ = export(capsys, path)
    offsets = parse_cfg(out.split("// ---- ")[1].split("\n", 1)[1])["offsets"]
    for joint, alpha in joints.items():
        literal = offsets[key_of(joint)]
        assert len(literal[:-3].partition(".")[2]) <= 6 and "e" not in literal[:-3], literal
        assert abs(math.degrees(rad(literal) + alpha)) <= 5e-7


def test_unknown_ids_ask_for_the_option(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path, robot={"id": "nao-17", "body_id": None, "head_id": "Dante"})
    code, _, err = export(capsys, path, "--out", tmp_path / "Config")
    assert code == 2 and err.count("\n") == 1 and "robot.body_id is unknown" in err and "--body-id" in err
    assert export(capsys, path, "--out", tmp_path / "Config", "--body-id", "Otto")[0] == 0
    assert (tmp_path / "Config/Robots/Otto/Body/jointCalibration.cfg").exists()


def test_team_options_are_refused_for_other_formats(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path)
    code = tools.cli.main(["offsets", "export", str(path), "--format", "urdf", "--merge-from", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--merge-from applies to the team formats" in err
