"""HULKs export: body.<BodyId>.json and head.<HeadId>.json with their field names, naocal's camera rotation converted
into HULKs' camera frame exactly (checked pixel by pixel with both camera models, written here from HULKs' and
naocal's code), and merges that keep every other field (fixtures in tests/data/export/hulks, sources in its README)."""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from tests.test_export_bhuman import offsets_file
from naocal.tools.export.hulks import hulks_correction, naocal_camera_rpy

DATA = Path(__file__).parent / "data" / "export" / "hulks"
BODY, HEAD = "P0000073A19S31T00003", "P0000074A09S31T00003"
ROBOT = {"id": "nao-21", "body_id": BODY, "head_id": HEAD}
LEGS = {"L": "left_leg", "R": "right_leg"}
FIELDS = {"HipYawPitch": "hip_yaw_pitch", "HipRoll": "hip_roll", "HipPitch": "hip_pitch", "KneePitch": "knee_pitch",
          "AnklePitch": "ankle_pitch", "AnkleRoll": "ankle_roll"}


def rot(axis, angle):
    axis = np.asarray(axis, dtype=float)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


X, Y, Z = (1, 0, 0), (0, 1, 0), (0, 0, 1)


def from_euler_angles(x, y, z):
    """nalgebra's Rotation3::from_euler_angles(roll, pitch, yaw): roll about x, then pitch about y, then yaw about z."""
    return rot(Z, z) @ rot(Y, y) @ rot(X, x)


def hulks_head_to_camera(pitch_down):
    """HULKs' head_to_camera rotation (camera_matrix_calculator.rs): Rx(-camera_pitch) * Ry(-pi/2) * Rx(pi/2), with
    camera_pitch negative for a camera looking down (projection tests: 'pitch_45_degree_down' uses -FRAC_PI_4)."""
    return rot(X, pitch_down) @ rot(Y, -math.pi / 2) @ rot(X, math.pi / 2)


def project_hulks(R_cam_head, p_head):
    """Intrinsic::project: (fx x / z + cx, fy y / z + cy) with fx = fy = 600, (cx, cy) = (320, 240)."""
    x, y, z = R_cam_head @ p_head
    return np.array([600 * x / z + 320, 600 * y / z + 240])


def project_naocal(R_head_cam, p_head):
    """naocal's camera model (docs/CONVENTIONS.md): u = cx - fx y / x, v = cy - fy z / x in the NAO camera frame."""
    x, y, z = R_head_cam.T @ p_head
    return np.array([320 - 600 * y / x, 240 - 600 * z / x])


@pytest.mark.parametrize("seed", range(20))
def test_correction_moves_every_pixel_as_naocals_camera_rotation_does(seed):
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = rng.uniform(-math.radians(15), math.radians(15), 3)  # the offsets file's plausible range
    nominal = rng.choice([0.692896, 0.0209435])  # bottom and top camera pitch
    R_head_naocal = rot(Y, nominal) @ rot(Y, pitch) @ rot(X, roll) @ rot(Z, yaw)
    C = from_euler_angles(*hulks_correction((roll, pitch, yaw)))
    R_cam_head_hulks = C @ hulks_head_to_camera(nominal)  # CameraMatrix::to_corrected: correction * head_to_camera
    optical_axis = R_head_naocal @ np.array([1.0, 0.0, 0.0])
    for _ in range(10):  # points in front of the camera, within the image
        direction = optical_axis + rng.uniform(-0.3, 0.3, 3)
        point = direction * rng.uniform(0.2, 3.0)
        assert project_hulks(R_cam_head_hulks, point) == pytest.approx(project_naocal(R_head_naocal, point),
                                                                        abs=1e-9)
    assert naocal_camera_rpy(hulks_correction((roll, pitch, yaw))) == pytest.approx((roll, pitch, yaw), abs=1e-12)


def test_nominal_frames_agree_without_correction():
    for nominal in (0.692896, 0.0209435):
        assert hulks_correction((0.0, 0.0, 0.0)) == pytest.approx([0, 0, 0], abs=1e-15)
        point = np.array([1.0, 0.2, -0.4])
        assert project_hulks(hulks_head_to_camera(nominal), point) == pytest.approx(
            project_naocal(rot(Y, nominal), point), abs=1e-9)


def export(capsys, *argv):
    code = tools.cli.main(["offsets", "export", *map(str, argv), "--format", "hulks"])
    out, err = capsys.readouterr()
    return code, out, err


def test_fresh_files_hold_only_what_naocal_calibrated(capsys, tmp_path):
    path, joints, bottom, upper = offsets_file(tmp_path, robot=ROBOT, top=True)
    code, _, err = export(capsys, path, "--out", tmp_path / "parameters")
    assert code == 0, err
    body = json.loads((tmp_path / f"parameters/body.{BODY}.json").read_text())
    assert list(body) == ["joint_calibration_offsets"]
    offsets = body["joint_calibration_offsets"]
    assert set(offsets) == {"left_leg", "right_leg", "head"}  # no arms: HULKs keeps their defaults
    for joint, alpha in joints.items():
        if joint.startswith("Head"):
            value = offsets["head"][joint[4:].lower()]
        else:
            value = offsets[LEGS[joint[0]]][FIELDS[joint[1:]]]
        assert value == -alpha  # c, added to commands and subtracted from readings, exactly (rad, JSON floats)
    head = json.loads((tmp_path / f"parameters/head.{HEAD}.json").read_text())
    calibration = head["camera_matrix_parameters"]["calibration"]
    assert set(calibration) == {"correction_in_camera_bottom", "correction_in_camera_top"}
    for name, rpy in (("bottom", bottom), ("top", upper)):
        assert naocal_camera_rpy(calibration[f"correction_in_camera_{name}"]) == pytest.approx(rpy, abs=1e-12)
    assert "correction_in_robot not estimated" in err and "arms not calibrated" in err


def test_no_head_offsets_and_no_top_camera_are_left_out(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path, robot=ROBOT, head=False)
    _, out, err = export(capsys, path)
    body_text, head_text = (part.split("\n", 1)[1] for part in out.split("// ---- ")[1:])
    assert "head" not in json.loads(body_text)["joint_calibration_offsets"]
    assert list(json.loads(head_text)["camera_matrix_parameters"]["calibration"]) == ["correction_in_camera_bottom"]
    assert "top camera not calibrated" in err


@pytest.fixture
def team_parameters(tmp_path):
    parameters = tmp_path / "parameters"
    shutil.copytree(DATA, parameters)
    return parameters


def test_merge_keeps_every_other_field_and_its_text(capsys, tmp_path, team_parameters):
    path, joints, bottom, _ = offsets_file(tmp_path, robot=ROBOT)
    body_file, head_file = team_parameters / f"body.{BODY}.json", team_parameters / f"head.{HEAD}.json"
    body_before, head_before = body_file.read_text(), head_file.read_text()
    code, _, err = export(capsys, path, "--merge-from", team_parameters, "--out", team_parameters)
    assert code == 0, err

    body, old_body = json.loads(body_file.read_text()), json.loads(body_before)
    assert body["joint_calibration_offsets"]["left_arm"] == old_body["joint_calibration_offsets"]["left_arm"]
    assert {k: v for k, v in body.items() if k != "joint_calibration_offsets"} == \
        {k: v for k, v in old_body.items() if k != "joint_calibration_offsets"}
    assert body["joint_calibration_offsets"]["left_leg"]["hip_yaw_pitch"] == -joints["LHipYawPitch"]
    block = body_before[body_before.index('  "step_planner"'):]
    assert body_file.read_text().endswith(block)  # everything after the offsets, byte for byte

    head, old_head = json.loads(head_file.read_text()), json.loads(head_before)
    calibration, old_calibration = (h["camera_matrix_parameters"]["calibration"] for h in (head, old_head))
    assert calibration["correction_in_camera_top"] == old_calibration["correction_in_camera_top"]
    assert calibration["correction_in_robot"] == old_calibration["correction_in_robot"]
    assert head["camera_matrix_parameters"]["vision_bottom"] == old_head["camera_matrix_parameters"]["vision_bottom"]
    assert head["player_number"] == "One"
    assert naocal_camera_rpy(calibration["correction_in_camera_bottom"]) == pytest.approx(bottom, abs=1e-12)
    changed = [a for a, b in zip(head_before.splitlines(), head_file.read_text().splitlines()) if a != b]
    assert len(changed) == 3 and len(head_before.splitlines()) == len(head_file.read_text().splitlines())
    assert (team_parameters / f"head.{HEAD}.json.bak").read_text() == head_before


def test_merge_into_files_that_nest_everything_in_parameters(capsys, tmp_path, team_parameters):
    """HULKs' newer files (e.g. etc/parameters/go25/) wrap their values in a top-level "parameters" object."""
    path, joints, bottom, _ = offsets_file(tmp_path, robot=ROBOT)
    for name in (f"body.{BODY}.json", f"head.{HEAD}.json"):
        doc = json.loads((team_parameters / name).read_text())
        (team_parameters / name).write_text(json.dumps({"parameters": doc}, indent=2) + "\n")
    assert export(capsys, path, "--merge-from", team_parameters, "--out", team_parameters)[0] == 0
    body = json.loads((team_parameters / f"body.{BODY}.json").read_text())
    assert list(body) == ["parameters"] and "step_planner" in body["parameters"]
    assert body["parameters"]["joint_calibration_offsets"]["right_leg"]["hip_roll"] == -joints["RHipRoll"]
    head = json.loads((team_parameters / f"head.{HEAD}.json").read_text())
    correction = head["parameters"]["camera_matrix_parameters"]["calibration"]["correction_in_camera_bottom"]
    assert list(head) == ["parameters"] and naocal_camera_rpy(correction) == pytest.approx(bottom, abs=1e-12)


def test_merge_without_a_team_file_writes_a_sparse_one(capsys, tmp_path):
    path, *_ = offsets_file(tmp_path, robot=ROBOT)
    (tmp_path / "parameters").mkdir()
    code, _, err = export(capsys, path, "--merge-from", tmp_path / "parameters", "--out", tmp_path / "parameters")
    assert code == 0 and f"no body.{BODY}.json" in err
    assert list(json.loads((tmp_path / f"parameters/body.{BODY}.json").read_text())) == ["joint_calibration_offsets"]


def test_invalid_team_json_is_refused_and_nothing_written(capsys, tmp_path, team_parameters):
    path, *_ = offsets_file(tmp_path, robot=ROBOT)
    body_file = team_parameters / f"body.{BODY}.json"
    body_file.write_text(body_file.read_text().replace('"forward": 0.04,', '"forward": 0.04'))  # a lost comma
    before = {p.name: p.read_bytes() for p in team_parameters.iterdir()}
    code, _, err = export(capsys, path, "--merge-from", team_parameters, "--out", team_parameters)
    # line 17: where the next member starts, as json.loads says too
    assert code == 2 and err.count("\n") == 1 and f"body.{BODY}.json, line 17" in err, err
    assert {p.name: p.read_bytes() for p in team_parameters.iterdir()} == before


@pytest.mark.parametrize("option,value", [("--body-id", "../../etc/evil"), ("--head-id", "a/b"),
                                          ("--body-id", "x\ny")])
def test_ids_that_are_not_file_name_parts_are_refused(capsys, tmp_path, option, value):
    path, *_ = offsets_file(tmp_path, robot=ROBOT)
    code, _, err = export(capsys, path, "--out", tmp_path / "parameters", option, value)
    assert code == 2 and err.count("\n") == 1 and "not a valid id" in err
    assert not (tmp_path / "parameters").exists() and not (tmp_path / "etc").exists()
