"""The measurement model of a serial arm from its URDF (docs/ARM.md): forward kinematics with per-joint and per-link
errors, mapped into the frame of an external sensor that sees points on the end effector, and its exact Jacobian.

For one observation (joint readings theta, a point p on the tip link, a sensor s):

    q_k   = theta_k - c_k + C_k * tau_k(theta)            c: joint_offset (the NAO's sign), C: elasticity
    A_k   = F_{k-1} @ T_origin_k(+ length_k along its offset) @ Trans(t_k) @ Exp(r_k)      link_pose (t, r)
    F_k   = A_k @ Rot(axis_k, q_k)                       F_{-1} = the chain's base frame
    p_b   = F_{n-1} @ T_end(+ length_n along its offset) @ (p0 + dp)                          points (dp)
    y     = Exp(dR_s) @ R0_s @ p_b + t_s                 the sensor's frame: T_sensor_base = (R_s, t_s)
    3-D sensor: residual = y - measured (m);  camera: residual = project(y) - measured (px, solver/camera.py)

tau_k is the static gravity torque about joint k of the links beyond it (URDF masses), at the readings theta: a
fixed regressor, so the model stays exact in its parameters. Everything is pure and vectorised over observations.
Rotation corrections use the exponential map; their exact derivative is the left Jacobian of SO(3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from naocal.solver.measurement import MEASUREMENTS
from naocal.solver.transforms import rot_axis_angle, skew

# The arm's effects: name -> what it is. The sensor frames are always in the model.
EFFECTS = {
    "joint_offsets": "encoder offset c of each joint (q = theta - c), rad",
    "link_lengths": "each link longer than the URDF says, along its origin offset, m",
    "link_poses": "full pose error of each joint origin: translation (m) and rotation (rad) in the joint frame",
    "points": "position error of each observed point on the end effector (tip frame), m",
    "elasticity": "joint compliance under the static gravity torque of the URDF masses, rad/(N m)",
}
DEFAULT_EFFECTS = ("joint_offsets", "link_lengths")
# Each effect's plausible size per unit: the std of its Gaussian prior (solver.arm_identify.arm_prior) about the
# URDF's value (every correction 0), and, times solver.arm_identify.RUNOFF_FACTOR, the value a fit must not land
# beyond. The sensor frames have none: they may be anywhere.
PRIOR_SIZE = {
    "joint_offsets": {"rad": math.radians(2.0)},  # encoder zeros are off by degrees at most
    "link_lengths": {"m": 2e-3},  # a machined link is off by millimetres
    "link_poses": {"m": 2e-3, "rad": math.radians(1.0)},
    "points": {"m": 3e-3},  # a marker or reflector glued by hand
    "elasticity": {"rad/(N m)": math.radians(0.05)},  # 0.5 deg under 10 N m: a soft gear
}
# The gauges' order (solver.identify.gauges, via solver.arm_identify.identifiable): of parameters the data cannot
# tell apart, the earlier group stays free and the later is fixed; a sensor frame is never fixed.
PRIORITY = ("sensor", "joint_offsets", "link_lengths", "points", "link_poses", "elasticity")
POINT_KINDS = tuple(MEASUREMENTS)  # the sensors' measurement kinds (solver.measurement)
AXES = "xyz"


@dataclass(frozen=True)
class ArmParameter:
    """One scalar parameter: `index` is the joint origin (0..n, n = the tip), sensor or point it belongs to;
    `component` which of its quantities (0-2 x, y, z; link pose 3-5 the rotation about x, y, z)."""

    name: str
    effect: str  # an EFFECTS key or 'sensor'
    unit: str
    scale: float
    index: int
    component: int = 0
    kind: str = ""  # sensor: 'rotation' or 'translation'


@dataclass(frozen=True)
class Sensor:
    """An external sensor: 'points' (3-D, m) or 'camera' (pixels; NAO camera frame: x optical axis, y left, z up)."""

    name: str
    kind: str
    intrinsics: dict | None = None
    noise: float | None = None  # m or px, when known
    prior_rotation: tuple | None = None  # rotation vector of R_sensor_base, rad
    prior_translation: tuple | None = None  # t_sensor_base, m


@dataclass
class Observations:
    """N observations: joint readings theta (N, n) in chain order, pose id, sensor and point indices, the measured
    point (N, 3) for 3-D sensors or pixel (N, 2 in [:, :2]) for cameras; `source_line` for messages;
    `pose_labels` the file's text label of each pose id (None: the ids are the file's own numbers)."""

    theta: np.ndarray
    pose: np.ndarray
    sensor: np.ndarray
    point: np.ndarray
    measured: np.ndarray
    source_line: np.ndarray | None = None
    pose_labels: tuple | None = None

    def __len__(self):
        return len(self.pose)

    def pose_name(self, pose: int):
        """A pose as the user's file names it: its text label, or its number."""
        return self.pose_labels[pose] if self.pose_labels is not None else int(pose)

    def subset(self, rows) -> "Observations":
        return Observations(self.theta[rows], self.pose[rows], self.sensor[rows], self.point[rows],
                            self.measured[rows], None if self.source_line is None else self.source_line[rows],
                            self.pose_labels)


def exp_so3(phi) -> np.ndarray:
    """Rotation matrix of a rotation vector (3,) (Rodrigues)."""
    phi = np.asarray(phi, dtype=float)
    angle = float(np.linalg.norm(phi))
    if angle < 1e-12:
        return np.eye(3) + skew(phi)
    return rot_axis_angle(phi / angle, angle)


def log_so3(R) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = math.acos(cos)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-8:
        return w / 2.0
    if angle > math.pi - 1e-6:  # near pi: the axis from the symmetric part
        B = (R + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(B), 0.0, None))
        i = int(np.argmax(axis))
        axis = B[i] / axis[i]
        axis /= np.linalg.norm(axis)
        if np.dot(axis, w) < 0:
            axis = -axis
        return axis * angle
    return w * angle / (2.0 * math.sin(angle))


def left_jacobian(phi) -> np.ndarray:
    """J_l(phi): Exp(phi + e) = Exp(J_l(phi) e) Exp(phi) to first order in e."""
    phi = np.asarray(phi, dtype=float)
    angle = float(np.linalg.norm(phi))
    K = skew(phi)
    if angle < 1e-6:
        return np.eye(3) + K / 2.0 + K @ K / 6.0
    return (np.eye(3) + (1.0 - math.cos(angle)) / angle ** 2 * K
            + (angle - math.sin(angle)) / angle ** 3 * (K @ K))


def _times(A, M) -> np.ndarray:
    """A @ M for a stack A (N, 3, 3) and one M (3, 3) or (3,): as one (3 N, 3) product (numpy's stacked matmul
    of small matrices is some 40 times slower)."""
    return (A.reshape(-1, 3) @ M).reshape(A.shape[:2] + np.shape(M)[1:])


def _turned(A, axis, angle) -> np.ndarray:
    """A @ Rot(axis, angle) for a stack A (N, 3, 3) and angles (N,), by Rodrigues: A + sin A K + (1 - cos) A K^2."""
    K = skew(axis)
    return (A + np.sin(angle)[:, None, None] * _times(A, K)
            + (1.0 - np.cos(angle))[:, None, None] * _times(A, K @ K))


class ArmModel:
    """The arm's parameters and its model for one chain, one set of sensors and points, and a choice of effects.

    chain: solver.robot.Chain (base to tip); points: {name: (3,) nominal position in the tip frame, m};
    sensors: [Sensor]; effects: names of EFFECTS; gravity_mps2 (3,) in the base frame; load: (mass kg, com (3,) in
    the tip frame) of what the tip carries, for the gravity torques.
    """

    def __init__(self, chain, points: dict, sensors, effects=DEFAULT_EFFECTS, gravity_mps2=(0.0, 0.0, -9.81),
                 load=(0.0, (0.0, 0.0, 0.0)), link_names=None):
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise ValueError(f"unknown arm effect {unknown[0]!r} (expected one of {', '.join(EFFECTS)})")
        self.chain = chain
        self.point_names = tuple(points)
        self.point_xyz = np.array([points[p] for p in self.point_names], dtype=float).reshape(-1, 3)
        self.sensors = tuple(sensors)
        self.effects = tuple(e for e in EFFECTS if e in effects)
        self.gravity_mps2 = np.asarray(gravity_mps2, dtype=float)
        self.load = (float(load[0]), np.asarray(load[1], dtype=float))
        n = len(chain.joint_names)
        offsets = [chain.T_origin[k, :3, 3] for k in range(n)] + [chain.T_end[:3, 3]]
        self.link_names = tuple(link_names or [f"link{k}" for k in range(n + 1)])  # the link each origin ends
        self.directions = [o / np.linalg.norm(o) if np.linalg.norm(o) > 1e-9 else None for o in offsets]
        self.R0 = np.array([exp_so3(s.prior_rotation or (0.0, 0.0, 0.0)) for s in self.sensors]).reshape(-1, 3, 3)
        self.parameters = self._parameters()
        self.names = tuple(p.name for p in self.parameters)
        self._by_effect = {}
        for i, p in enumerate(self.parameters):
            self._by_effect.setdefault(p.effect, []).append((i, p))

    # -- parameters

    def _parameters(self) -> list[ArmParameter]:
        params = []
        for s, sensor in enumerate(self.sensors):
            params += [ArmParameter(f"sensor.{sensor.name}.rotation.{a}", "sensor", "rad", 0.01, s, c, "rotation")
                       for c, a in enumerate(AXES)]
            params += [ArmParameter(f"sensor.{sensor.name}.translation.{a}", "sensor", "m", 0.01, s, c,
                                    "translation") for c, a in enumerate(AXES)]
        joints = self.chain.joint_names
        if "joint_offsets" in self.effects:
            params += [ArmParameter(f"joint_offset.{j}", "joint_offsets", "rad", 1e-3, k) for k, j in enumerate(joints)]
        if "link_lengths" in self.effects:
            params += [ArmParameter(f"link_length.{self.link_names[k]}", "link_lengths", "m", 1e-3, k)
                       for k, d in enumerate(self.directions) if d is not None]
        if "points" in self.effects:
            params += [ArmParameter(f"point.{p}.{a}", "points", "m", 1e-3, i, c)
                       for i, p in enumerate(self.point_names) for c, a in enumerate(AXES)]
        if "link_poses" in self.effects:
            params += [ArmParameter(f"link_pose.{self.link_names[k]}.{q}", "link_poses", unit, 1e-3, k, c)
                       for k in range(len(joints))
                       for c, (q, unit) in enumerate([("x", "m"), ("y", "m"), ("z", "m"),
                                                      ("rx", "rad"), ("ry", "rad"), ("rz", "rad")])]
        if "elasticity" in self.effects:
            params += [ArmParameter(f"elasticity.{j}", "elasticity", "rad/(N m)", 1e-3, k)
                       for k, j in enumerate(joints)]
        return params

    def params(self, effect):
        return self._by_effect.get(effect, [])

    @property
    def scales(self) -> np.ndarray:
        return np.array([p.scale for p in self.parameters])

    def initial_values(self) -> np.ndarray:
        """Zero corrections; each sensor's translation at its prior (its rotation prior is R0)."""
        x = np.zeros(len(self.parameters))
        for i, p in self.params("sensor"):
            if p.kind == "translation":
                x[i] = (self.sensors[p.index].prior_translation or (0.0, 0.0, 0.0))[p.component]
        return x

    def sensor_correction(self, x, s) -> np.ndarray:
        """The rotation vector (3,) of sensor s's correction: R_sensor_base = Exp(correction) @ R0."""
        d = np.zeros(3)
        for i, p in self.params("sensor"):
            if p.index == s and p.kind == "rotation":
                d[p.component] = x[i]
        return d

    def sensor_pose(self, x, s) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of T_sensor_base of sensor s at parameter values x."""
        t = np.zeros(3)
        for i, p in self.params("sensor"):
            if p.index == s and p.kind == "translation":
                t[p.component] = x[i]
        return exp_so3(self.sensor_correction(x, s)) @ self.R0[s], t

    def rebase_sensors(self, x) -> np.ndarray:
        """Fold the sensors' rotation corrections of x into R0; returns x with those corrections zero."""
        x = np.array(x, dtype=float)
        for s in range(len(self.sensors)):
            self.R0[s] = self.sensor_pose(x, s)[0]
        for i, p in self.params("sensor"):
            if p.kind == "rotation":
                x[i] = 0.0
        return x

    def reported_values(self, x) -> dict:
        """{name: value} as people and truth.json read them: a sensor's rotation is the rotation vector of
        R_sensor_base (not the correction the solver works on)."""
        out = dict(zip(self.names, (float(v) for v in x)))
        for s, sensor in enumerate(self.sensors):
            rotvec = log_so3(self.sensor_pose(x, s)[0])
            for c, a in enumerate(AXES):
                out[f"sensor.{sensor.name}.rotation.{a}"] = float(rotvec[c])
        return out

    # -- gravity

    def gravity_torques(self, theta) -> np.ndarray:
        """(N, n) static gravity torques about each joint at the readings (nominal URDF geometry and masses)."""
        from naocal.solver.kinematics import chain_gravity_torques

        return chain_gravity_torques(self.chain, theta, self.gravity_mps2, load_mass_kg=self.load[0],
                                     load_com_m=self.load[1])

    # -- the model

    def base_points(self, x, obs: Observations) -> np.ndarray:
        """(N, 3) the observed points in the chain's base frame (before any sensor)."""
        return self.predict(x, obs, base_frame=True)

    def predict(self, x, obs: Observations, *, jacobian=False, tau=None, base_frame=False):
        """Predicted measurements (N, 3) (cameras: pixels in [:, :2], 0 in [:, 2]) and with `jacobian` also
        d prediction / d x (N, 3, P)."""
        chain = self.chain
        n = len(chain.joint_names)
        N = len(obs)
        P = len(self.parameters)
        lengths = np.zeros(n + 1)
        for i, p in self.params("link_lengths"):
            lengths[p.index] = x[i]
        pose_t = np.zeros((n, 3))
        pose_r = np.zeros((n, 3))
        for i, p in self.params("link_poses"):
            (pose_t if p.component < 3 else pose_r)[p.index, p.component % 3] = x[i]
        q = np.array(obs.theta, dtype=float)
        for i, p in self.params("joint_offsets"):
            q[:, p.index] -= x[i]
        if self.params("elasticity"):
            tau = self.gravity_torques(obs.theta) if tau is None else tau
            for i, p in self.params("elasticity"):
                q[:, p.index] += x[i] * tau[:, p.index]
        R = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
        t = np.zeros((N, 3))
        frames = []  # per joint: (R before origin, R_B, R_G, origin o, axis a in base)
        for k in range(n):
            offset = chain.T_origin[k, :3, 3] + (lengths[k] * self.directions[k] if self.directions[k] is not None
                                                 else 0.0)
            R_prev = R
            R_B = _times(R, chain.T_origin[k, :3, :3])
            t = t + _times(R, offset)
            t = t + _times(R_B, pose_t[k])
            E = exp_so3(pose_r[k])
            R_A = _times(R_B, E)
            a = _times(R_A, chain.axes[k])
            frames.append((R_prev, R_B, t.copy(), a, E))
            R = _turned(R_A, chain.axes[k], q[:, k])
        offset_end = chain.T_end[:3, 3] + (lengths[n] * self.directions[n] if self.directions[n] is not None else 0.0)
        R_prev_end = R
        t_end = t + _times(R, offset_end)
        R_end = _times(R, chain.T_end[:3, :3])
        p_tip = self.point_xyz[obs.point].copy()
        for i, p in self.params("points"):
            p_tip[obs.point == p.index, p.component] += x[i]
        p_b = t_end + np.einsum("nij,nj->ni", R_end, p_tip)
        if base_frame:
            return p_b
        # into the sensors
        R_s = np.empty((len(self.sensors), 3, 3))
        t_s = np.empty((len(self.sensors), 3))
        for s in range(len(self.sensors)):
            R_s[s], t_s[s] = self.sensor_pose(x, s)
        rows_of = [np.flatnonzero(obs.sensor == s) for s in range(len(self.sensors))]
        y = np.empty_like(p_b)
        for s, rows in enumerate(rows_of):  # one rotation per sensor: one BLAS product each
            y[rows] = p_b[rows] @ R_s[s].T + t_s[s]
        pred = np.empty_like(y)
        dpred_dy = {}  # per sensor: its rows and d prediction / d y, unless the identity (3-D points)
        for s, (sensor, rows) in enumerate(zip(self.sensors, rows_of)):
            pred[rows], D = MEASUREMENTS[sensor.kind].predict(y[rows], sensor)
            if sensor.kind != "points":
                dpred_dy[s] = (rows, D)
        if not jacobian:
            return pred
        Jb = np.zeros((N, 3, P))  # d p_b / d x
        Js = np.zeros((N, 3, P))  # d y / d x beyond R_s d p_b
        for i, p in self.params("joint_offsets"):
            _, _, o, a, _ = frames[p.index]
            Jb[:, :, i] = -np.cross(a, p_b - o)
        if self.params("elasticity"):
            for i, p in self.params("elasticity"):
                _, _, o, a, _ = frames[p.index]
                Jb[:, :, i] = tau[:, p.index, None] * np.cross(a, p_b - o)
        for i, p in self.params("link_lengths"):
            R_before = R_prev_end if p.index == n else frames[p.index][0]
            Jb[:, :, i] = _times(R_before, self.directions[p.index])
        for i, p in self.params("link_poses"):
            _, R_B, o, _, _ = frames[p.index]
            if p.component < 3:
                Jb[:, :, i] = R_B[:, :, p.component]
            else:
                w = left_jacobian(pose_r[p.index])[:, p.component - 3]
                Jb[:, :, i] = np.cross(_times(R_B, w), p_b - o)
        for i, p in self.params("points"):
            rows = obs.point == p.index
            Jb[rows, :, i] = R_end[rows, :, p.component]
        for i, p in self.params("sensor"):
            rows = obs.sensor == p.index
            if p.kind == "translation":
                Js[rows, p.component, i] = 1.0
            else:
                w = left_jacobian(self.sensor_correction(x, p.index))[:, p.component]
                Js[rows, :, i] = np.cross(w, y[rows] - t_s[p.index])
        J = Js
        for s, rows in enumerate(rows_of):
            turned = np.swapaxes(Jb[rows], 1, 2).reshape(-1, 3) @ R_s[s].T  # (n P, 3): one BLAS product
            J[rows] += np.swapaxes(turned.reshape(len(rows), P, 3), 1, 2)
        for s, (rows, D) in dpred_dy.items():
            J[rows] = np.einsum("nij,njp->nip", D, J[rows])
        return pred, J

    def component_mask(self, obs: Observations) -> np.ndarray:
        """(N, 3) which components of a prediction are measured (cameras: u, v only)."""
        mask = np.ones((len(obs), 3), dtype=bool)
        for s, sensor in enumerate(self.sensors):
            mask[obs.sensor == s] = MEASUREMENTS[sensor.kind].measured
        return mask
