"""The robot description (solver/robot.py, solver/data/nao.json): chains from any URDF base to any tip, cameras,
targets, and clear errors for a bad description."""

import json
import shutil

import numpy as np
import pytest

from naocal.solver.errors import DataError
from naocal.solver.kinematics import chain_frames
from naocal.solver.robot import load_robot, nao
from naocal.solver.transforms import make_transform, rot_axis_angle, rot_rpy
from naocal.solver.urdf import nominal_urdf


def walk(urdf, base, tip, angles):
    """T_base_tip by composing the URDF's joints from the tip up, one joint at a time (shares no chain code)."""
    by_child = {j.child: j for j in urdf.joints.values()}
    T = np.eye(4)
    link = tip
    while link != base:
        joint = by_child[link]
        R = rot_rpy(*joint.rpy)
        if joint.kind in ("revolute", "continuous"):
            R = R @ rot_axis_angle(np.asarray(joint.axis), angles[joint.name])
        T = make_transform(R, joint.xyz) @ T
        link = joint.parent
    return T


@pytest.mark.parametrize("tip", ["l_sole", "r_sole", "CameraBottom_frame", "CameraTop_frame", "l_gripper",
                                 "RHandTouchBack_frame", "Head", "torso"])
def test_any_serial_chain_matches_the_urdf(tip):
    robot = nao()
    chain = robot.chain(tip)
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, size=(5, len(chain.joint_names)))
    _, T = chain_frames(chain, q)
    for k in range(len(q)):
        expected = walk(robot.urdf, "torso", tip, dict(zip(chain.joint_names, q[k])))
        np.testing.assert_allclose(T[k], expected, atol=1e-12)


def test_chain_between_two_links_of_the_urdf():
    robot = nao()
    chain = robot.chain("l_gripper", base="LBicep")
    assert chain.joint_names == ("LElbowYaw", "LElbowRoll", "LWristYaw", "LHand")


def test_the_nao_description():
    robot = nao()
    assert len(robot.joints) == 14 and robot.joints[:2] == ("HeadYaw", "HeadPitch")
    assert robot.named_chain("left_leg").joint_names[0] == "LHipYawPitch"
    assert robot.camera_chain("bottom").joint_names == ("HeadYaw", "HeadPitch")
    assert robot.motor_partner("RHipYawPitch") == "LHipYawPitch" and robot.motor_partner("LHipYawPitch") is None
    bottom = robot.camera("bottom")
    assert (bottom.width_px, bottom.height_px, bottom.readout_s) == (640, 480, 0.045)
    assert robot.camera("top").readout_s == 0.037
    sandal = robot.target("L")
    assert sandal.frame == "l_sole" and sandal.board.n_vertices == 24 and sandal.board.mass_kg == 0.10
    V = sandal.vertices()
    np.testing.assert_allclose(V[0], [0.1075, -0.0375, 0.0])  # docs/CONVENTIONS.md
    np.testing.assert_allclose(V[5], [0.2325, -0.0375, 0.0])  # col along +x of the sole
    np.testing.assert_allclose(V[6], [0.1075, -0.0125, 0.0])  # row along +y
    floor = robot.target("floor")
    assert floor.load == "supporting" and floor.board.n_vertices == 9
    np.testing.assert_allclose(floor.vertices()[4], [0.6, 0.05, 0.0])
    assert robot.gravity_mps2 == (-9.81, 0.0, 0.0)
    assert robot.default_cameras == ("bottom",) and robot.default_targets == ("L", "R")


def test_unknown_names_are_refused_naming_the_file():
    robot = nao()
    with pytest.raises(DataError, match="unknown camera 'side'"):
        robot.camera("side")
    with pytest.raises(DataError, match="unknown target"):
        robot.target("hand")
    with pytest.raises(DataError, match="no chain from 'torso' to 'nowhere'"):
        robot.chain("nowhere")


def description(tmp_path, change):
    """A copy of the NAO's description (and its URDF) in tmp_path, changed by `change`."""
    source = nao().path
    doc = json.loads(source.read_text())
    change(doc)
    shutil.copy(source.with_name("nao_v50.urdf"), tmp_path / "nao_v50.urdf")
    path = tmp_path / "robot.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("change,field,problem", [
    (lambda d: d.update(schema="naocal.robot/9"), "schema", "wrong schema"),
    (lambda d: d["joints"].append("LFoot"), "joints[14]", "not a revolute joint"),
    (lambda d: d["cameras"]["bottom"].update(frame="Eye"), "cameras.bottom.frame", "no link 'Eye'"),
    (lambda d: d["cameras"]["bottom"].update(fx_px=-1), "cameras.bottom.fx_px", "must be positive"),
    (lambda d: d["targets"]["L"]["board"].update(columns=1), "targets.L.board", "at least 2 squares"),
    (lambda d: d["targets"]["L"].update(load="floating"), "targets.L.load", "expected one of"),
    (lambda d: d["targets"]["L"].update(colour="red"), "targets.L.colour", "unknown field"),
    (lambda d: d.update(shared_motors=[["LHipYawPitch", "Neck"]]), "shared_motors[0]", "two or more joints"),
    (lambda d: d.update(urdf="../../etc/passwd"), "urdf", "URDF file beside"),
    (lambda d: d.update(default_targets=["Q"]), "default_targets", "'Q' is not defined"),
])
def test_bad_description_names_the_field(tmp_path, change, field, problem):
    with pytest.raises(DataError) as info:
        load_robot(description(tmp_path, change))
    assert info.value.field == field, str(info.value)
    assert problem in str(info.value) and "robot.json" in str(info.value)


def test_a_description_with_another_base_and_chains(tmp_path):
    """Any serial chain of the URDF: an arm from the torso to the gripper, with a camera on the head."""
    def arm(doc):
        doc["joints"] = ["HeadYaw", "HeadPitch", "LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll",
                         "LWristYaw"]
        doc["shared_motors"] = []
        doc["chains"] = {"arm": {"base": "torso", "tip": "l_wrist"}}
        doc["link_lengths"] = {"forearm": "LWristYaw"}
        doc["targets"] = {"hand": {"frame": "l_wrist", "board": {"columns": 3, "rows": 3, "square_m": 0.01},
                                   "pose": {"xyz": [0.05, 0, 0], "rpy": [0, 0, 0]}}}
        doc["default_targets"] = ["hand"]
    robot = load_robot(description(tmp_path, arm))
    assert robot.target_chain("hand").joint_names == ("LShoulderPitch", "LShoulderRoll", "LElbowYaw",
                                                       "LElbowRoll", "LWristYaw")
    assert robot.target("hand").board.n_vertices == 4
    assert nominal_urdf().joints["LWristYaw"].parent == "LForeArm"


def test_one_intrinsics_type_for_the_description_and_the_backends():
    """The robot description's cameras and what backends report are one type (solver.camera.CameraIntrinsics)."""
    from naocal.backends.base import CameraIntrinsics as reported
    from naocal.solver.camera import CameraIntrinsics

    assert reported is CameraIntrinsics
    top = nao().camera("top")
    assert isinstance(top, CameraIntrinsics) and (top.name, top.frame) == ("top", "CameraTop_frame")
    assert top.intrinsics() == {"width_px": 640, "height_px": 480, "fx_px": 600.0, "fy_px": 600.0, "cx_px": 320.0,
                                "cy_px": 240.0, "distortion": [0.0] * 5}
    assert top.to_dict() == {"name": "top", **top.intrinsics()}
    assert CameraIntrinsics(640, 480, 600.0, 600.0, 320.0, 240.0).to_dict()["name"] == "bottom"
