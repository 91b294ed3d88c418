"""A simulated arm (docs/ARM.md): a PyBullet arm built from a URDF with hidden link-length and joint-offset errors,
a 3-D sensor (laser tracker) in a hidden frame and a camera in a hidden pose watching markers on the end effector.

The physical arm is PyBullet's: its URDF with every link lengthened by its hidden error (the joint origins moved
along their offsets), set to the true angles q = theta - c; the points come from PyBullet's forward kinematics,
not from naocal's, so the simulation checks the model. Stances are drawn uniformly inside the joint limits less a
margin, and kept only when no two non-adjacent links are closer than 5 mm (PyBullet's collision shapes; pairs
already touching in the arm's mid-range stance are part of its build and not counted), no link but the base is
within 20 mm of the floor (z = 0 of the base frame), and the tracker's points are in front of it.
"""

from __future__ import annotations

import math
import re
import tempfile
from pathlib import Path

import numpy as np

from naocal.kinds.arm.model import Observations, Sensor, exp_so3, log_so3
from naocal.kinds.arm.dataset import arm_chain
from naocal.solver.effect import POSE_COMPONENTS
from naocal.solver.errors import NaocalError

LIMIT_MARGIN_RAD = 0.1
LIMIT_MARGIN_FRACTION = 0.1
SELF_DISTANCE_M = 0.005
FLOOR_CLEARANCE_M = 0.02
TOOL_RADIUS_M = 0.1  # the tracker's three reflectors on the tool, around the tip's z axis
MARKER_RADIUS_M = 0.06  # the camera's four markers
TOOL_HEIGHT_M = 0.1
CAMERA = {"width_px": 1280, "height_px": 1024, "fx_px": 1400.0, "fy_px": 1400.0, "cx_px": 639.5, "cy_px": 511.5,
          "distortion": [0.0, 0.0, 0.0, 0.0, 0.0]}
IMAGE_MARGIN_PX = 10.0


def tool_points() -> dict:
    """The points on the end effector (tip frame, m): tracker reflectors t1..t3 and camera markers m1..m4."""
    points = {}
    for i in range(3):
        a = 2.0 * math.pi * i / 3.0
        points[f"t{i + 1}"] = (TOOL_RADIUS_M * math.cos(a), TOOL_RADIUS_M * math.sin(a), TOOL_HEIGHT_M)
    for i in range(4):
        a = math.pi / 4.0 + math.pi / 2.0 * i
        points[f"m{i + 1}"] = (MARKER_RADIUS_M * math.cos(a), MARKER_RADIUS_M * math.sin(a), TOOL_HEIGHT_M + 0.02)
    return points


def hidden_truth(chain, link_names, rng, *, joint_offsets=True, link_lengths=True) -> dict:
    """Joint offsets 0.01-0.5 deg and link length errors 0.1-2 mm (random signs), by parameter name."""
    truth = {}
    for joint in chain.joint_names:
        size = math.radians(rng.uniform(0.01, 0.5)) if joint_offsets else 0.0
        truth[f"joint_offset.{joint}"] = float(size * rng.choice((-1.0, 1.0)))
    offsets = [chain.T_origin[k, :3, 3] for k in range(len(chain.joint_names))] + [chain.T_end[:3, 3]]
    for name, offset in zip(link_names, offsets):
        if np.linalg.norm(offset) > 1e-9:
            size = rng.uniform(0.1e-3, 2e-3) if link_lengths else 0.0
            truth[f"link_length.{name}"] = float(size * rng.choice((-1.0, 1.0)))
    return truth


def perturbed_urdf(urdf_path: Path, chain, link_names, truth: dict, out_path: Path) -> None:
    """The URDF with each chain joint's origin (and the tip's fixed joint) moved along its offset by the hidden
    link length error; mesh paths made absolute so the copy loads from anywhere."""
    import xml.etree.ElementTree as ET

    tree = ET.parse(urdf_path)
    root = tree.getroot()
    joints = {j.get("name"): j for j in root.findall("joint")}
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    # the joint element that carries each origin: the chain's joints, and for the tip offset the last fixed joint
    # with a translation between the last movable joint and the tip
    carriers = [joints[j] for j in chain.joint_names]
    tip_joint = None
    link = chain.tip
    while link in by_child and by_child[link].get("name") not in chain.joint_names:
        j = by_child[link]
        origin = j.find("origin")
        if origin is not None and np.linalg.norm([float(v) for v in origin.get("xyz", "0 0 0").split()]) > 1e-9:
            tip_joint = j
        link = j.find("parent").get("link")
    carriers.append(tip_joint)
    offsets = [chain.T_origin[k, :3, 3] for k in range(len(chain.joint_names))] + [chain.T_end[:3, 3]]
    for element, name, offset in zip(carriers, link_names, offsets):
        delta = truth.get(f"link_length.{name}", 0.0)
        if not delta:
            continue
        if element is None:
            raise NaocalError(f"{urdf_path}: cannot place the length error of {name} (several fixed joints)")
        origin = element.find("origin")
        xyz = np.array([float(v) for v in origin.get("xyz").split()])
        # the folded offset and this joint's own translation point the same way when the only fixed joints
        # between carry no translation (true of kuka_iiwa and franka_panda; checked by tests)
        direction = offset / np.linalg.norm(offset)
        own = xyz / np.linalg.norm(xyz)
        if abs(abs(own @ direction) - 1.0) > 1e-9 and element.get("type") != "fixed":
            raise NaocalError(f"{urdf_path}: joint {element.get('name')}'s origin does not carry the whole offset")
        origin.set("xyz", " ".join(repr(float(v)) for v in xyz + delta * own))
    text = ET.tostring(root, encoding="unicode")
    base = urdf_path.parent

    def absolute(match):
        name = match.group(1)
        name = name[len("package://"):] if name.startswith("package://") else name
        return f'filename="{(base / name).resolve()}"' if not name.startswith("/") else match.group(0)

    out_path.write_text(re.sub(r'filename="([^"]+)"', absolute, text), encoding="utf-8")


class SelfCollision:
    """Which links of a PyBullet body come within SELF_DISTANCE_M of each other (its URDF's collision shapes): every
    pair but a link and its parent, less the pairs already that close in the stance the body stands in when it is
    made (part of its build: a wrist's short links overlap). The robot is real hardware in spirit: a stance whose
    links touch is never measured, as it would never be commanded."""

    def __init__(self, p, client, body):
        self._p, self._client, self.body = p, client, body
        n = p.getNumJoints(body, physicsClientId=client)
        parent = {i: p.getJointInfo(body, i, physicsClientId=client)[16] for i in range(n)}
        pairs = [(a, b) for a in range(-1, n) for b in range(a + 1, n) if parent.get(b) != a]
        self.built_in = {pair for pair in pairs if self._close(*pair)}
        self.pairs = [pair for pair in pairs if pair not in self.built_in]

    def _close(self, a, b) -> bool:
        return bool(self._p.getClosestPoints(self.body, self.body, SELF_DISTANCE_M, linkIndexA=a, linkIndexB=b,
                                             physicsClientId=self._client))

    def colliding(self):
        """The first pair of link indices (-1: the base) closer than SELF_DISTANCE_M in the body's current stance,
        or None."""
        return next((pair for pair in self.pairs if self._close(*pair)), None)


def look_at(eye, target) -> np.ndarray:
    """R_base_cam of a camera at `eye` looking at `target` (NAO camera frame: x optical axis, y left, z up)."""
    x = np.asarray(target, float) - np.asarray(eye, float)
    x /= np.linalg.norm(x)
    y = np.cross([0.0, 0.0, 1.0], x)
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


class SimulatedArm:
    """A PyBullet arm with hidden errors. Use as a context manager (it owns a PyBullet connection)."""

    def __init__(self, urdf_path, base, tip, seed=0, *, hidden=("joint_offsets", "link_lengths")):
        from naocal.body.pybullet_quiet import c_output_silenced, pybullet  # without its banner on naocal's output

        self.urdf_path = Path(urdf_path)
        self.base, self.tip = base, tip
        self.chain, self.link_names, self.load = arm_chain(self.urdf_path, base, tip, self.urdf_path)
        self.rng = np.random.default_rng(seed)
        self.truth = hidden_truth(self.chain, self.link_names, self.rng, joint_offsets="joint_offsets" in hidden,
                                  link_lengths="link_lengths" in hidden)
        self.points = tool_points()
        # hidden frames: a tracker 2-3 m away, turned anyhow; a camera 2.5 m away looking at the workspace
        R_base_tracker = exp_so3(self.rng.normal(size=3) * 1.0)
        eye = np.array([2.0, -1.5, 1.2]) + self.rng.normal(size=3) * 0.1
        R_base_tracker_t = np.array([2.5, 1.0, 0.5]) + self.rng.normal(size=3) * 0.2
        R_base_cam = look_at(eye, (0.3, 0.0, 0.6)) @ exp_so3(self.rng.normal(size=3) * 0.02)
        self.frames = {"tracker": (R_base_tracker.T, -R_base_tracker.T @ R_base_tracker_t),
                       "camera": (R_base_cam.T, -R_base_cam.T @ eye)}  # T_sensor_base: (R, t)
        for name, (R, t) in self.frames.items():
            rotvec = log_so3(R)
            for c, a in enumerate("xyz"):
                self.truth[f"sensor.{name}.rotation.{a}"] = float(rotvec[c])
                self.truth[f"sensor.{name}.translation.{a}"] = float(t[c])
        self._p = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        self._tmp = tempfile.TemporaryDirectory(prefix="naocal-arm-")
        true_urdf = Path(self._tmp.name) / "true.urdf"
        perturbed_urdf(self.urdf_path, self.chain, self.link_names, self.truth, true_urdf)
        with c_output_silenced():  # its warnings about links without <inertial> (masses are not used here)
            self.body = pybullet.loadURDF(str(true_urdf), useFixedBase=True, physicsClientId=self._client)
        info = [pybullet.getJointInfo(self.body, i, physicsClientId=self._client)
                for i in range(pybullet.getNumJoints(self.body, physicsClientId=self._client))]
        index = {i[1].decode(): i[0] for i in info}
        self.joint_index = [index[j] for j in self.chain.joint_names]
        link_index = {i[12].decode(): i[0] for i in info}
        self.tip_index = link_index[tip]
        mid = [(lo + hi) / 2.0 for lo, hi in self.limits()]
        self._set(mid)
        self.self_collision = SelfCollision(pybullet, self._client, self.body)
        self.on_floor = {link for link in range(-1, len(info)) if self._link_low(link)}

    # -- pybullet helpers

    def limits(self):
        out = []
        for joint in self.chain.joint_names:
            j = self.chain_urdf_joint(joint)
            lo, hi = (j.lower, j.upper) if math.isfinite(j.lower) else (-math.pi, math.pi)
            margin = max(LIMIT_MARGIN_RAD, LIMIT_MARGIN_FRACTION * (hi - lo))
            out.append((lo + margin, hi - margin))
        return out

    def chain_urdf_joint(self, joint):
        from naocal.solver.urdf import parse_urdf

        if not hasattr(self, "_urdf"):
            self._urdf = parse_urdf(self.urdf_path)
        return self._urdf.joints[joint]

    def _set(self, q):
        for i, angle in zip(self.joint_index, q):
            self._p.resetJointState(self.body, i, float(angle), physicsClientId=self._client)
        self._p.performCollisionDetection(physicsClientId=self._client)

    def _link_low(self, link) -> bool:
        lo, _ = self._p.getAABB(self.body, link, physicsClientId=self._client)
        return lo[2] < FLOOR_CLEARANCE_M

    def collides(self) -> bool:
        if self.self_collision.colliding() is not None:
            return True
        n = self._p.getNumJoints(self.body, physicsClientId=self._client)
        return any(self._link_low(link) for link in range(-1, n) if link not in self.on_floor)

    def tip_pose(self):
        state = self._p.getLinkState(self.body, self.tip_index, computeForwardKinematics=True,
                                     physicsClientId=self._client)
        R = np.array(self._p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return R, np.array(state[4])

    # -- measuring

    def true_angles(self, theta):
        c = np.array([self.truth[f"joint_offset.{j}"] for j in self.chain.joint_names])
        return np.asarray(theta) - c

    def points_in_base(self, theta) -> dict:
        """{point: (3,)} of the true arm at readings theta (PyBullet's forward kinematics)."""
        self._set(self.true_angles(theta))
        R, t = self.tip_pose()
        return {name: R @ np.array(p) + t for name, p in self.points.items()}

    def sample_stances(self, n, max_tries=None):
        """n readings theta (n, k) of collision-free stances inside the limits (true angles checked)."""
        limits = np.array(self.limits())
        out, tries = [], 0
        max_tries = max_tries or 200 * n
        while len(out) < n:
            tries += 1
            if tries > max_tries:
                raise NaocalError(f"found only {len(out)} of {n} collision-free stances in {max_tries} tries")
            theta = self.rng.uniform(limits[:, 0], limits[:, 1])
            self._set(self.true_angles(theta))
            if self.collides():
                continue
            out.append(theta)
        return np.array(out)

    def measure(self, thetas, noise_m=1e-4, noise_px=0.2):
        """Observations of the tracker (t1..t3) and the camera (m1..m4 where it sees them) at readings thetas."""
        from naocal.solver.camera import project_points

        sensors = [Sensor("tracker", "points", noise=noise_m), Sensor("camera", "camera", dict(CAMERA), noise_px)]
        names = list(self.points)
        rows = []
        for pose, theta in enumerate(thetas):
            p_base = self.points_in_base(theta)
            R, t = self.frames["tracker"]
            for name in ("t1", "t2", "t3"):
                y = R @ p_base[name] + t + self.rng.normal(0.0, noise_m, 3)
                rows.append((pose, 0, names.index(name), theta, y))
            R, t = self.frames["camera"]
            for name in ("m1", "m2", "m3", "m4"):
                p_cam = R @ p_base[name] + t
                uv, depth = project_points(p_cam, CAMERA)
                inside = (IMAGE_MARGIN_PX <= uv[0] <= CAMERA["width_px"] - 1 - IMAGE_MARGIN_PX
                          and IMAGE_MARGIN_PX <= uv[1] <= CAMERA["height_px"] - 1 - IMAGE_MARGIN_PX)
                if depth > 0.2 and inside:
                    uv = uv + self.rng.normal(0.0, noise_px, 2)
                    rows.append((pose, 1, names.index(name), theta, np.array([uv[0], uv[1], 0.0])))
        obs = Observations(np.array([r[3] for r in rows]), np.array([r[0] for r in rows]),
                           np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
                           np.array([r[4] for r in rows]))
        return obs, sensors

    def close(self):
        if self._client is not None:
            self._p.disconnect(physicsClientId=self._client)
            self._client = None
        self._tmp.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def simulate_arm(out, urdf_path, base, tip, *, seed=0, n_poses=60, noise_m=1e-4, noise_px=0.2,
                 hidden=("joint_offsets", "link_lengths"), name="arm", pose_error_rad=0.0) -> dict:
    """Write a naocal.arm_dataset/1 directory `out` (with robot.urdf, the nominal URDF) and out/truth.json.

    pose_error_rad : the arm's repeatability: at each pose every joint stands off its reading by a random error of
        this standard deviation, shared by all that pose's observations (errors correlated within a pose)."""
    import json
    import shutil

    from naocal.kinds.arm.dataset import write_arm_dataset
    from naocal.solver.fileio import atomic_write_text

    out = Path(out)
    with SimulatedArm(urdf_path, base, tip, seed, hidden=hidden) as arm:
        thetas = arm.sample_stances(n_poses)
        off = np.random.default_rng([seed, 1]).normal(0.0, pose_error_rad, thetas.shape) if pose_error_rad else 0.0
        obs, sensors = arm.measure(thetas + off, noise_m, noise_px)
        obs.theta = np.asarray(thetas)[obs.pose]  # what the encoders read
        truth = dict(arm.truth)
        points = arm.points
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(urdf_path, out / "robot.urdf")
    meta = {
        "robot": {"id": f"simulated-{name}-{seed}", "model": name, "urdf": "robot.urdf", "base": base, "tip": tip},
        "points": {p: {"xyz_m": list(xyz)} for p, xyz in points.items()},
        "sensors": {"tracker": {"kind": "points", "noise_m": noise_m},
                    "camera": dict({"kind": "camera", "noise_px": noise_px}, **CAMERA)},
        "source": f"naocal simulate --robot {name} --seed {seed} (PyBullet; {n_poses} stances)",
    }
    write_arm_dataset(out, meta, arm.chain.joint_names, obs, sensors, points)
    truth_doc = {"schema": "naocal.arm_truth/1", "parameters": truth,
                 "noise": {"tracker_m": noise_m, "camera_px": noise_px, "pose_rad": pose_error_rad},
                 "hidden": list(hidden)}
    atomic_write_text(out / "truth.json", json.dumps(truth_doc, indent=1) + "\n")
    return {"n_poses": int(len(thetas)), "n_observations": int(len(obs)), "truth": truth}


# ------------------------------------------------------------------------------------------------ the dual-arm robot
# Two 6-DoF arms on a torso that turns about the vertical (a dual-arm industrial robot's layout, issue 24): naocal's
# own URDF (kinds/arm/data/dualarm.urdf, written by dualarm_urdf: no third-party file), two cameras on the torso, a
# laser tracker on the floor seeing a reflector on the right tool, ArUco-like markers glued on each tool.

DUALARM_URDF = Path(__file__).with_name("data") / "dualarm.urdf"
DUALARM_CHAINS = {"left": ("base_link", "left_tool"), "right": ("base_link", "right_tool")}
TORSO_HEIGHT_M = 0.8
# (joint, xyz in the parent link, axis, lower, upper rad, the child link's mass kg) of one arm; side s = +1 left,
# -1 right: the shoulder sits s * 0.22 m to the side and the arm's zero stance points sideways and up (its z
# outward, tilted up by SHOULDER_TILT_RAD: the two first axes are not on one line, which a turn of both torso
# cameras about it would hide)
SHOULDER_TILT_RAD = 0.4
ARM = (("j1", (0.05, 0.22, 0.35), (0, 0, 1), -2.9, 2.9, 3.5),
       ("j2", (0.0, 0.0, 0.12), (0, 1, 0), -0.6, 2.8, 5.0),
       ("j3", (0.04, 0.0, 0.36), (0, 1, 0), -2.6, 2.6, 3.0),
       ("j4", (0.0, 0.0, 0.30), (0, 0, 1), -2.9, 2.9, 1.5),
       ("j5", (0.0, 0.0, 0.08), (0, 1, 0), -2.1, 2.1, 1.0),
       ("j6", (0.0, 0.0, 0.08), (0, 0, 1), -2.9, 2.9, 0.4))
TOOL_OFFSET_M = 0.05  # the flange to the tool frame
# collision shapes (capsules along each link, for the simulator's collision check): each arm link's radius, the
# tool's (its markers stand on a ring of MARKER_RING_M), the pedestal's and the torso's (a column to its head)
LINK_RADIUS_M = (0.06, 0.055, 0.045, 0.035, 0.035, 0.03)
TOOL_RADIUS_DUAL_M, TOOL_LENGTH_M = 0.035, 0.06
PEDESTAL_RADIUS_M, TORSO_RADIUS_M, TORSO_TOP_M = 0.2, 0.15, 0.65
TOOL_MASS_KG = 0.8
TORSO_LIMIT_RAD = 2.6
DUAL_CAMERA = {"width_px": 1920, "height_px": 1200, "fx_px": 1100.0, "fy_px": 1100.0, "cx_px": 959.5,
               "cy_px": 599.5, "distortion": [0.0, 0.0, 0.0, 0.0, 0.0]}
# How far a camera's filed intrinsics are from the camera (`simulate_dualarm(camera_error=...)`), one standard
# deviation: focal lengths 0.3 % relative, the principal point 1.5 px, k1 0.002, the middle of what a separate
# checkerboard calibration leaves on a real robot's cameras (0.1-0.5 % and 1-2 px: the lens's focus and temperature
# since, the board's coverage of the image). One checkerboard session's own stated error is smaller (Bouguet's
# Camera Calibration Toolbox, its first example: fc +-0.05 %, cc +-0.6 px, kc(1) +-0.0025, about 3 sigma).
CAMERA_FILING_ERROR = {"f_rel": 3e-3, "c_px": 1.5, "k1": 2e-3}
MARKER_RING_M, MARKER_HEIGHT_M = 0.035, 0.03  # four markers around the tool's z axis, one on top
MARKER_SIZE_M = 0.03  # each marker's printed side: its corners' known spacing
# How far a printed marker sheet's scale is from the size typed (`simulate_dualarm(print_scale_error=...)`), one
# standard deviation, relative: an office laser or inkjet printer set to "actual size" prints a few tenths of a
# percent off (its paper feed and drum or head; the paper's humidity), so a 30 mm side comes out 29.9-30.1 mm unless
# it is measured. Every marker of one sheet shares the sheet's scale: each tool's markers are one sheet (SHEETS).
PRINT_SCALE_ERROR = 3e-3
SHEETS = {"left": "L_sheet", "right": "R_sheet"}  # each tool's markers: printed on one sheet
MARKER_VIEW_RAD = math.radians(65.0)  # a marker is detected when it faces the camera within this angle
REFLECTOR_M = (0.0, 0.0, 0.06)  # the tracker's reflector on the right tool


def dualarm_urdf(origins: dict | None = None) -> str:
    """The dual-arm robot's URDF text; `origins` {joint: xyz} replaces joint origins (the true robot's)."""
    origins = origins or {}

    def inertial(mass, com):
        return (f'<inertial><origin xyz="{com[0]:.6g} {com[1]:.6g} {com[2]:.6g}"/><mass value="{mass:g}"/>'
                f'<inertia ixx="{mass * 0.004:.6g}" iyy="{mass * 0.004:.6g}" izz="{mass * 0.002:.6g}" ixy="0" '
                'ixz="0" iyz="0"/></inertial>')

    def joint(name, kind, parent, child, xyz, rpy=(0.0, 0.0, 0.0), axis=None, limits=None):
        xyz, rpy = (" ".join(repr(float(v)) for v in vector) for vector in (origins.get(name, xyz), rpy))
        text = (f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{xyz}" rpy="{rpy}"/>')
        if axis is not None:
            text += f'<axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>'
        if limits is not None:
            text += f'<limit lower="{limits[0]}" upper="{limits[1]}" effort="150" velocity="2"/>'
        return text + "</joint>"

    def collision(radius, start, end):
        """A capsule of `radius` from `start` to `end` (the link's frame)."""
        start, end = np.asarray(start, float), np.asarray(end, float)
        d = end - start
        length = float(np.linalg.norm(d))
        pitch, yaw = math.acos(d[2] / length), math.atan2(d[1], d[0])  # R = Rz(yaw) Ry(pitch) turns z onto d
        centre = (start + end) / 2.0
        return (f'<collision><origin xyz="{centre[0]:.6g} {centre[1]:.6g} {centre[2]:.6g}" rpy="0 {pitch:.9g} '
                f'{yaw:.9g}"/><geometry><capsule radius="{radius:g}" length="{length:.6g}"/></geometry></collision>')

    lines = ['<?xml version="1.0"?>',
             "<!-- naocal's simulated dual-arm robot (kinds/arm/sim.py dualarm_urdf; written for naocal, no "
             "third-party content): a torso turning about z, two 6-DoF arms, a tool on each -->",
             '<robot name="dualarm">',
             f'  <link name="base_link">{inertial(40.0, (0.0, 0.0, 0.4))}'
             f'{collision(PEDESTAL_RADIUS_M, (0.0, 0.0, PEDESTAL_RADIUS_M), (0.0, 0.0, 0.6))}</link>',
             f'  <link name="torso">{inertial(25.0, (0.0, 0.0, 0.25))}'
             f'{collision(TORSO_RADIUS_M, (0.0, 0.0, 0.0), (0.0, 0.0, TORSO_TOP_M))}</link>',
             joint("torso_joint", "revolute", "base_link", "torso", (0.0, 0.0, TORSO_HEIGHT_M), axis=(0, 0, 1),
                   limits=(-TORSO_LIMIT_RAD, TORSO_LIMIT_RAD))]
    for side, s in (("left", 1.0), ("right", -1.0)):
        parent = "torso"
        for k, (name, xyz, axis, lo, hi, mass) in enumerate(ARM):
            child = f"{side}_link{k + 1}"
            following = ARM[k + 1][1] if k + 1 < len(ARM) else (0.0, 0.0, TOOL_OFFSET_M)
            lines.append(f'  <link name="{child}">{inertial(mass, [v / 2 for v in following])}'
                         f'{collision(LINK_RADIUS_M[k], (0.0, 0.0, 0.0), following)}</link>')
            xyz = (xyz[0], s * xyz[1], xyz[2])
            rpy = (-s * (math.pi / 2.0 - SHOULDER_TILT_RAD), 0.0, 0.0) if k == 0 else (0.0, 0.0, 0.0)
            lines.append(joint(f"{side}_{name}", "revolute", parent, child, xyz, rpy, axis, (lo, hi)))
            parent = child
        lines.append(f'  <link name="{side}_tool">{inertial(TOOL_MASS_KG, (0.0, 0.0, 0.03))}'
                     f'{collision(TOOL_RADIUS_DUAL_M, (0.0, 0.0, 0.0), (0.0, 0.0, TOOL_LENGTH_M))}</link>')
        lines.append(joint(f"{side}_tool_joint", "fixed", parent, f"{side}_tool", (0.0, 0.0, TOOL_OFFSET_M)))
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def dualarm_points() -> dict:
    """{name: (xyz in its tool frame, outward normal or None, chain)}: the corners L_m1_c1..L_m1_c4, ... of the
    printed markers L_m1..L_m5 and R_m1..R_m5 (MARKER_SIZE_M square; four around the tool, one on top; their
    grouping: dualarm_markers), the tracker's reflector R_smr on the right tool."""
    points = {}
    for side, prefix in (("left", "L"), ("right", "R")):
        faces = []
        for i in range(4):
            a = math.pi / 2.0 * i
            normal = np.array([math.cos(a), math.sin(a), 0.0])
            faces.append((normal * MARKER_RING_M + [0.0, 0.0, MARKER_HEIGHT_M], normal,
                          np.array([-math.sin(a), math.cos(a), 0.0])))
        faces.append((np.array([0.0, 0.0, MARKER_HEIGHT_M + 0.02]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0])))
        for i, (centre, normal, u) in enumerate(faces):
            w = np.cross(normal, u)
            for k, (a, b) in enumerate(((-1, 1), (1, 1), (1, -1), (-1, -1))):  # ArUco's order seen from the front
                corner = centre + MARKER_SIZE_M / 2.0 * (a * u + b * w)
                points[f"{prefix}_m{i + 1}_c{k + 1}"] = (tuple(round(float(v), 12) for v in corner), tuple(normal), side)
    points["R_smr"] = (REFLECTOR_M, None, "right")
    return points


def true_intrinsics(filed: dict, error: dict, rng) -> dict:
    """A camera as it is, its calibration filed as `filed`: fx, fy off by N(0, error["f_rel"]) relative, cx, cy by
    N(0, error["c_px"]) px, k1 by N(0, error["k1"]) (CAMERA_FILING_ERROR)."""
    true = dict(filed, distortion=list(filed["distortion"]))
    for key in ("fx_px", "fy_px"):
        true[key] = float(filed[key] * (1.0 + rng.normal(0.0, error["f_rel"])))
    for key in ("cx_px", "cy_px"):
        true[key] = float(filed[key] + rng.normal(0.0, error["c_px"]))
    true["distortion"][0] = float(filed["distortion"][0] + rng.normal(0.0, error["k1"]))
    return true


def dualarm_markers() -> dict:
    """{corner point: its marker} of dualarm_points (the reflector is no marker's)."""
    return {name: name.rpartition("_")[0] for name, (_, normal, _) in dualarm_points().items() if normal is not None}


def dualarm_sheets() -> dict:
    """{marker: the sheet it was printed on} (SHEETS: each tool's markers one sheet)."""
    return {marker: SHEETS["left" if marker.startswith("L_") else "right"]
            for marker in dict.fromkeys(dualarm_markers().values())}


def dualarm_sensors(noise_m, noise_px) -> list:
    return [Sensor("cam_left", "camera", dict(DUAL_CAMERA), noise_px, link="torso"),
            Sensor("cam_right", "camera", dict(DUAL_CAMERA), noise_px, link="torso"),
            Sensor("tracker", "points", noise=noise_m)]


def dualarm_model(effects, sensors=None, noise_m=5e-5, noise_px=0.3):
    """The nominal ArmModel of the dual-arm robot (kinds/arm/data/dualarm.urdf) with these effects."""
    from naocal.kinds.arm.model import ArmModel
    from naocal.kinds.arm.dataset import arm_chains

    chains = arm_chains(DUALARM_URDF, DUALARM_CHAINS)
    points = {name: xyz for name, (xyz, _, _) in dualarm_points().items()}
    return ArmModel(chains, points, sensors if sensors is not None else dualarm_sensors(noise_m, noise_px), effects,
                    markers=dualarm_markers(), sheets=dualarm_sheets())


def _random_vector(rng, low, high) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v) * rng.uniform(low, high)


DUAL_LINK_ERROR_M = (2e-5, 2e-4)  # an industrial robot's machined links: within 0.2 mm of its URDF


def dualarm_truth(rng) -> dict:
    """Hidden errors by parameter name: joint offsets 0.01-0.5 deg, link lengths 0.02-0.2 mm (DUAL_LINK_ERROR_M),
    each tool's mount 1-3 mm and 0.2-0.6 deg, each marker glued 1-2 mm and 0.5-2 deg off, the reflector 1-2 mm."""
    model = dualarm_model(("joint_offsets", "link_lengths", "tool", "points"))
    truth = {}
    for _, p in model.params("joint_offsets"):
        truth[p.name] = float(math.radians(rng.uniform(0.01, 0.5)) * rng.choice((-1.0, 1.0)))
    for _, p in model.params("link_lengths"):
        truth[p.name] = float(rng.uniform(*DUAL_LINK_ERROR_M) * rng.choice((-1.0, 1.0)))
    for ac in model.arm_chains:
        t, r = _random_vector(rng, 1e-3, 3e-3), _random_vector(rng, math.radians(0.2), math.radians(0.6))
        for c, (q, _) in enumerate(POSE_COMPONENTS):
            truth[f"tool.{ac.name}.{q}"] = float((t if c < 3 else r)[c % 3])
    for name, rigid in zip(model.body_names, model.body_rigid):
        d = np.concatenate([_random_vector(rng, 1e-3, 2e-3)]
                           + ([_random_vector(rng, math.radians(0.5), math.radians(2.0))] if rigid else []))
        for (q, _), v in zip(POSE_COMPONENTS, d):
            truth[f"point.{name}.{q}"] = float(v)
    return truth


def _true_origins(model, truth) -> dict:
    """{URDF joint: true xyz}: each origin moved along its offset by its link's hidden length error."""
    from naocal.solver.urdf import parse_urdf

    urdf = parse_urdf(DUALARM_URDF)
    out = {}
    for o, key in enumerate(model.origin_keys):
        delta = truth.get(f"link_length.{model.origin_names[o]}", 0.0)
        if not delta:
            continue
        name = key[1] if key[0] == "joint" else f"{key[1]}_tool_joint"  # the tip offset: the tool's fixed joint
        xyz = np.array(urdf.joints[name].xyz)
        out[name] = tuple(xyz + delta * xyz / np.linalg.norm(xyz))
    return out


DUAL_HIDDEN = ("joint_offsets", "link_lengths", "tool", "points")  # the dual arm's hidden errors, by effect


def simulate_dualarm(out, *, seed=0, n_poses=600, sessions=3, noise_m=5e-5, noise_px=0.3, outlier_fraction=0.02,
                     camera_error=None, print_scale_error=PRINT_SCALE_ERROR, write=True, hidden=DUAL_HIDDEN,
                     stance_seed=None):
    """The dual-arm robot measured: a naocal.arm_dataset/1 directory `out` with chains (left, right), the cameras
    on the torso, the tracker, and out/truth.json (write=False: nothing written). Returns {"observations",
    "mistaken" (a bool per observation: the outliers drawn; truth.json's "mistaken_detections"), "truth", "sensors",
    "points", "n_poses"}.

    Readings are drawn uniformly inside the joint limits less a margin (the torso within +-0.6 rad) and kept when
    both tools are in front of the torso (torso frame x > 0.3 m, 0.25 m apart, neither below the torso's floor
    clearance); the true robot is PyBullet's (the URDF with the true link lengths) at q = theta - c, the tool
    mounts and markers placed on its tool links. A camera detects a marker in its image that faces it within 65
    deg (pixel noise `noise_px`); `outlier_fraction` of the detections are wrong by 8-40 px (a corner mistaken).
    The tracker reads the reflector at every pose (noise `noise_m` per axis). Poses are labelled by session, and
    each row says its session (`sessions` blocks of consecutive poses).

    `camera_error` (None: the cameras are exactly as filed; else sizes as CAMERA_FILING_ERROR): each camera's true
    intrinsics drawn off the filed DUAL_CAMERA (true_intrinsics; its own random stream, so the rest of the draws
    stay the seed's); the pixels are the true cameras', the dataset files DUAL_CAMERA, and the returned
    "intrinsics" and truth.json's "intrinsics" hold the true ones.

    `print_scale_error` (default PRINT_SCALE_ERROR, 0.3 %; 0: printed exactly): each marker sheet (SHEETS: each
    tool's five markers) printed at a scale 1 + N(0, print_scale_error), its own random stream (the rest of the
    draws stay the seed's): every true corner lies that much further from its marker's centre than the dataset's
    MARKER_SIZE_M says. The dataset names each marker's sheet (`"sheet"`); the returned "print_scale" and
    truth.json's hold {sheet: scale}, and the truth's `marker_scale.<sheet>` the relative error (scale - 1).

    `hidden` (default DUAL_HIDDEN: all of them): the effects whose errors the robot has; the others' are drawn
    as ever (the rest of the draws stay the seed's) and then made exact (0): what a fit lacking an effect leaves
    in its residual is measured by switching that effect off here (benchmarks/bench_dual_arm_residual.py).

    `stance_seed` (None: the seed's own stream): another session of the same robot. The robot (its hidden errors,
    sensors' frames, print, cameras) stays the seed's; the stances, noise and outliers are drawn from their own
    stream for this stance seed, so the session shares no reading with the seed's own (`naocal verify` on it)."""
    import json

    from naocal.body.pybullet_quiet import c_output_silenced, pybullet
    from naocal.solver.camera import project_points

    rng = np.random.default_rng([seed, 24])
    model = dualarm_model(("joint_offsets", "link_lengths", "tool", "points"), noise_m=noise_m, noise_px=noise_px)
    unknown = set(hidden) - set(DUAL_HIDDEN)
    if unknown:
        raise NaocalError(f"simulate_dualarm: hidden {sorted(unknown)}: not among {', '.join(DUAL_HIDDEN)}")
    effect_of = {p.name: p.effect for p in model.parameters}
    truth = {name: value if effect_of[name] in hidden else 0.0 for name, value in dualarm_truth(rng).items()}
    x_true = np.array([truth.get(n, 0.0) for n in model.names])
    # the sensors: cameras on the torso's head looking down at the work area, a tracker 2.5-3 m in front
    frames = {}
    for name, y in (("cam_left", 0.08), ("cam_right", -0.08)):
        eye = np.array([0.12, y, 0.6]) + rng.normal(0.0, 0.01, 3)
        R = look_at(eye, (0.6, 0.0, 0.15)) @ exp_so3(rng.normal(size=3) * 0.02)  # R_torso_cam
        frames[name] = (R.T, -R.T @ eye)
    eye = np.array([2.8, -0.6, 1.4]) + rng.normal(0.0, 0.1, 3)
    R = exp_so3(rng.normal(size=3))
    frames["tracker"] = (R.T, -R.T @ eye)
    for name, (R, t) in frames.items():
        rotvec = log_so3(R)
        for c, a in enumerate("xyz"):
            truth[f"sensor.{name}.rotation.{a}"] = float(rotvec[c])
            truth[f"sensor.{name}.translation.{a}"] = float(t[c])
    tools = {}
    for ac in model.arm_chains:
        v = [truth[f"tool.{ac.name}.{q}"] for q, _ in POSE_COMPONENTS]
        tools[ac.name] = (exp_so3(v[3:]), np.array(v[:3]))
    points = dualarm_points()
    markers = {}  # marker (the reflector: its own) -> its corners
    for name in points:
        markers.setdefault(dualarm_markers().get(name, name), []).append(name)
    glued, levers = model.tool_points(x_true)  # the markers' corners as glued, each from its marker's centre
    scale_rng = np.random.default_rng([seed, 24, 2])
    print_scale = {sheet: float(1.0 + (scale_rng.normal(0.0, print_scale_error) if print_scale_error else 0.0))
                   for sheet in SHEETS.values()}
    for sheet, scale in print_scale.items():
        truth[f"marker_scale.{sheet}"] = scale - 1.0
    sheet_of = dualarm_sheets()
    printed = np.array([print_scale[sheet_of[model.markers[name]]] if name in model.markers else 1.0
                        for name in model.point_names])
    on_tool = dict(zip(model.point_names, glued + (printed - 1.0)[:, None] * levers))  # as printed and glued
    cameras = ("cam_left", "cam_right")
    camera_rng = np.random.default_rng([seed, 24, 1])
    intrinsics = {cam: dict(DUAL_CAMERA) if camera_error is None else true_intrinsics(DUAL_CAMERA, camera_error,
                                                                                      camera_rng) for cam in cameras}

    client = pybullet.connect(pybullet.DIRECT)
    tmp = tempfile.TemporaryDirectory(prefix="naocal-dualarm-")
    try:
        true_urdf = Path(tmp.name) / "true.urdf"
        true_urdf.write_text(dualarm_urdf(_true_origins(model, truth)), encoding="utf-8")
        with c_output_silenced():
            body = pybullet.loadURDF(str(true_urdf), useFixedBase=True, physicsClientId=client)
        info = [pybullet.getJointInfo(body, i, physicsClientId=client)
                for i in range(pybullet.getNumJoints(body, physicsClientId=client))]
        joint_index = {i[1].decode(): i[0] for i in info}
        link_index = {i[12].decode(): i[0] for i in info}
        self_collision = SelfCollision(pybullet, client, body)  # in the URDF's zero stance: arms out and up
        from naocal.solver.urdf import parse_urdf

        urdf = parse_urdf(DUALARM_URDF)
        joints = model.joint_names
        lo = np.array([urdf.joints[j].lower for j in joints])
        hi = np.array([urdf.joints[j].upper for j in joints])
        margin = np.maximum(LIMIT_MARGIN_RAD, LIMIT_MARGIN_FRACTION * (hi - lo))
        lo, hi = lo + margin, hi - margin
        torso = joints.index("torso_joint")
        lo[torso], hi[torso] = -0.6, 0.6
        offsets = np.array([truth[f"joint_offset.{j}"] for j in joints])

        def pose_of(link):
            state = pybullet.getLinkState(body, link_index[link], computeForwardKinematics=True,
                                          physicsClientId=client)
            return np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3), np.array(state[4])

        if stance_seed is not None:  # the robot above is the seed's; what is measured of it, this session's
            rng = np.random.default_rng([seed, 24, 3, stance_seed])
        rows, pose_labels = [], []
        tries = colliding = 0
        while len(pose_labels) < n_poses:
            tries += 1
            if tries > 400 * n_poses:
                raise NaocalError(f"found only {len(pose_labels)} of {n_poses} stances with both tools in front")
            theta = rng.uniform(lo, hi)
            for j, angle in zip(joints, theta - offsets):
                pybullet.resetJointState(body, joint_index[j], float(angle), physicsClientId=client)
            R_torso, t_torso = pose_of("torso")
            tool_frames = {}
            for ac in model.arm_chains:
                R_tip, t_tip = pose_of(ac.chain.tip)
                R_tool, t_tool = tools[ac.name]
                tool_frames[ac.name] = (R_tip @ R_tool, t_tip + R_tip @ t_tool)
            in_torso = {c: R_torso.T @ (t - t_torso) for c, (_, t) in tool_frames.items()}
            if (min(p[0] for p in in_torso.values()) < 0.3 or min(p[2] for p in in_torso.values()) < -0.6
                    or np.linalg.norm(in_torso["left"] - in_torso["right"]) < 0.25):
                continue
            if self_collision.colliding() is not None:  # never a stance whose arms, tools or torso touch
                colliding += 1
                continue
            pose = len(pose_labels)
            seen = []
            for marker, corners in markers.items():
                _, normal, chain = points[corners[0]]
                R_tool, t_tool = tool_frames[chain]
                c = 0 if chain == "left" else 1
                p_base = np.array([R_tool @ on_tool[name] + t_tool for name in corners])
                if normal is None:  # the reflector: the tracker, in the base frame
                    R, t = frames["tracker"]
                    seen.append((pose, c, 2, marker, theta, R @ p_base[0] + t + rng.normal(0.0, noise_m, 3), False))
                    continue
                p_torso = (p_base - t_torso) @ R_torso
                n_torso = R_torso.T @ (R_tool @ normal)
                for s, cam in enumerate(cameras):
                    R, t = frames[cam]
                    eye = -R.T @ t
                    to_eye = eye - p_torso.mean(axis=0)
                    if n_torso @ to_eye < math.cos(MARKER_VIEW_RAD) * np.linalg.norm(to_eye):
                        continue
                    uv, depth = project_points(p_torso @ R.T + t, intrinsics[cam])
                    if not (np.all(depth > 0.2) and np.all(uv >= IMAGE_MARGIN_PX)
                            and np.all(uv[:, 0] <= DUAL_CAMERA["width_px"] - 1 - IMAGE_MARGIN_PX)
                            and np.all(uv[:, 1] <= DUAL_CAMERA["height_px"] - 1 - IMAGE_MARGIN_PX)):
                        continue  # a marker is detected with all its corners in the image
                    for name, corner in zip(corners, uv):
                        corner = corner + rng.normal(0.0, noise_px, 2)
                        mistaken = rng.random() < outlier_fraction
                        if mistaken:
                            corner = corner + _random_vector(rng, 8.0, 40.0)[:2]
                        seen.append((pose, c, s, name, theta, np.array([corner[0], corner[1], 0.0]), mistaken))
            if len({(r[1], r[2]) for r in seen if r[2] < 2}) < 3:  # each stance was chosen for the cameras to see
                continue  # markers of both tools: at least three (tool, camera) pairs
            rows += seen
            pose_labels.append(f"s{pose * sessions // n_poses + 1}-{pose:04d}")
    finally:
        pybullet.disconnect(physicsClientId=client)
        tmp.cleanup()
    names = list(points)
    pose = np.array([r[0] for r in rows])
    obs = Observations(np.array([r[4] for r in rows]), pose, np.array([r[2] for r in rows]),
                       np.array([names.index(r[3]) for r in rows]), np.array([r[5] for r in rows]), None,
                       tuple(pose_labels), np.array([r[1] for r in rows]), pose * sessions // n_poses,
                       tuple(f"s{k + 1}" for k in range(sessions)))
    sensors = dualarm_sensors(noise_m, noise_px)
    mistaken = np.array([r[6] for r in rows], dtype=bool)  # the truth of the outliers: which detections were made wrong
    result = {"observations": obs, "truth": truth, "sensors": sensors, "mistaken": mistaken,
              "points": {n: xyz for n, (xyz, _, _) in points.items()}, "markers": dualarm_markers(),
              "n_poses": n_poses, "x_true": x_true, "intrinsics": intrinsics,
              "refused_colliding": colliding, "print_scale": print_scale, "sheets": dualarm_sheets()}
    if write:
        from naocal.kinds.arm.dataset import write_arm_dataset
        from naocal.solver.fileio import atomic_write_text

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "robot.urdf", DUALARM_URDF.read_text(encoding="utf-8"))
        meta = {
            "robot": {"id": f"simulated-dualarm-{seed}", "model": "dualarm", "urdf": "robot.urdf"},
            "chains": {c: {"base": b, "tip": t} for c, (b, t) in DUALARM_CHAINS.items()},
            "points": {n: dict({"xyz_m": list(xyz)}, **({"marker": result["markers"][n],
                                                          "sheet": result["sheets"][result["markers"][n]]}
                                                         if n in result["markers"] else {}))
                       for n, xyz in result["points"].items()},
            "sensors": {"cam_left": dict({"kind": "camera", "noise_px": noise_px, "link": "torso"}, **DUAL_CAMERA),
                        "cam_right": dict({"kind": "camera", "noise_px": noise_px, "link": "torso"}, **DUAL_CAMERA),
                        "tracker": {"kind": "points", "noise_m": noise_m}},
            "source": f"naocal simulate --robot dualarm --seed {seed}"
                      + (f" --stance-seed {stance_seed}" if stance_seed is not None else "")
                      + f" (PyBullet; {n_poses} stances in {sessions} "
                      "sessions)",
        }
        write_arm_dataset(out, meta, model.joint_names, obs, sensors, result["points"],
                          chain_names=[ac.name for ac in model.arm_chains])
        truth_doc = {"schema": "naocal.arm_truth/1", "parameters": truth,
                     "noise": {"tracker_m": noise_m, "camera_px": noise_px, "outlier_fraction": outlier_fraction},
                     "hidden": list(hidden) + (["marker_scale"] if print_scale_error else []), "intrinsics": intrinsics,
                     "camera_error": camera_error, "print_scale_error": print_scale_error,
                     "print_scale": print_scale,
                     "mistaken_detections": [{"pose": obs.pose_name(obs.pose[k]), "sensor": sensors[obs.sensor[k]].name,
                                              "point": names[obs.point[k]]} for k in np.flatnonzero(mistaken)]}
        atomic_write_text(out / "truth.json", json.dumps(truth_doc, indent=1) + "\n")
    return result
