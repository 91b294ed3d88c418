"""The NAO as a PyBullet multibody of primitive shapes, lying on its back, and a collision checker.

The body is generated as a URDF string from the nominal URDF's joint origins, axes, masses and centres of mass
(solver/data/nao_v50.urdf), optionally perturbed: thigh/tibia lengths per leg and the sandals' mounting errors.
Its links carry capsules, boxes and a sphere sized like the NAO's parts (the URDF's meshes are not available).

World frame: z up, the ground plane is z = 0. The torso lies on its back: torso +x points up (world +z), torso +z
(towards the head) is world +x, so gravity in the torso frame is (-9.81, 0, 0) m/s^2.

Each `NaoBody` owns its own PyBullet DIRECT client, so several bodies (a mock's true robot, a planner's nominal one)
live side by side in one process.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from naocal.body.pybullet_quiet import pybullet
from naocal.solver.joints import HEAD_JOINTS, JOINTS, LEGS, leg_joints
from naocal.solver.nao_model import BOARD_CENTER_X_M, BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M, SANDAL_MASS_KG, SOLE_JOINTS
from naocal.solver.transforms import make_transform, rot_z, rpy_from_rot
from naocal.solver.urdf import Urdf, nominal_urdf

# --- Placement -------------------------------------------------------------------------------------------------
R_WORLD_TORSO = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])  # torso x -> up, torso z -> world x
TORSO_BACK_X_M = -0.060  # the torso's back (battery) in the torso frame: it rests on the ground
T_WORLD_TORSO = make_transform(R_WORLD_TORSO, [0.0, 0.0, -TORSO_BACK_X_M])
GRAVITY_TORSO_MPS2 = R_WORLD_TORSO.T @ np.array([0.0, 0.0, -9.81])  # (-9.81, 0, 0)

# --- The sandal (see solver.nao_model): printed region = 7 x 5 squares plus a white border ------------------------
BOARD_BORDER_M = 0.015
BOARD_HALF_X_M = BOARD_COLUMNS * BOARD_SQUARE_M / 2 + BOARD_BORDER_M  # printed region, board frame
BOARD_HALF_Y_M = BOARD_ROWS * BOARD_SQUARE_M / 2 + BOARD_BORDER_M
SANDAL_THICKNESS_M = 0.006
SANDAL_HEEL_X_M = -0.055  # the plate reaches back under the heel (sole frame)

# --- Shapes, in each link's own frame (m). Colours are greys: rgba ------------------------------------------------
TORSO_BOX = ((TORSO_BACK_X_M, 0.050), (-0.070, 0.070), (-0.040, 0.115))  # (x range, y range, z range)
NECK_CYLINDER = (0.022, (-0.015, 0.0))  # radius, z range in the Neck frame
HEAD_SPHERE = (0.055, (-0.005, 0.0, 0.060))  # radius, centre in the Head frame (the camera stays outside it)
THIGH_RADIUS_M = 0.032
TIBIA_RADIUS_M = 0.030
FOOT_BOXES_SOLE = (((-0.055, 0.100), (-0.040, 0.040), (0.0, 0.004)),  # the foot in the sole frame: a thin toe,
                   ((-0.055, 0.085), (-0.040, 0.040), (0.004, 0.016)),  # the sole,
                   ((-0.045, 0.045), (-0.035, 0.035), (0.016, 0.040)))  # the block under the ankle
ARM_RADIUS_M = 0.025
ARM_SEGMENT_TORSO = {"L": ((-0.035, 0.105, 0.095), (-0.035, 0.150, -0.105)), "R": None}  # R mirrors L
GROUND_HALF_SIZE_M = 3.0

COLOURS = {
    "torso": 0.80, "neck": 0.55, "head": 0.86, "thigh": 0.74, "tibia": 0.70, "foot": 0.72, "sandal": 0.78,
    "arm": 0.68, "ground": 0.42,
}


@dataclass(frozen=True)
class BoardMount:
    """Mounting error of a sandal: p_sole = Rot_z(rot_z) @ (p_nominal + [trans_x, trans_y, 0])."""

    rot_z_rad: float = 0.0
    trans_x_m: float = 0.0
    trans_y_m: float = 0.0


@dataclass(frozen=True)
class BodyGeometry:
    """What differs between one simulated NAO and the nominal one. Per leg 'L'/'R'."""

    thigh_delta_m: dict = field(default_factory=lambda: {"L": 0.0, "R": 0.0})
    tibia_delta_m: dict = field(default_factory=lambda: {"L": 0.0, "R": 0.0})
    board_mount: dict = field(default_factory=lambda: {"L": BoardMount(), "R": BoardMount()})
    sandal_mass_kg: float = SANDAL_MASS_KG


def T_sole_board(mount: BoardMount = BoardMount()) -> np.ndarray:
    """Pose (4, 4) of the board frame in the sole frame: origin at the board centre, axes those of the sole
    turned by the mount's rot_z; the printed face is the board frame's z = 0 plane, looking towards +z."""
    R = rot_z(mount.rot_z_rad)
    return make_transform(R, R @ np.array([BOARD_CENTER_X_M + mount.trans_x_m, mount.trans_y_m, 0.0]))


def _xyz(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _origin(T: np.ndarray) -> str:
    return f'<origin xyz="{_xyz(T[:3, 3])}" rpy="{_xyz(rpy_from_rot(T[:3, :3]))}"/>'


def _material(grey: float) -> str:
    return f'<material name="grey{grey:.2f}"><color rgba="{grey} {grey} {grey} 1"/></material>'


def _shape(geometry: str, T: np.ndarray, grey: float) -> str:
    """A visual and an identical collision element (the renderer and the checker see the same body)."""
    return (f"<visual>{_origin(T)}<geometry>{geometry}</geometry>{_material(grey)}</visual>"
            f"<collision>{_origin(T)}<geometry>{geometry}</geometry></collision>")


def _box(ranges, T_link_frame=np.eye(4), grey=0.7) -> str:
    lo = np.array([r[0] for r in ranges])
    hi = np.array([r[1] for r in ranges])
    T = T_link_frame @ make_transform(np.eye(3), (lo + hi) / 2)
    return _shape(f'<box size="{_xyz(hi - lo)}"/>', T, grey)


def _capsule(a, b, radius, grey) -> str:
    """A capsule whose axis runs from point a to point b (link frame)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return _shape(f'<capsule radius="{radius}" length="{length}"/>', make_transform(R, (a + b) / 2), grey)


def _link(name: str, urdf: Urdf, shapes: str = "", mass=None, com=None) -> str:
    if mass is None:
        source = urdf.links.get(name)
        mass, com = (source.mass, source.com) if source else (0.0, (0.0, 0.0, 0.0))
    inertia = 1e-5 if mass > 0 else 0.0  # inertia tensors do not enter static torques
    return (f'<link name="{name}"><inertial><origin xyz="{_xyz(com)}"/><mass value="{mass:.9g}"/>'
            f'<inertia ixx="{inertia}" iyy="{inertia}" izz="{inertia}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f"{shapes}</link>")


def _joint(name, kind, parent, child, T_origin, axis=(1.0, 0.0, 0.0), limits=None) -> str:
    limit = ""
    if limits is not None:
        limit = (f'<limit lower="{limits.lower}" upper="{limits.upper}" effort="{limits.effort}" '
                 f'velocity="{limits.velocity}"/>')
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'{_origin(T_origin)}<axis xyz="{_xyz(axis)}"/>{limit}</joint>')


def _urdf_joint_origin(urdf: Urdf, name: str, length_delta_m: float = 0.0) -> np.ndarray:
    """The joint's origin; a length delta lengthens its translation along its own direction (as in
    solver.kinematics.chain_frames)."""
    from naocal.solver.transforms import rot_rpy

    joint = urdf.joints[name]
    t = np.array(joint.xyz, dtype=float)
    if length_delta_m:
        t = t + length_delta_m * t / np.linalg.norm(t)
    return make_transform(rot_rpy(*joint.rpy), t)


def nao_urdf_string(geometry: BodyGeometry = BodyGeometry()) -> str:
    """The simulated NAO as URDF text: torso (base), head, arms (fixed, lying beside the body), both legs with
    their sandals. Joint origins, axes, limits, masses and centres of mass come from the nominal URDF."""
    urdf = nominal_urdf()
    parts = ['<?xml version="1.0"?>', '<robot name="naocal_nao">']
    parts.append(_link("torso", urdf, _box(TORSO_BOX, grey=COLOURS["torso"])))
    # Head: HeadYaw -> Neck, HeadPitch -> Head.
    neck_r, (neck_z0, neck_z1) = NECK_CYLINDER
    neck = _shape(f'<cylinder radius="{neck_r}" length="{neck_z1 - neck_z0}"/>',
                  make_transform(np.eye(3), [0, 0, (neck_z0 + neck_z1) / 2]), COLOURS["neck"])
    head_r, head_c = HEAD_SPHERE
    head = _shape(f'<sphere radius="{head_r}"/>', make_transform(np.eye(3), head_c), COLOURS["head"])
    for name, shapes in zip(HEAD_JOINTS, (neck, head)):
        j = urdf.joints[name]
        parts.append(_link(j.child, urdf, shapes))
        parts.append(_joint(name, "revolute", j.parent, j.child, _urdf_joint_origin(urdf, name), j.axis, j))
    # Arms: decorative and for collisions, fixed beside the body.
    for leg, sign in (("L", 1.0), ("R", -1.0)):
        a, b = (np.array(p) * [1.0, sign, 1.0] for p in ARM_SEGMENT_TORSO["L"])
        parts.append(_link(f"{leg}Arm", urdf, _capsule(a, b, ARM_RADIUS_M, COLOURS["arm"]), 0.0, (0, 0, 0)))
        parts.append(_joint(f"{leg}Arm_fixedjoint", "fixed", "torso", f"{leg}Arm", np.eye(4)))
    # Legs.
    for leg in LEGS:
        names = leg_joints(leg)
        thigh_len = 0.100 + geometry.thigh_delta_m[leg]
        tibia_len = 0.1029 + geometry.tibia_delta_m[leg]
        deltas = {names[3]: geometry.thigh_delta_m[leg], names[4]: geometry.tibia_delta_m[leg]}
        for k, name in enumerate(names):
            j = urdf.joints[name]
            if k == 2:  # HipPitch -> thigh
                shapes = _capsule((0, 0, -0.012), (0, 0, -thigh_len), THIGH_RADIUS_M, COLOURS["thigh"])
            elif k == 3:  # KneePitch -> tibia
                shapes = _capsule((0, 0, 0), (0, 0, -tibia_len + 0.01), TIBIA_RADIUS_M, COLOURS["tibia"])
            elif k == 5:  # AnkleRoll -> foot (the ankle frame; the sole lies 0.04511 below)
                T_ankle_sole = _urdf_joint_origin(urdf, SOLE_JOINTS[leg])
                shapes = "".join(_box(box, T_ankle_sole, COLOURS["foot"]) for box in FOOT_BOXES_SOLE)
            else:
                shapes = ""
            parts.append(_link(j.child, urdf, shapes))
            parts.append(_joint(name, "revolute", j.parent, j.child,
                                _urdf_joint_origin(urdf, name, deltas.get(name, 0.0)), j.axis, j))
        foot_link = urdf.joints[names[5]].child
        T_ankle_board = _urdf_joint_origin(urdf, SOLE_JOINTS[leg]) @ T_sole_board(geometry.board_mount[leg])
        mount = geometry.board_mount[leg]
        # The plate: printed region in front, reaching back under the heel; its top face is the board plane.
        heel_x = SANDAL_HEEL_X_M - BOARD_CENTER_X_M - mount.trans_x_m
        plate = _box(((heel_x, BOARD_HALF_X_M), (-BOARD_HALF_Y_M, BOARD_HALF_Y_M), (-SANDAL_THICKNESS_M, 0.0)),
                     grey=COLOURS["sandal"])
        parts.append(_link(f"{leg}Sandal", urdf, plate, geometry.sandal_mass_kg, (0.0, 0.0, 0.0)))
        parts.append(_joint(f"{leg}Sandal_fixedjoint", "fixed", foot_link, f"{leg}Sandal", T_ankle_board))
    parts.append("</robot>")
    return "\n".join(parts)


def _quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation

    return tuple(float(x) for x in Rotation.from_matrix(R).as_quat())


class NaoBody:
    """A simulated NAO (and the ground) in its own PyBullet DIRECT client.

    `link_index` names the links used elsewhere: 'torso' (-1), 'Neck', 'Head', 'LArm', 'RArm', and per leg
    'LThigh', 'LTibia', 'LFoot', 'LSandal' (and R...). `joint_index` maps solver.joints.JOINTS to PyBullet joints.
    """

    def __init__(self, geometry: BodyGeometry = BodyGeometry()):
        self.geometry = geometry
        self.client = pybullet.connect(pybullet.DIRECT)
        try:
            self._load(geometry)
        except Exception:
            pybullet.disconnect(physicsClientId=self.client)
            raise

    def _load(self, geometry: BodyGeometry) -> None:
        cid = self.client
        # PyBullet's inverse dynamics of a fixed-base body ignores the base's orientation: it applies the
        # gravity vector in the base (torso) frame. Nothing here is ever stepped, so give gravity in that frame.
        pybullet.setGravity(*GRAVITY_TORSO_MPS2, physicsClientId=cid)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="naocal_nao_")
        try:
            with os.fdopen(fd, "w") as handle:
                handle.write(nao_urdf_string(geometry))
            self.robot = pybullet.loadURDF(
                path, basePosition=T_WORLD_TORSO[:3, 3].tolist(), baseOrientation=_quaternion_xyzw(R_WORLD_TORSO),
                useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        finally:
            os.unlink(path)
        half = GROUND_HALF_SIZE_M
        grey = COLOURS["ground"]
        ground_collision = pybullet.createCollisionShape(
            pybullet.GEOM_BOX, halfExtents=[half, half, 0.01], physicsClientId=cid)
        ground_visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=[half, half, 0.01], rgbaColor=[grey, grey, grey, 1], physicsClientId=cid)
        self.ground = pybullet.createMultiBody(0.0, ground_collision, ground_visual, [0.0, 0.0, -0.01],
                                               physicsClientId=cid)
        urdf = nominal_urdf()
        child_names = {}
        self.joint_index: dict[str, int] = {}
        for i in range(pybullet.getNumJoints(self.robot, physicsClientId=cid)):
            info = pybullet.getJointInfo(self.robot, i, physicsClientId=cid)
            joint_name, link_name = info[1].decode(), info[12].decode()
            child_names[link_name] = i
            if info[2] == pybullet.JOINT_REVOLUTE:
                self.joint_index[joint_name] = i
        self.link_index = {"torso": -1}
        for name in ("Neck", "Head", "LArm", "RArm", "LSandal", "RSandal"):
            self.link_index[name] = child_names[name]
        for leg in LEGS:
            names = leg_joints(leg)
            self.link_index[f"{leg}Thigh"] = child_names[urdf.joints[names[2]].child]
            self.link_index[f"{leg}Tibia"] = child_names[urdf.joints[names[3]].child]
            self.link_index[f"{leg}Foot"] = child_names[urdf.joints[names[5]].child]
        # The movable joints in PyBullet's DoF order (inverse dynamics takes and returns them in this order).
        self._dof_joints = sorted(self.joint_index, key=self.joint_index.get)
        self._dof_of_joint = np.array([self._dof_joints.index(j) for j in JOINTS])
        assert set(self._dof_joints) == set(JOINTS)

    def set_angles(self, q) -> None:
        """Put the 14 joints (solver.joints.JOINTS order, rad) at `q`."""
        q = np.asarray(q, dtype=float)
        for name, angle in zip(JOINTS, q):
            pybullet.resetJointState(self.robot, self.joint_index[name], float(angle), physicsClientId=self.client)

    def gravity_torques(self, q) -> np.ndarray:
        """Static torque (N m) that gravity exerts on each of the 14 joints at angles q (JOINTS order).

        PyBullet's inverse dynamics returns the torque that HOLDS the body still; gravity's torque is its
        negative (positive turns the joint in +q, as solver.kinematics.gravity_torques)."""
        q = np.asarray(q, dtype=float)
        q_dof = np.empty(len(JOINTS))
        q_dof[self._dof_of_joint] = q
        zeros = [0.0] * len(JOINTS)
        holding = pybullet.calculateInverseDynamics(self.robot, q_dof.tolist(), zeros, zeros,
                                                    physicsClientId=self.client)
        return -np.asarray(holding)[self._dof_of_joint]

    def hidden(self, q, eye_world, points_world, *, stop_short_m: float = 1e-3) -> np.ndarray:
        """(N,) True where the body (at angles q) or the ground lies on the straight line from `eye_world` (3,)
        to each of `points_world` (N, 3), m. Rays stop `stop_short_m` before the point so that the surface the
        point lies on does not hide it."""
        self.set_angles(q)
        points = np.atleast_2d(np.asarray(points_world, dtype=float))
        eye = np.asarray(eye_world, dtype=float)
        direction = points - eye
        length = np.linalg.norm(direction, axis=1, keepdims=True)
        ends = eye + direction * np.maximum(length - stop_short_m, 0.0) / length
        starts = np.broadcast_to(eye, points.shape)
        hits = pybullet.rayTestBatch(starts.tolist(), ends.tolist(), physicsClientId=self.client)
        return np.array([hit[0] != -1 for hit in hits], dtype=bool)

    def link_pose_world(self, name: str) -> np.ndarray:
        """T_world_link (4, 4) of a named link's frame (the URDF link frame, not its centre of mass)."""
        from scipy.spatial.transform import Rotation

        index = self.link_index[name]
        if index == -1:  # PyBullet gives the base's centre-of-mass frame: take its inertial offset back out
            position, orientation = pybullet.getBasePositionAndOrientation(self.robot, physicsClientId=self.client)
            info = pybullet.getDynamicsInfo(self.robot, -1, physicsClientId=self.client)
            T_world_com = make_transform(Rotation.from_quat(orientation).as_matrix(), position)
            T_link_com = make_transform(Rotation.from_quat(info[4]).as_matrix(), info[3])
            return T_world_com @ np.linalg.inv(T_link_com)
        else:
            state = pybullet.getLinkState(self.robot, index, computeForwardKinematics=True,
                                          physicsClientId=self.client)
            position, orientation = state[4], state[5]
        return make_transform(Rotation.from_quat(orientation).as_matrix(), position)

    def close(self) -> None:
        if self.client is not None:
            try:
                pybullet.disconnect(physicsClientId=self.client)
            except pybullet.error:
                pass
            self.client = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


# --- Collision checking -------------------------------------------------------------------------------------------
LEG_PARTS = ("Sandal", "Foot", "Tibia", "Thigh")
BODY_PARTS = ("torso", "Head", "Neck", "LArm", "RArm")


def _checked_pairs() -> list[tuple[str, str]]:
    """Link pairs that must keep apart: leg-leg, leg-body (but not thigh-torso, joined at the hip), and within a
    leg the sandal and foot against the thigh and tibia (neighbouring links touch by construction)."""
    pairs = [("L" + a, "R" + b) for a in LEG_PARTS for b in LEG_PARTS]
    for leg in LEGS:
        pairs += [(leg + a, b) for a in LEG_PARTS for b in BODY_PARTS if (a, b) != ("Thigh", "torso")]
        pairs += [(leg + "Sandal", leg + "Thigh"), (leg + "Sandal", leg + "Tibia"), (leg + "Foot", leg + "Thigh")]
    return pairs


GROUND_CHECKED = tuple(leg + part for part in LEG_PARTS for leg in LEGS) + ("Head", "Neck")


@dataclass(frozen=True)
class Contact:
    """Two links (or a link and 'ground') closer than the checker's margin; distance < 0 is penetration, m."""

    link_a: str
    link_b: str
    distance_m: float


class CollisionChecker:
    """Self-collision and ground-contact checks of a stance on a `NaoBody` (the nominal one by default).

    A stance is the 14 joint angles in solver.joints.JOINTS order (rad), as the body would take them. Links closer
    than `margin_m` to each other, or than `ground_margin_m` to the ground, make the stance unsafe.
    The planner's checker should use a larger margin than the robot's own refusal check (the mock's), since the
    true robot differs from the nominal one by its joint offsets.
    """

    def __init__(self, body: NaoBody | None = None, *, margin_m: float = 0.01, ground_margin_m: float = 0.01):
        self._owns_body = body is None
        self.body = body if body is not None else NaoBody()
        self.margin_m = float(margin_m)
        self.ground_margin_m = float(ground_margin_m)
        index = self.body.link_index
        self._pairs = [(a, b, index[a], index[b]) for a, b in _checked_pairs()]
        self._ground = [(a, index[a]) for a in GROUND_CHECKED]

    def _closest(self, link_a: int, body_b: int, link_b: int, margin: float):
        kwargs = {"linkIndexA": link_a, "physicsClientId": self.body.client}
        if link_b is not None:
            kwargs["linkIndexB"] = link_b
        points = pybullet.getClosestPoints(self.body.robot, body_b, margin, **kwargs)
        return min((pt[8] for pt in points), default=None)

    def _scan(self, q, stop_at_first: bool) -> list[Contact]:
        self.body.set_angles(_as_stance(q))
        found = []
        for name, link in self._ground:
            d = self._closest(link, self.body.ground, None, self.ground_margin_m)
            if d is not None:
                found.append(Contact(name, "ground", float(d)))
                if stop_at_first:
                    return found
        for name_a, name_b, link_a, link_b in self._pairs:
            d = self._closest(link_a, self.body.robot, link_b, self.margin_m)
            if d is not None:
                found.append(Contact(name_a, name_b, float(d)))
                if stop_at_first:
                    return found
        return found

    def contacts(self, q) -> list[Contact]:
        """Every checked pair (and ground contact) closer than its margin at stance q."""
        return self._scan(q, stop_at_first=False)

    def is_safe(self, q) -> bool:
        """True if no checked pair comes closer than the margin and nothing checked nears the ground."""
        return not self._scan(q, stop_at_first=True)

    def safe_mask(self, Q) -> np.ndarray:
        """(N,) bool: is_safe for each row of Q (N, 14)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        return np.array([self.is_safe(q) for q in Q], dtype=bool)

    def close(self) -> None:
        if self._owns_body:
            self.body.close()

    def distances(self, q, query_m: float, pairs=None) -> dict:
        """{(link_a, link_b or 'ground'): signed distance m} of every checked pair (or of `pairs`) closer than
        query_m at stance q; pairs farther apart are left out."""
        self.body.set_angles(_as_stance(q))
        out = {}
        wanted = None if pairs is None else set(pairs)
        for name, link in self._ground:
            if wanted is None or (name, "ground") in wanted:
                d = self._closest(link, self.body.ground, None, query_m)
                if d is not None:
                    out[(name, "ground")] = float(d)
        for name_a, name_b, link_a, link_b in self._pairs:
            if wanted is None or (name_a, name_b) in wanted:
                d = self._closest(link_a, self.body.robot, link_b, query_m)
                if d is not None:
                    out[(name_a, name_b)] = float(d)
        return out

    def margin_for(self, pair) -> float:
        return self.ground_margin_m if pair[1] == "ground" else self.margin_m

    def distance_gradients(self, q, query_m: float, dof_groups) -> tuple[list, np.ndarray, np.ndarray]:
        """(pairs, distances (P,), gradients (G, P)) of every checked pair closer than query_m at stance q: the
        signed distance and its derivative with respect to each group of joints (JOINTS indices turned together,
        e.g. the one HipYawPitch motor), from the closest points and the joints' axes:
        d distance / d q_j = n . (w_j x (p_a - o_j) [a below j] - w_j x (p_b - o_j) [b below j]),
        n the normal from b to a, w_j and o_j joint j's axis and origin in the world."""
        q = _as_stance(q)
        self.body.set_angles(q)
        axes, origins, below = self._joint_frames()
        pairs, dists, points = [], [], []
        for name, link in self._ground:
            found = pybullet.getClosestPoints(self.body.robot, self.body.ground, query_m, linkIndexA=link,
                                              physicsClientId=self.body.client)
            if found:
                pt = min(found, key=lambda p: p[8])
                pairs.append((name, "ground"))
                dists.append(pt[8])
                points.append((link, None, np.array(pt[5]), np.array(pt[6]), np.array(pt[7])))
        for name_a, name_b, link_a, link_b in self._pairs:
            found = pybullet.getClosestPoints(self.body.robot, self.body.robot, query_m, linkIndexA=link_a,
                                              linkIndexB=link_b, physicsClientId=self.body.client)
            if found:
                pt = min(found, key=lambda p: p[8])
                pairs.append((name_a, name_b))
                dists.append(pt[8])
                points.append((link_a, link_b, np.array(pt[5]), np.array(pt[6]), np.array(pt[7])))
        grads = np.zeros((len(dof_groups), len(pairs)))
        if not pairs:
            return pairs, np.array(dists), grads
        link_a = np.array([pt[0] for pt in points]) + 1  # rows of `below` (-1, the torso, is row 0)
        link_b = np.array([-1 if pt[1] is None else pt[1] for pt in points]) + 1  # the ground: row 0 too
        p_a, p_b, normal = (np.array([pt[k] for pt in points]) for k in (2, 3, 4))
        v_a = np.cross(axes[:, None, :], p_a[None] - origins[:, None, :]) * below[:, link_a, None]
        v_b = np.cross(axes[:, None, :], p_b[None] - origins[:, None, :]) * below[:, link_b, None]
        per_joint = np.einsum("pk,jpk->jp", normal, v_a - v_b)  # (14 joints, P)
        for k, group in enumerate(dof_groups):
            grads[k] = per_joint[np.atleast_1d(group)].sum(axis=0)
        return pairs, np.array(dists), grads

    def _joint_frames(self):
        """Axes (14, 3) and origins (14, 3) of the joints (JOINTS order) in the world, and below (14, links + 1)
        bool: whether joint j moves link i (column i + 1; column 0, the torso, never moves)."""
        client, robot = self.body.client, self.body.robot
        if not hasattr(self, "_below"):
            n = pybullet.getNumJoints(robot, physicsClientId=client)
            parents = {i: pybullet.getJointInfo(robot, i, physicsClientId=client)[16] for i in range(n)}
            self._below = np.zeros((len(JOINTS), n + 1), dtype=bool)
            for k, joint in enumerate(JOINTS):
                j = self.body.joint_index[joint]
                for i in range(n):
                    self._below[k, i + 1] = _descends(i, j, parents)
            self._axis_local = np.array([pybullet.getJointInfo(robot, self.body.joint_index[j],
                                                               physicsClientId=client)[13] for j in JOINTS])
        axes, origins = np.empty((len(JOINTS), 3)), np.empty((len(JOINTS), 3))
        for k, joint in enumerate(JOINTS):
            state = pybullet.getLinkState(robot, self.body.joint_index[joint], computeForwardKinematics=True,
                                          physicsClientId=client)
            axes[k] = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3) @ self._axis_local[k]
            origins[k] = state[4]
        return axes, origins, self._below


def _descends(link: int, joint: int, parents: dict) -> bool:
    """Whether `link` is joint's child link or below it."""
    while link != -1:
        if link == joint:
            return True
        link = parents[link]
    return False


def _as_stance(q) -> np.ndarray:
    """14 angles in JOINTS order from an array or a {joint: angle} dict holding all 14 joints."""
    if isinstance(q, dict):
        missing = [j for j in JOINTS if j not in q]
        if missing:
            raise ValueError(f"stance misses joints {missing}")
        return np.array([float(q[j]) for j in JOINTS])
    q = np.asarray(q, dtype=float)
    if q.shape != (len(JOINTS),):
        raise ValueError(f"a stance is {len(JOINTS)} angles in solver.joints.JOINTS order, got shape {q.shape}")
    return q
