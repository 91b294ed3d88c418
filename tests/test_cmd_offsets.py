"""`naocal offsets show|diff|validate|export|apply`, driven through tools.cli.main and (for exit codes) a subprocess.

The URDF export is checked three ways: the XML's tags, PyBullet's link poses against a chain built here from the
exported XML, and against naocal's own kinematic model with the same alphas (the compensated model).
"""

import importlib.util
import json
import math
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import naocal.tools.cli  # noqa

from naocal import tools
from naocal.solver.joints import HEAD_JOINTS, JOINTS, LEG_JOINTS, leg_joints
from naocal.solver.offsets import read_offsets, write_offsets
from tests.test_offsets import make_offsets
from tests.cfg_reader import parse_cfg
from naocal.tools.export.bhuman import joint_keys
from naocal.tools.export.urdf import export_urdf

ROOT = tools.cli.__file__.rsplit("/tools/", 1)[0]
ALL_VERB_MODULES = tools.cli.VERB_MODULES


@pytest.fixture(autouse=True)
def only_existing_verbs(monkeypatch):
    """Other verbs are written in parallel: build the CLI from the verb modules that exist now."""
    present = tuple(m for m in tools.cli.VERB_MODULES if importlib.util.find_spec(m) is not None)
    monkeypatch.setattr(tools.cli, "VERB_MODULES", present)


def naocal(capsys, *argv):
    code = tools.cli.main(["offsets", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, out, err, *fragments):
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in err, err


@pytest.fixture
def offsets_file(tmp_path):
    path = tmp_path / "nao-17.json"
    write_offsets(make_offsets(head=True), path)
    return path


def damage(path, change):
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    return path


# ------------------------------------------------------------------------------------------- show / validate


def test_show_prints_every_section(capsys, offsets_file):
    offsets = read_offsets(offsets_file)
    code, out, _ = naocal(capsys, "show", offsets_file)
    assert code == 0
    c_deg = math.degrees(offsets.joint_offsets_rad["LKneePitch"])
    line = next(line for line in out.splitlines() if line.strip().startswith("LKneePitch"))
    assert f"{c_deg:.4f}" in line and f"{math.degrees(1e-3):.4f}" in line  # value and std in degrees
    roll_deg = math.degrees(offsets.camera_rpy()[0])
    assert any(line.strip().startswith("roll") and f"{roll_deg:.4f}" in line for line in out.splitlines())
    trans_x_mm = offsets.board_mount["L"]["trans_x_m"] * 1000
    assert f"{trans_x_mm:.4f}" in out
    for text in ("HeadYaw", "RAnkleRoll", "elasticity.LHipPitch", "deg/(N m)", "time_lag.dt", "ms",
                 "model effects: joint_offsets, camera_rotation, board_mount, elasticity",
                 "rms 0.310 px (x), 0.270 px (y) over 3456 vertices in 144 images", "dataset: runs/nao-17",
                 "id nao-17, body AL-B-17, head AL-H-04"):
        assert text in out, text


def test_validate_ok(capsys, offsets_file):
    assert naocal(capsys, "validate", offsets_file)[:2] == (0, "ok\n")


DAMAGES = {
    "nan": lambda d: d["body"]["joint_offsets_rad"].update(LHipPitch=float("nan")),
    "wrong schema": lambda d: d.update(schema="naocal.offsets/0"),
    "unknown joint": lambda d: d["body"]["joint_offsets_rad"].update(LHipPtch=0.01),
    "wrong units": lambda d: d["model"]["parameters"]["camera.bottom.pitch"].update(unit="deg"),
    "degrees as radians": lambda d: d["head"]["camera_rotation_rad"]["bottom"].update(pitch=-4.0),
}


@pytest.mark.parametrize("damage_name", DAMAGES)
@pytest.mark.parametrize("verb", ["validate", "show", "export", "apply", "diff"])
def test_damaged_files_are_refused_with_one_line(capsys, offsets_file, damage_name, verb):
    damage(offsets_file, DAMAGES[damage_name])
    extra = {"validate": [], "show": [], "export": ["--format", "json"], "apply": ["--command", "LHipPitch=1"],
             "diff": [offsets_file]}[verb]
    code, out, err = naocal(capsys, verb, offsets_file, *extra)
    assert_one_line_error(code, out, err, str(offsets_file))


def test_truncated_file_is_refused(capsys, offsets_file):
    offsets_file.write_text(offsets_file.read_text()[:300])
    assert_one_line_error(*naocal(capsys, "validate", offsets_file), "truncated JSON")


def test_missing_file_is_refused(capsys, tmp_path):
    assert_one_line_error(*naocal(capsys, "show", tmp_path / "absent.json"), "file not found")


def test_exit_codes_through_a_real_process(tmp_path, offsets_file):
    command = [sys.executable, "-m", "naocal"]
    if any(importlib.util.find_spec(m) is None for m in ALL_VERB_MODULES):  # other verbs not written yet
        command = [sys.executable, "-c", "import sys, naocal.tools.cli as c; c.VERB_MODULES = ('naocal.tools.cmd_offsets',); "
                                         "sys.exit(c.main())"]
    run = lambda *argv: subprocess.run([*command, "offsets", *map(str, argv)],  # noqa: E731
                                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    ok = run("validate", offsets_file)
    assert (ok.returncode, ok.stdout) == (0, "ok\n")
    damage(offsets_file, DAMAGES["nan"])
    bad = run("validate", offsets_file)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "Traceback" not in bad.stderr
    assert "joint_offsets_rad.LHipPitch" in bad.stderr


# ------------------------------------------------------------------------------------------------- diff


def test_diff_marks_only_differences_beyond_the_combined_uncertainty(capsys, tmp_path, offsets_file):
    other = read_offsets(offsets_file)
    sigma = math.hypot(1e-3, 1e-3)  # both files: std 1e-3 rad on every leg joint offset
    for joint, change in (("LHipRoll", 3 * sigma), ("RHipPitch", 0.5 * sigma)):  # both copies of the value
        other.joint_offsets_rad[joint] += change
        other.model["parameters"][f"joint_offset.{joint}"]["value"] += change
    other.robot["head_id"] = "AL-H-09"
    write_offsets(other, tmp_path / "other.json")
    code, out, _ = naocal(capsys, "diff", offsets_file, tmp_path / "other.json")
    assert code == 0
    lines = {line.split()[0] + " " + line.split()[1]: line for line in out.splitlines() if line.startswith("  c ")}
    assert lines["c LHipRoll"].endswith("*")
    assert f"{math.degrees(3 * sigma):.4f}" in lines["c LHipRoll"]
    assert not lines["c RHipPitch"].endswith("*")
    assert not lines["c LKneePitch"].endswith("*")
    assert "1 of" in out and "head_id differs" in out
    code, _, _ = naocal(capsys, "diff", offsets_file, tmp_path / "other.json", "--fail-on-difference")
    assert code == 1
    assert naocal(capsys, "diff", offsets_file, offsets_file, "--fail-on-difference")[0] == 0


# ----------------------------------------------------------------------------------------------- export


def test_export_json_round_trips(capsys, tmp_path, offsets_file):
    code, out, _ = naocal(capsys, "export", offsets_file, "--format", "json")
    assert code == 0
    (tmp_path / "stdout.json").write_text(out)
    assert read_offsets(tmp_path / "stdout.json") == read_offsets(offsets_file)
    assert naocal(capsys, "export", offsets_file, "--format", "json", "--out", tmp_path / "copy.json")[0] == 0
    assert read_offsets(tmp_path / "copy.json") == read_offsets(offsets_file)


def deg(literal: str) -> float:
    assert literal.endswith("deg"), literal
    return float(literal[:-3])


def test_export_bhuman_parses_back_to_the_same_numbers(capsys, tmp_path, offsets_file):
    offsets = read_offsets(offsets_file)
    code, _, _ = naocal(capsys, "export", offsets_file, "--format", "bhuman", "--out", tmp_path / "bh")
    assert code == 0
    joints = parse_cfg((tmp_path / "bh/Robots/AL-B-17/Body/jointCalibration.cfg").read_text())
    assert list(joints) == ["offsets"] and tuple(joints["offsets"]) == joint_keys(2025)
    for key, literal in joints["offsets"].items():
        joint = key[0].upper() + key[1:]
        expected = math.degrees(offsets.joint_offsets_rad.get(joint, 0.0))  # same sign: added to requests
        assert deg(literal) == pytest.approx(expected, abs=5e-7), key
    assert deg(joints["offsets"]["lHipPitch"]) != 0 and deg(joints["offsets"]["headYaw"]) != 0

    camera = parse_cfg((tmp_path / "bh/Robots/AL-H-04/AL-B-17/cameraCalibration.cfg").read_text())
    roll, pitch, yaw = offsets.camera_rpy("bottom")
    lower = camera["cameraRotationCorrections"]["lower"]
    assert [deg(lower[k]) for k in "xyz"] == pytest.approx([math.degrees(a) for a in (roll, pitch, yaw)], abs=5e-7)
    assert {k: deg(v) for k, v in camera["cameraRotationCorrections"]["upper"].items()} == {"x": 0, "y": 0, "z": 0}
    assert set(camera["bodyRotationCorrection"]) == {"x", "y"}

    code, out, _ = naocal(capsys, "export", offsets_file, "--format", "bhuman")  # both files on stdout
    assert code == 0 and "offsets = {" in out and "cameraRotationCorrections = {" in out


def test_failed_export_overwrites_nothing(capsys, tmp_path, offsets_file):
    target = tmp_path / "robot.urdf"
    target.write_text("previous export")
    damage(offsets_file, DAMAGES["unknown joint"])
    assert_one_line_error(*naocal(capsys, "export", offsets_file, "--format", "urdf", "--out", target))
    assert target.read_text() == "previous export"
    good = tmp_path / "good.json"
    write_offsets(make_offsets(), good)
    code, out, err = naocal(capsys, "export", good, "--format", "bhuman", "--out", target)  # a file, not a dir
    assert_one_line_error(code, out, err, "directory")
    assert target.read_text() == "previous export"
    code, out, err = naocal(capsys, "export", good, "--format", "urdf", "--out", target,
                            "--nominal-urdf", tmp_path / "missing.urdf")
    assert_one_line_error(code, out, err, "nominal URDF not found")
    assert target.read_text() == "previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.json", "nao-17.json", "robot.urdf"]


# ------------------------------------------------------------------------------------------------- URDF


def rot(axis, angle):
    """Rotation about a unit axis (Rodrigues), written out here independently of solver.transforms."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rpy_matrix(r, p, y):
    return rot((0, 0, 1), y) @ rot((0, 1, 0), p) @ rot((1, 0, 0), r)


def pose(R, t=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


class XmlChain:
    """Forward kinematics straight from a URDF's XML: enough to check PyBullet and the export."""

    def __init__(self, text):
        self.joints = {}
        for joint in ET.fromstring(text).findall("joint"):
            origin, axis = joint.find("origin"), joint.find("axis")
            floats = lambda s: [float(v) for v in s.split()]  # noqa: E731
            self.joints[joint.find("child").get("link")] = {
                "name": joint.get("name"), "parent": joint.find("parent").get("link"),
                "T": pose(rpy_matrix(*floats(origin.get("rpy"))), floats(origin.get("xyz"))),
                "axis": floats(axis.get("xyz")) if axis is not None else [0, 0, 0],
                "revolute": joint.get("type") == "revolute",
                "rising": float(joint.find("calibration").get("rising")) if joint.find("calibration") is not None
                else None,
            }

    def joint(self, name):
        return next(j for j in self.joints.values() if j["name"] == name)

    def pose(self, link, positions, base="torso"):
        T = np.eye(4)
        while link != base:
            joint = self.joints[link]
            motion = pose(rot(joint["axis"], positions.get(joint["name"], 0.0))) if joint["revolute"] else np.eye(4)
            T = joint["T"] @ motion @ T
            link = joint["parent"]
        return T


@pytest.fixture(scope="module")
def calibrated():
    offsets = make_offsets(seed=3, head=True)
    text = export_urdf(offsets, strip_meshes=True)
    return offsets, text


def test_urdf_tags_and_camera_rotation(calibrated):
    offsets, text = calibrated
    root = ET.fromstring(text)
    joints = {j.get("name"): j for j in root.findall("joint")}
    for joint in LEG_JOINTS + HEAD_JOINTS:
        calibration = joints[joint].findall("calibration")
        assert len(calibration) == 1 and float(calibration[0].get("rising")) == offsets.joint_offsets_rad[joint]
    assert joints["LShoulderPitch"].find("calibration") is None
    mimic = joints["RHipYawPitch"].find("mimic")
    assert float(mimic.get("offset")) == offsets.joint_offset("LHipYawPitch") - offsets.joint_offset("RHipYawPitch")

    roll, pitch, yaw = offsets.camera_rpy()
    origin = joints["CameraBottom_sensor_fixedjoint"].find("origin")
    R_expected = rpy_matrix(0, 0.692896, 0) @ rot((0, 1, 0), pitch) @ rot((1, 0, 0), roll) @ rot((0, 0, 1), yaw)
    assert rpy_matrix(*map(float, origin.get("rpy").split())) == pytest.approx(R_expected, abs=1e-12)
    assert origin.get("xyz") == "0.05071 0 0.01774"
    assert joints["CameraTop_sensor_fixedjoint"].find("origin").get("rpy") == "0 0.0209435 0"
    assert root.find(".//mesh") is None  # stripped for PyBullet
    assert "<mesh" in export_urdf(offsets)  # kept by default


def test_urdf_export_loads_in_pybullet_and_matches_the_compensated_model(calibrated, tmp_path):
    """What "the URDF's forward kinematics equals the compensated model" means here.

    naocal's model: a joint whose encoder reads theta is truly at q = theta + alpha, and the bottom camera sits at
    T_torso_cam(q_head) @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw). The file stores c = -alpha. A driver using the
    calibrated URDF publishes corrected readings theta - c (= theta + alpha = q) and evaluates the URDF there; the
    URDF's camera joint carries the rotation correction. So for any encoder readings theta, the exported URDF at
    theta - rising must put soles and camera where the model with those alphas puts them at theta.
    (Equivalently, commanding requested + c makes the encoder read theta = requested + c, so the robot is truly at
    q = requested: the compensated robot follows the nominal kinematics of the requested angles.)
    Checked three ways: PyBullet vs. a chain built here from the exported XML vs. solver.kinematics with alphas.
    """
    pybullet = pytest.importorskip("pybullet")
    offsets, text = calibrated
    path = tmp_path / "calibrated.urdf"
    path.write_text(text)
    chain = XmlChain(text)
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(path), physicsClientId=client)
        joint_index, link_index = {}, {}
        for i in range(pybullet.getNumJoints(body, physicsClientId=client)):
            info = pybullet.getJointInfo(body, i, physicsClientId=client)
            joint_index[info[1].decode()] = i
            link_index[info[12].decode()] = i

        def bullet_pose(link):
            state = pybullet.getLinkState(body, link_index[link], computeForwardKinematics=True,
                                          physicsClientId=client)
            R = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            return pose(R, state[4])

        rng = np.random.default_rng(7)
        limits = {name: (0.8 * lo, 0.8 * hi) for name, lo, hi in _limits(text)}
        for _ in range(20):
            theta = {j: rng.uniform(*limits[j]) for j in JOINTS}  # encoder readings
            theta["RHipYawPitch"] = theta["LHipYawPitch"]  # one motor, one reading
            corrected = {j: theta[j] - chain.joint(j)["rising"] for j in JOINTS}
            mimic = float(ET.fromstring(text).find("joint[@name='RHipYawPitch']/mimic").get("offset"))
            assert corrected["RHipYawPitch"] == pytest.approx(corrected["LHipYawPitch"] + mimic, abs=1e-15)
            for joint, value in corrected.items():
                pybullet.resetJointState(body, joint_index[joint], value, physicsClientId=client)
            T_world_torso = bullet_pose("torso")
            for link in ("l_sole", "r_sole", "CameraBottom_frame"):
                T_bullet = np.linalg.inv(T_world_torso) @ bullet_pose(link)
                T_xml = chain.pose(link, corrected)
                assert T_bullet == pytest.approx(T_xml, abs=1e-6)  # PyBullet computes in single precision
                assert T_xml == pytest.approx(model_pose(link, theta, offsets), abs=1e-12)
    finally:
        pybullet.disconnect(client)


def _limits(text):
    for joint in ET.fromstring(text).findall("joint"):
        limit = joint.find("limit")
        if joint.get("name") in JOINTS and limit is not None:
            yield joint.get("name"), float(limit.get("lower")), float(limit.get("upper"))


def model_pose(link, theta, offsets):
    """naocal's model at encoder readings theta with the file's alphas (alpha = -c), T_torso_<link>."""
    from naocal.solver.kinematics import camera_fk, leg_fk

    alpha = {j: -offsets.joint_offset(j) for j in JOINTS}
    if link in ("l_sole", "r_sole"):
        leg = link[0].upper()
        q = np.array([[theta[j] + alpha[j] for j in leg_joints(leg)]])
        return leg_fk(q, leg)[0]
    roll, pitch, yaw = offsets.camera_rpy()
    q_head = np.array([[theta[j] + alpha[j] for j in HEAD_JOINTS]])
    return camera_fk(q_head)[0] @ pose(rot((0, 1, 0), pitch) @ rot((1, 0, 0), roll) @ rot((0, 0, 1), yaw))


# ------------------------------------------------------------------------------------------------ apply


def test_apply_command_and_reading(capsys, offsets_file):
    offsets = read_offsets(offsets_file)
    c_deg = math.degrees(offsets.joint_offsets_rad["LHipPitch"])
    code, out, _ = naocal(capsys, "apply", offsets_file, "--command", "LHipPitch=-20", "LShoulderPitch=5")
    assert code == 0
    values = dict(line.split("=") for line in out.split())
    assert float(values["LHipPitch"]) == pytest.approx(-20 + c_deg, abs=1e-8)
    assert float(values["LShoulderPitch"]) == 5.0
    code, out, _ = naocal(capsys, "apply", offsets_file, "--reading", "LHipPitch=-20")
    assert float(out.split("=")[1]) == pytest.approx(-20 - c_deg, abs=1e-8)
    code, out, _ = naocal(capsys, "apply", offsets_file, "--reading", "--rad", "LHipPitch=0.5")
    assert float(out.split("=")[1]) == pytest.approx(0.5 - offsets.joint_offsets_rad["LHipPitch"], abs=1e-10)


@pytest.mark.parametrize("assignment,problem", [
    ("LHipPtch=3", "unknown joint"), ("LHipPitch=abc", "not a number"), ("LHipPitch", "JOINT=ANGLE"),
    ("LHipPitch=nan", "non-finite"),
])
def test_apply_bad_arguments(capsys, offsets_file, assignment, problem):
    assert_one_line_error(*naocal(capsys, "apply", offsets_file, "--command", assignment), problem)


def test_help_documents_the_verbs(capsys):
    with pytest.raises(SystemExit) as info:
        tools.cli.main(["offsets", "--help"])
    out = capsys.readouterr().out
    assert info.value.code == 0
    for text in ("show", "diff", "validate", "export", "apply", "--command|--reading",
                 "arm:\n  naocal.arm_calibration/1", "duckiebot:\n  naocal.duckiebot_calibration/1",
                 "Duckietown calibrations DIR"):  # each kind's own paragraph (offsets_help)
        assert text in out, text
    with pytest.raises(SystemExit):
        tools.cli.main(["offsets", "export", "--help"])
    out = capsys.readouterr().out
    for text in ("x = roll", "calibration rising", "hulks", "naodevils", "--merge-from", "--bhuman-release",
                 "--head-id", "waistYaw", "correction_in_camera_bottom", "docs/EXPORTS.md"):
        assert text in out, text


def test_diff_of_files_with_different_parameters_lists_them_instead_of_failing(capsys, tmp_path, offsets_file):
    """A file without the boards' mounts (found by the fuzz harness: a KeyError traceback when A had them)."""
    import json

    doc = json.loads(offsets_file.read_text())
    doc["targets"].pop("board_mount")
    for name in [n for n in doc["model"]["parameters"] if n.startswith("board.")]:  # in neither copy
        del doc["model"]["parameters"][name]
    (tmp_path / "fewer.json").write_text(json.dumps(doc))
    for a, b, where in ((offsets_file, tmp_path / "fewer.json", "(only in A)"),
                        (tmp_path / "fewer.json", offsets_file, "(only in B)")):
        code, out, err = naocal(capsys, "diff", a, b)
        assert code == 0 and "Traceback" not in err, err
        assert any(line.startswith("  board.L.rot_z") and line.endswith(where) for line in out.splitlines()), out
