"""Forward kinematics and gravity torques against independent computations.

The nominal model is the project's own copy of the ros-naoqi URDF (solver/data/nao_v50.urdf, licence beside it).
Two independent checks: `XmlChain` walks that file's raw XML with scipy rotations (no code shared with solver/),
and the file itself is checked against numbers typed from Aldebaran's documentation of the NAO H25 V5.
"""

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import ROOT
from naocal.solver import kinematics
from naocal.solver.joints import HEAD_JOINTS, leg_joints
from naocal.solver.nao_model import SANDAL_MASS_KG, board_vertices_sole, leg_chain
from naocal.solver.urdf import nominal_urdf

URDF = ROOT / "solver" / "data" / "nao_v50.urdf"

# Typed from Aldebaran's NAO H25 V5 documentation (doc.aldebaran.com/2-1/family/nao_h25/links_h25.html,
# masses_h25.html, and family/robots/video_robot.html), metres, kg, rad:
NECK_OFFSET_Z = 0.1265
HIP_OFFSET_Y, HIP_OFFSET_Z = 0.050, 0.085
THIGH_LENGTH, TIBIA_LENGTH = 0.100, 0.1029
FOOT_HEIGHT = 0.04511  # the URDF's; the links page says 0.04519
CAMERA_BOTTOM_XYZ, CAMERA_BOTTOM_PITCH = (0.05071, 0.0, 0.01774), np.radians(39.7)  # in the head frame
CAMERA_TOP_XYZ, CAMERA_TOP_PITCH = (0.05871, 0.0, 0.06364), np.radians(1.2)
LEG_MASSES = {"Pelvis": 0.06981, "Hip": 0.14053, "Thigh": 0.38968, "Tibia": 0.30142, "AnklePitch": 0.13416,
              "ankle": 0.17184}
TOTAL_MASS = 5.305


class XmlChain:
    """A chain walked from the raw URDF XML with scipy rotations: shares no code with solver/."""

    def __init__(self, path):
        root = ET.parse(path).getroot()
        self.by_child = {}
        for joint in root.findall("joint"):
            origin = joint.find("origin")
            axis = joint.find("axis")
            self.by_child[joint.find("child").get("link")] = {
                "name": joint.get("name"),
                "type": joint.get("type"),
                "parent": joint.find("parent").get("link"),
                "xyz": np.array([float(v) for v in origin.get("xyz").split()]),
                "rpy": [float(v) for v in origin.get("rpy").split()],
                "axis": np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else None,
            }

    def pose(self, link, angles):
        """(R, t) of `link` in the torso frame, with joint angles from the dict `angles`."""
        R, t = np.eye(3), np.zeros(3)
        while link != "torso":
            joint = self.by_child[link]
            R_origin = Rotation.from_euler("xyz", joint["rpy"]).as_matrix()  # extrinsic x, y, z = URDF rpy
            R_joint = np.eye(3)
            if joint["type"] == "revolute":
                axis = joint["axis"] / np.linalg.norm(joint["axis"])
                R_joint = Rotation.from_rotvec(axis * angles[joint["name"]]).as_matrix()
            # pose_parent_child = (R_origin R_joint, xyz); compose on the left of what we have.
            R, t = R_origin @ R_joint @ R, R_origin @ R_joint @ t + joint["xyz"]
            link = joint["parent"]
        return R, t


def random_angles(rng, names, n):
    urdf = nominal_urdf()
    lower = np.array([urdf.joints[j].lower for j in names])
    upper = np.array([urdf.joints[j].upper for j in names])
    return rng.uniform(lower, upper, size=(n, len(names)))


@pytest.fixture(scope="module")
def xml_chain():
    return XmlChain(URDF)


@pytest.mark.parametrize("leg,sole", [("L", "l_sole"), ("R", "r_sole")])
def test_leg_fk_matches_independent_chain(xml_chain, leg, sole):
    rng = np.random.default_rng(0)
    names = leg_joints(leg)
    q = random_angles(rng, names, 1000)
    T = kinematics.leg_fk(q, leg)
    worst_t = worst_R = 0.0
    for i in range(len(q)):
        R, t = xml_chain.pose(sole, dict(zip(names, q[i])))
        worst_t = max(worst_t, np.abs(T[i, :3, 3] - t).max())
        worst_R = max(worst_R, np.linalg.norm(Rotation.from_matrix(T[i, :3, :3] @ R.T).as_rotvec()))
    assert worst_t < 1e-9 and worst_R < 1e-9


@pytest.mark.parametrize("camera,link", [("bottom", "CameraBottom_frame"), ("top", "CameraTop_frame")])
def test_camera_fk_matches_independent_chain(xml_chain, camera, link):
    rng = np.random.default_rng(1)
    q = random_angles(rng, HEAD_JOINTS, 1000)
    T = kinematics.camera_fk(q, camera)
    for i in range(len(q)):
        R, t = xml_chain.pose(link, dict(zip(HEAD_JOINTS, q[i])))
        assert np.abs(T[i, :3, 3] - t).max() < 1e-9
        assert np.linalg.norm(Rotation.from_matrix(T[i, :3, :3] @ R.T).as_rotvec()) < 1e-9


def test_zero_pose_geometry_matches_documented_dimensions():
    T = kinematics.leg_fk(np.zeros((1, 6)), "L")[0]
    # HipOffsetY 0.050, HipOffsetZ 0.085, Thigh 0.100, Tibia 0.1029, FootHeight 0.04511 (URDF value).
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.050, -(0.085 + 0.100 + 0.1029 + 0.04511)], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-12)


def test_link_length_corrections_lengthen_the_straight_leg():
    q = np.zeros((1, 6))
    base = kinematics.leg_fk(q, "R")[0, 2, 3]
    longer = kinematics.leg_fk(q, "R", thigh_delta_m=0.002, tibia_delta_m=-0.001)[0, 2, 3]
    assert longer - base == pytest.approx(-0.001, abs=1e-12)


def potential_energy(q_leg, leg, g):
    """U = -sum m g . p over the leg's links and the sandal."""
    chain = leg_chain(leg)
    frames, T_sole = kinematics.chain_frames(chain, q_leg[None])
    U = 0.0
    for k in range(6):
        com = frames[0, k, :3, :3] @ chain.link_com[k] + frames[0, k, :3, 3]
        U -= chain.link_mass[k] * g @ com
    sandal = T_sole[0, :3, :3] @ np.array([0.17, 0, 0]) + T_sole[0, :3, 3]
    return U - SANDAL_MASS_KG * g @ sandal


@pytest.mark.parametrize("leg", ["L", "R"])
def test_gravity_torque_is_minus_gradient_of_potential(leg):
    rng = np.random.default_rng(2)
    g = np.array([-9.81, 0.3, -0.5])
    q = random_angles(rng, leg_joints(leg), 20)
    tau = kinematics.gravity_torques(q, leg, g)
    h = 1e-6
    for i in range(len(q)):
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            grad = (potential_energy(q[i] + dq, leg, g) - potential_energy(q[i] - dq, leg, g)) / (2 * h)
            assert tau[i, j] == pytest.approx(-grad, abs=1e-8)


@pytest.mark.parametrize("leg", ["L", "R"])
def test_gravity_torque_jacobian_matches_finite_differences(leg):
    """d tau / d q drives the implicit elasticity model (q = q0 + C tau(q)); it must be exact."""
    rng = np.random.default_rng(3)
    g = np.array([-9.81, 0.3, -0.5])
    q = random_angles(rng, leg_joints(leg), 20)
    tau, dtau = kinematics.gravity_torques(q, leg, g, jacobian=True)
    assert np.allclose(tau, kinematics.gravity_torques(q, leg, g))
    h = 1e-6
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        fd = (kinematics.gravity_torques(q + dq, leg, g) - kinematics.gravity_torques(q - dq, leg, g)) / (2 * h)
        assert np.abs(dtau[:, :, i] - fd).max() < 1e-7, i
    assert np.abs(dtau).max() > 0.1  # the test has something to check


def test_board_vertices_span_documented_area():
    v = board_vertices_sole()
    assert v.shape == (24, 3)
    np.testing.assert_allclose([v[:, 0].min(), v[:, 0].max()], [0.1075, 0.2325])
    np.testing.assert_allclose([v[:, 1].min(), v[:, 1].max()], [-0.0375, 0.0375])
    np.testing.assert_allclose(v[0], [0.1075, -0.0375, 0.0])
    np.testing.assert_allclose(v[1], [0.1325, -0.0375, 0.0])


def test_projection_of_sole_points_equals_the_models_prediction():
    """The planner's and the agent's projection (no distortion) is the identification model's at zero offsets."""
    from naocal.solver.joints import HEAD_COLUMNS, LEG_COLUMNS
    from naocal.solver.model import Model
    from naocal.solver.registry import Registry
    from naocal.sim.synthetic import DEFAULT_INTRINSICS, make_model_data, random_plan

    rng = np.random.default_rng(5)
    theta, leg, stance, posture = random_plan(rng, 4, 2)
    data = make_model_data(theta, leg, stance, posture)
    predicted = Model(data, Registry()).residuals(Registry().zeros()) + data.uv_px  # detections are zero
    for m in range(len(theta)):
        T_cam = kinematics.camera_fk(theta[m:m + 1, HEAD_COLUMNS])
        T_sole = kinematics.leg_fk(theta[m:m + 1, LEG_COLUMNS[leg[m]]], leg[m])
        uv, depth = kinematics.project_sole_points(T_cam, T_sole, board_vertices_sole(), DEFAULT_INTRINSICS)
        assert np.all(depth > 0)
        assert np.abs(uv[0] - predicted[data.image_of_row == m]).max() < 1e-9


def test_the_urdf_holds_the_documented_geometry_and_masses(xml_chain):
    zero = {j: 0.0 for j in (*HEAD_JOINTS, *leg_joints("L"), *leg_joints("R"))}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        R, t = xml_chain.pose(f"{side}_sole", zero)
        np.testing.assert_allclose(t, [0.0, sign * HIP_OFFSET_Y,
                                       -(HIP_OFFSET_Z + THIGH_LENGTH + TIBIA_LENGTH + FOOT_HEIGHT)], atol=1e-9)
        np.testing.assert_allclose(R, np.eye(3), atol=1e-9)
    for link, xyz, pitch in (("CameraBottom_frame", CAMERA_BOTTOM_XYZ, CAMERA_BOTTOM_PITCH),
                             ("CameraTop_frame", CAMERA_TOP_XYZ, CAMERA_TOP_PITCH)):
        R, t = xml_chain.pose(link, zero)
        np.testing.assert_allclose(t, np.add(xyz, [0.0, 0.0, NECK_OFFSET_Z]), atol=1e-9)
        np.testing.assert_allclose(Rotation.from_matrix(R).as_rotvec(), [0.0, pitch, 0.0], atol=1e-3)
    axes = {joint["name"]: joint["axis"] for joint in xml_chain.by_child.values()}
    np.testing.assert_allclose(axes["LHipYawPitch"], [0.0, 0.7071, -0.7071], atol=1e-4)
    np.testing.assert_allclose(axes["RHipYawPitch"], [0.0, 0.7071, 0.7071], atol=1e-4)
    root = ET.parse(URDF).getroot()
    masses = {link.get("name"): float(link.find("inertial/mass").get("value"))
              for link in root.findall("link") if link.find("inertial/mass") is not None}
    for side, sole in (("L", "l"), ("R", "r")):
        for part, mass in LEG_MASSES.items():
            name = f"{sole}_ankle" if part == "ankle" else f"{side}{part}"
            assert masses[name] == pytest.approx(mass, abs=1e-5), name
    assert sum(masses.values()) == pytest.approx(TOTAL_MASS, abs=1e-3)


def test_elementary_rotations_and_their_derivatives():
    """rot_x, rot_y, rot_z: right-handed rotations of any shape of angles; d_rot_*: their exact derivatives."""
    from naocal.solver.transforms import d_rot_x, d_rot_y, d_rot_z, rot_axis_angle, rot_x, rot_y, rot_z

    angles = np.random.default_rng(2).uniform(-3.0, 3.0, (4, 5))
    for axis, rot, d_rot in ((0, rot_x, d_rot_x), (1, rot_y, d_rot_y), (2, rot_z, d_rot_z)):
        R = rot(angles)
        assert R.shape == (4, 5, 3, 3) and rot(0.3).shape == (3, 3)
        np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-15)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
        unit = np.eye(3)[axis]
        np.testing.assert_allclose(R[1, 2], _rodrigues(unit, angles[1, 2]), atol=1e-15)
        h = 1e-6
        np.testing.assert_allclose(d_rot(angles), (rot(angles + h) - rot(angles - h)) / (2 * h), atol=1e-9)
        np.testing.assert_allclose(rot_axis_angle(unit, angles), R, atol=1e-15)


def _rodrigues(axis, angle):
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
