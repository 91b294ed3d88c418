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

from naocal.solver.arm import Observations, Sensor, exp_so3, log_so3
from naocal.solver.arm_dataset import arm_chain
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
        self.parent = {i[0]: i[16] for i in info}
        mid = [(lo + hi) / 2.0 for lo, hi in self.limits()]
        self._set(mid)
        self.ignored_pairs = {pair for pair in self._link_pairs() if self._close(*pair)}
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

    def _link_pairs(self):
        n = self._p.getNumJoints(self.body, physicsClientId=self._client)
        return [(a, b) for a in range(-1, n) for b in range(a + 1, n) if self.parent.get(b) != a]

    def _close(self, a, b) -> bool:
        return bool(self._p.getClosestPoints(self.body, self.body, SELF_DISTANCE_M, linkIndexA=a, linkIndexB=b,
                                             physicsClientId=self._client))

    def _link_low(self, link) -> bool:
        lo, _ = self._p.getAABB(self.body, link, physicsClientId=self._client)
        return lo[2] < FLOOR_CLEARANCE_M

    def collides(self) -> bool:
        if any(self._close(a, b) for a, b in self._link_pairs() if (a, b) not in self.ignored_pairs):
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

    from naocal.solver.arm_dataset import write_arm_dataset
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
