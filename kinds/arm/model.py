"""The measurement model of a serial arm from its URDF (docs/ARM.md): forward kinematics with per-joint and per-link
errors, mapped into the frame of an external sensor that sees points on the end effector, and its exact Jacobian.

For one observation (joint readings theta, a point p on the tip link of the observation's chain, a sensor s):

    q_k   = theta_k - c_k + C_k * tau_k(theta)            c: joint_offset (the NAO's sign), C: elasticity
    A_k   = F_{k-1} @ T_origin_k(+ length_k along its offset) @ Trans(t_k) @ Exp(r_k)      link_pose (t, r)
    F_k   = A_k @ Rot(axis_k, q_k)   (prismatic: A_k @ Trans(axis_k q_k))   F_{-1} = the sensor's mount (the base)
    p_b   = F_{n-1} @ T_end(+ length_n along its offset) @ (t_T + Exp(r_T) p_tool)     tool (t_T, r_T)
    p_tool = p0 + t_m + ((1 + m_s) Exp(r_m) - I)(p0 - c_m)    points: a marker's corners move as one rigid body (t_m,
                                                      r_m about its centre c_m: its printed size is kept), a lone point
                                                      by t_m; marker_scale: m_s of the sheet s it was printed on
    y     = Exp(dR_s) @ R0_s @ p_b + t_s                 the sensor's frame: T_sensor_mount = (R_s, t_s)
    K_s   = the camera's filed intrinsics + (dfx, dfy, dcx, dcy; dk1, dk2, dp1, dp2, dk3)  intrinsics (a camera's)

Several chains (two arms on one torso) share joints, joint origins and sensors by name: a joint's offset is one
parameter whichever chain moves it. A sensor mounted on a link of the chains (a camera on the torso) sees the
points in that link's frame: the joints before it do not move them.
    3-D sensor: residual = y - measured (m);  camera: residual = project(y; K_s) - measured (px, solver/camera.py)

tau_k is the static gravity torque about joint k of the links beyond it (URDF masses), at the readings theta: a
fixed regressor, so the model stays exact in its parameters. Everything is pure and vectorised over observations.
Rotation corrections use the exponential map; their exact derivative is the left Jacobian of SO(3).

Each term is an effect of solver/effects/ (one module each, the NAO's too): the model takes its parameters from
the effects' `arm_parameters`, in their gauge order (the sensors' frames, joint_offsets, link_lengths, tool,
points, marker_scale, link_poses, elasticity, intrinsics), and the joint terms (c, C) from their `joint_terms`, the NAO model's hook.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from naocal.solver.camera import distortion_of
from naocal.solver.effects import ARM_EFFECTS, ARM_MODEL_EFFECTS, EFFECTS, defines
from naocal.solver.effects.intrinsics import DISTORTION
from naocal.solver.measurement import MEASUREMENTS
from naocal.solver.transforms import rot_axis_angle, skew

DEFAULT_EFFECTS = ("joint_offsets", "link_lengths")  # the effects (solver.effects.ARM_EFFECTS) of a plain fit
POINT_KINDS = tuple(MEASUREMENTS)  # the sensors' measurement kinds (solver.measurement)


@dataclass(frozen=True)
class Sensor:
    """An external sensor: 'points' (3-D, m) or 'camera' (pixels; NAO camera frame: x optical axis, y left, z up)."""

    name: str
    kind: str
    intrinsics: dict | None = None
    noise: float | None = None  # m or px, when known
    prior_rotation: tuple | None = None  # rotation vector of R_sensor_base, rad
    prior_translation: tuple | None = None  # t_sensor_base, m
    link: str | None = None  # the URDF link it is mounted on (None: the chains' base), e.g. a camera on a torso


@dataclass(frozen=True)
class ArmChain:
    """One serial chain of a model with several (two arms on one torso): `chain` (solver.robot.Chain, base to tip),
    `link_names` the link each joint origin (and the tip offset) ends, `load` (mass kg, com in the tip frame) what
    the tip carries, `child_links` the URDF link each joint moves (where a sensor may be mounted)."""

    name: str
    chain: object
    link_names: tuple
    load: tuple = (0.0, (0.0, 0.0, 0.0))
    child_links: tuple = ()


@dataclass
class Observations:
    """N observations: joint readings theta (N, n) in the model's joint order (one chain: its order), pose id,
    sensor and point indices, the measured point (N, 3) for 3-D sensors or pixel (N, 2 in [:, :2]) for cameras;
    `source_line` for messages; `pose_labels` the file's text label of each pose id (None: the ids are the file's
    own numbers); `chain` the index of each observation's chain (None: all on the first); `session` the index
    into `session_labels` of each observation's session (None: the file names none)."""

    theta: np.ndarray
    pose: np.ndarray
    sensor: np.ndarray
    point: np.ndarray
    measured: np.ndarray
    source_line: np.ndarray | None = None
    pose_labels: tuple | None = None
    chain: np.ndarray | None = None
    session: np.ndarray | None = None
    session_labels: tuple | None = None

    def __len__(self):
        return len(self.pose)

    def pose_name(self, pose: int):
        """A pose as the user's file names it: its text label, or its number."""
        return self.pose_labels[pose] if self.pose_labels is not None else int(pose)

    def subset(self, rows) -> "Observations":
        return Observations(self.theta[rows], self.pose[rows], self.sensor[rows], self.point[rows],
                            self.measured[rows], None if self.source_line is None else self.source_line[rows],
                            self.pose_labels, None if self.chain is None else self.chain[rows],
                            None if self.session is None else self.session[rows], self.session_labels)

    def chains(self) -> np.ndarray:
        """(N,) each observation's chain index."""
        return np.zeros(len(self.pose), dtype=int) if self.chain is None else self.chain


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


class _ArmLayout:
    """What the effects' joint_terms and chain_terms hooks (solver.effect.JointTerm, ChainTerm) look things up in,
    for N observations of an arm: the NAO model's Layout interface (solver.model.Layout), per observation instead
    of per image, a chain's frame its name. A gravity term's regressor is the torque at the readings (the arm's
    fixed regressor; the NAO's model re-evaluates it at the sagging angle)."""

    def __init__(self, model, n, tau):
        self.model, self.n_images = model, n
        self.data = self  # the NAO's hooks read the torques as layout.data.tau
        self.tau = tau

    def params(self, effect_name):
        return self.model.params(effect_name)

    def column(self, joint):
        return self.model.joint_names.index(joint)

    def chains_in_use(self):
        return [(ac.name, ac.chain) for ac in self.model.arm_chains]

    def origin_of(self, parameter, frame):
        """The index (0..n, n: the tip's offset) on the chain called `frame` of the origin `parameter` moves (its
        `index`, an origin of the model's, shared by the chains that share it); None when not on that chain."""
        origins = self.model.origin_index[self.model.chain_names.index(frame)]
        return origins.index(parameter.index) if parameter.index in origins else None


class ArmModel:
    """The arm's parameters and its model for its chains, one set of sensors and points, and a choice of effects.

    chain: solver.robot.Chain (base to tip), or several chains as a sequence of ArmChain (sharing a base);
    points: {name: (3,) nominal position in the tip frame of the chain that carries it, m}; markers: {point name:
    marker name} for the corners of printed markers (each marker one rigid body; the other points each their own);
    sheets: {marker: sheet} the sheet each marker was printed on (the marker_scale effect's; a marker not named: its
    own sheet); sensors: [Sensor];
    effects: names of solver.effects.ARM_EFFECTS (the sensors' frames are always in); gravity_mps2 (3,) in the
    base frame; load, link_names: of a single Chain (an ArmChain carries its own): (mass kg, com (3,) in the tip
    frame) of what the tip carries, for the gravity torques, and the link each joint origin ends.
    """

    # The typical size of the arm's physical parameters (Parameter.scale): its solver works on mm, mrad and
    # mrad/(N m); the identifiability threshold (solver.identify.gauges) and verify's drift sizes are relative to it.
    scale = 1e-3

    def __init__(self, chain, points: dict, sensors, effects=DEFAULT_EFFECTS, gravity_mps2=(0.0, 0.0, -9.81),
                 load=(0.0, (0.0, 0.0, 0.0)), link_names=None, markers=None, sheets=None):
        unknown = [e for e in effects if e not in ARM_EFFECTS]
        if unknown:
            raise ValueError(f"unknown arm effect {unknown[0]!r} (expected one of {', '.join(ARM_EFFECTS)})")
        self.chain = chain  # as given: a model with other effects is made from it (kinds.arm.diagnose)
        if isinstance(chain, (tuple, list)):
            self.arm_chains = tuple(chain)
        else:
            n = len(chain.joint_names)
            self.arm_chains = (ArmChain(chain.tip, chain, tuple(link_names or [f"link{k}" for k in range(n + 1)]),
                                        load),)
        first = self.arm_chains[0]
        self.load = (float(first.load[0]), np.asarray(first.load[1], dtype=float))
        self.link_names = first.link_names
        self.point_names = tuple(points)
        self.point_xyz = np.array([points[p] for p in self.point_names], dtype=float).reshape(-1, 3)
        self._point_bodies(markers or {}, sheets or {})
        self.sensors = tuple(sensors)
        self.effects = tuple(e for e in ARM_EFFECTS if e in effects)
        self.gravity_mps2 = np.asarray(gravity_mps2, dtype=float)
        self._layout()
        self.chain_names = [ac.name for ac in self.arm_chains]
        self.R0 = np.array([exp_so3(s.prior_rotation or (0.0, 0.0, 0.0)) for s in self.sensors]).reshape(-1, 3, 3)
        in_model = [EFFECTS[e] for e in ARM_MODEL_EFFECTS if e in self.effects or EFFECTS[e].arm_always]
        self.parameters = [p for e in in_model for p in e.arm_parameters(self)]
        self._joint_effects = [e for e in in_model if defines(e, "joint_terms")]
        self._chain_effects = [e for e in in_model if defines(e, "chain_terms")]
        self.names = tuple(p.name for p in self.parameters)
        self._by_effect = {}
        for i, p in enumerate(self.parameters):
            self._by_effect.setdefault(p.effect, []).append((i, p))
        self._index_parameters()

    # -- the chains' joints and origins, shared by name

    def _layout(self):
        """The model's joints (union of the chains', in order of appearance), each chain's columns of them, its
        joint origins (shared where the chains share a joint), and where each sensor's mount lies on each chain."""
        joints, prismatic, self.columns = [], [], []
        origins = {}  # key -> index into self.origin_*: ("joint", name) or ("tip", chain name)
        self.origin_keys, self.origin_links, self.directions, self.origin_index = [], [], [], []
        for ac in self.arm_chains:
            chain = ac.chain
            cols = []
            for k, j in enumerate(chain.joint_names):
                if j not in joints:
                    joints.append(j)
                    prismatic.append(bool(chain.prismatic and chain.prismatic[k]))
                cols.append(joints.index(j))
            self.columns.append(np.array(cols, dtype=int))
            n = len(chain.joint_names)
            index = []
            for k in range(n + 1):
                key = ("joint", chain.joint_names[k]) if k < n else ("tip", ac.name)
                if key not in origins:
                    offset = chain.T_origin[k, :3, 3] if k < n else chain.T_end[:3, 3]
                    origins[key] = len(self.origin_keys)
                    self.origin_keys.append(key)
                    self.origin_links.append(ac.link_names[k])
                    norm = np.linalg.norm(offset)
                    self.directions.append(offset / norm if norm > 1e-9 else None)
                index.append(origins[key])
            self.origin_index.append(index)
        self.joint_names = tuple(joints)
        self.prismatic = tuple(prismatic)
        # an origin's name is its link's; a link that ends several origins (a torso carrying two shoulders)
        # names each by the joint (or chain tip) it leads to
        count = {}
        for link in self.origin_links:
            count[link] = count.get(link, 0) + 1
        self.origin_names = [link if count[link] == 1 else f"{link}_to_{key[1]}"
                             for link, key in zip(self.origin_links, self.origin_keys)]
        # the first joint of each chain that moves what a sensor sees (None: the sensor's link is not on it)
        self.starts = np.zeros((len(self.sensors), len(self.arm_chains)), dtype=int)
        self.sees = np.ones((len(self.sensors), len(self.arm_chains)), dtype=bool)
        for s, sensor in enumerate(self.sensors):
            for c, ac in enumerate(self.arm_chains):
                if sensor.link is None or sensor.link == ac.chain.base:
                    continue
                if sensor.link in ac.child_links:
                    self.starts[s, c] = ac.child_links.index(sensor.link) + 1
                else:
                    self.sees[s, c] = False

    def _point_bodies(self, markers, sheets):
        """The rigid bodies the points sit on (the points effect's one correction each): each marker (its corners,
        printed at a known size) and each point of no marker: `body_names`, `body_rigid` (a marker: it turns too),
        `point_body` (each point's body), `point_lever` (each point from its body's centre, the mean of its points);
        the sheets the markers were printed on (the marker_scale effect's one scale each): `sheet_names`,
        `point_sheet` (each point's sheet, -1: no marker's)."""
        unknown = sorted(set(markers) - set(self.point_names))
        if unknown:
            raise ValueError(f"marker corner {unknown[0]!r} is not a point")
        self.markers = {p: markers[p] for p in self.point_names if p in markers}
        bodies = list(dict.fromkeys(self.markers.get(p, p) for p in self.point_names))
        clash = sorted((set(self.point_names) - set(self.markers)) & set(self.markers.values()))
        if clash:
            raise ValueError(f"{clash[0]!r} names both a marker and a point")
        few = [m for m in set(self.markers.values()) if list(self.markers.values()).count(m) < 3]
        if few:  # fewer corners do not fix its turn
            raise ValueError(f"marker {sorted(few)[0]!r} has fewer than 3 corners")
        self.body_names = tuple(bodies)
        self.point_body = np.array([bodies.index(self.markers.get(p, p)) for p in self.point_names], dtype=int)
        self.body_rigid = tuple(b in self.markers.values() for b in bodies)
        centres = np.array([self.point_xyz[self.point_body == b].mean(axis=0) for b in range(len(bodies))])
        self.point_lever = self.point_xyz - centres.reshape(-1, 3)[self.point_body] if bodies else self.point_xyz
        unknown = sorted(set(sheets) - set(self.markers.values()))
        if unknown:
            raise ValueError(f"{unknown[0]!r} has a sheet but is no marker")
        self.sheets = {m: sheets.get(m, m) for m in dict.fromkeys(self.markers.values())}
        self.sheet_names = tuple(dict.fromkeys(self.sheets.values()))
        self.point_sheet = np.array([self.sheet_names.index(self.sheets[self.markers[p]]) if p in self.markers else -1
                                     for p in self.point_names], dtype=int)

    # -- parameters

    def _index_parameters(self):
        """Each quantity's parameter index (-1: not in the model), for predict (the joint terms come from their
        effects' joint_terms)."""
        O, C = len(self.origin_keys), len(self.arm_chains)
        self._pose_i = np.full((O, 6), -1)
        self._tool_i, self._point_i = np.full((C, 6), -1), np.full((len(self.point_names), 6), -1)
        self._scale_i = np.full(len(self.point_names), -1)  # each point's sheet's marker_scale
        self._intrinsics_i = {}  # sensor -> [(parameter, component)]
        for i, p in enumerate(self.parameters):
            if p.effect == "intrinsics":
                self._intrinsics_i.setdefault(p.index, []).append((i, p.component))
            if p.effect == "link_poses":
                self._pose_i[p.index, p.axis] = i
            elif p.effect == "tool":
                self._tool_i[p.index, p.axis] = i
            elif p.effect == "points":  # each point of the body
                self._point_i[self.point_body == p.index, p.axis] = i
            elif p.effect == "marker_scale":  # each corner of the sheet's markers
                self._scale_i[self.point_sheet == p.index] = i

    def params(self, effect):
        return self._by_effect.get(effect, [])

    @property
    def scales(self) -> np.ndarray:
        return np.array([p.scale for p in self.parameters])

    def initial_values(self) -> np.ndarray:
        """Zero corrections; each sensor's translation at its prior (its rotation prior is R0)."""
        x = np.zeros(len(self.parameters))
        for i, p in self.params("sensors"):
            if p.axis < 3:  # its translation
                x[i] = (self.sensors[p.index].prior_translation or (0.0, 0.0, 0.0))[p.axis]
        return x

    def sensor_correction(self, x, s) -> np.ndarray:
        """The rotation vector (3,) of sensor s's correction: R_sensor_base = Exp(correction) @ R0."""
        d = np.zeros(3)
        for i, p in self.params("sensors"):
            if p.index == s and p.axis >= 3:
                d[p.axis - 3] = x[i]
        return d

    def sensor_pose(self, x, s) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of T_sensor_base of sensor s at parameter values x."""
        t = np.zeros(3)
        for i, p in self.params("sensors"):
            if p.index == s and p.axis < 3:
                t[p.axis] = x[i]
        return exp_so3(self.sensor_correction(x, s)) @ self.R0[s], t

    def sensor_intrinsics(self, x, s) -> dict | None:
        """Sensor s's intrinsics at parameter values x: the filed ones plus the intrinsics effect's corrections."""
        filed = self.sensors[s].intrinsics
        if s not in self._intrinsics_i:
            return filed
        k = dict(filed)
        distortion = distortion_of(filed)
        for i, component in self._intrinsics_i[s]:
            if component in DISTORTION:
                distortion[DISTORTION.index(component)] += x[i]
            else:
                k[f"{component}_px"] = filed[f"{component}_px"] + x[i]
        k["distortion"] = [float(d) for d in distortion]
        return k

    def rebase_sensors(self, x) -> np.ndarray:
        """Fold the sensors' rotation corrections of x into R0; returns x with those corrections zero."""
        x = np.array(x, dtype=float)
        for s in range(len(self.sensors)):
            self.R0[s] = self.sensor_pose(x, s)[0]
        for i, p in self.params("sensors"):
            if p.axis >= 3:
                x[i] = 0.0
        return x

    def reported_values(self, x) -> dict:
        """{name: value} as people and truth.json read them: a sensor's rotation is the rotation vector of
        R_sensor_base (not the correction the solver works on)."""
        out = dict(zip(self.names, (float(v) for v in x)))
        for s, sensor in enumerate(self.sensors):
            rotvec = log_so3(self.sensor_pose(x, s)[0])
            for c, a in enumerate("xyz"):
                out[f"sensor.{sensor.name}.rotation.{a}"] = float(rotvec[c])
        return out

    def tool_points(self, x) -> tuple[np.ndarray, np.ndarray]:
        """((n_points, 3) each point on its tool, before the tool's pose: nominal plus the points and marker_scale
        effects, (n_points, 3) each point's lever from its body's centre as the body's turn has turned it and its
        sheet's print has scaled it)."""
        x = np.asarray(x, dtype=float)
        value = np.where(self._point_i >= 0, x[np.maximum(self._point_i, 0)], 0.0)
        printed = 1.0 + np.where(self._scale_i >= 0, x[np.maximum(self._scale_i, 0)], 0.0)
        turned = np.array([exp_so3(r) @ lever for r, lever in zip(value[:, 3:], self.point_lever)]).reshape(-1, 3)
        turned = turned * printed[:, None]
        return self.point_xyz + value[:, :3] + turned - self.point_lever, turned

    # -- gravity

    def gravity_torques(self, theta, chains=None) -> np.ndarray:
        """(N, J) static gravity torques about each joint at the readings (nominal URDF geometry and masses), each
        row on its chain (`chains` (N,) indices; None: the first); 0 for the joints off a row's chain."""
        from naocal.solver.kinematics import chain_gravity_torques

        theta = np.asarray(theta, dtype=float)
        chains = np.zeros(len(theta), dtype=int) if chains is None else np.asarray(chains)
        tau = np.zeros_like(theta)
        for c, ac in enumerate(self.arm_chains):
            rows = np.flatnonzero(chains == c)
            if len(rows):
                cols = self.columns[c]
                load = (float(ac.load[0]), np.asarray(ac.load[1], dtype=float))
                tau[np.ix_(rows, cols)] = chain_gravity_torques(ac.chain, theta[np.ix_(rows, cols)],
                                                                self.gravity_mps2, load_mass_kg=load[0],
                                                                load_com_m=load[1])
        return tau

    # -- the model

    def base_points(self, x, obs: Observations) -> np.ndarray:
        """(N, 3) the observed points in the frame of the link each row's sensor is mounted on (the chains' base
        unless a sensor says otherwise), before the sensor's own frame."""
        return self.predict(x, obs, base_frame=True)

    def _groups(self, obs):
        """[(chain, first joint, rows)]: the observations that share a chain and a sensor mount on it."""
        chains = obs.chains()
        if not self.sensors:  # points in the base frame only (base_points)
            return [(c, 0, rows) for c in range(len(self.arm_chains))
                    for rows in [np.flatnonzero(chains == c)] if len(rows)]
        if not np.all(self.sees[obs.sensor, chains]):
            bad = int(np.flatnonzero(~self.sees[obs.sensor, chains])[0])
            raise ValueError(f"sensor {self.sensors[obs.sensor[bad]].name} is mounted on "
                             f"{self.sensors[obs.sensor[bad]].link!r}, not on chain "
                             f"{self.arm_chains[chains[bad]].name}")
        starts = self.starts[obs.sensor, chains]
        key = chains * (len(self.joint_names) + 1) + starts
        return [(int(chains[rows[0]]), int(starts[rows[0]]), rows)
                for rows in (np.flatnonzero(key == k) for k in np.unique(key))]

    def predict(self, x, obs: Observations, *, jacobian=False, tau=None, base_frame=False):
        """Predicted measurements (N, 3) (cameras: pixels in [:, :2], 0 in [:, 2]) and with `jacobian` also
        d prediction / d x (N, 3, P). tau: gravity_torques(obs.theta, obs.chain), when already known."""
        x = np.asarray(x, dtype=float)
        N = len(obs)
        P = len(self.parameters)
        if self.params("elasticity") and tau is None:
            tau = self.gravity_torques(obs.theta, obs.chain)
        layout = _ArmLayout(self, N, tau)
        joint_terms = [t for e in self._joint_effects for t in e.joint_terms(layout)]
        chain_terms = [t for e in self._chain_effects for t in e.chain_terms(layout, x)]
        p_b = np.empty((N, 3))
        Jb = np.zeros((N, 3, P)) if jacobian else None  # d p_b / d x
        for c, start, rows in self._groups(obs):
            p_b[rows], J = self._forward(x, obs, rows, c, start, jacobian, joint_terms, chain_terms)
            if jacobian:
                Jb[rows] = J
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
        seen_by = {}  # per sensor: as it is at x (a camera's intrinsics corrected)
        for s, (sensor, rows) in enumerate(zip(self.sensors, rows_of)):
            if s in self._intrinsics_i:
                sensor = replace(sensor, intrinsics=self.sensor_intrinsics(x, s))
            seen_by[s] = sensor
            pred[rows], D = MEASUREMENTS[sensor.kind].predict(y[rows], sensor)
            if sensor.kind != "points":
                dpred_dy[s] = (rows, D)
        if not jacobian:
            return pred
        Js = np.zeros((N, 3, P))  # d y / d x beyond R_s d p_b
        for i, p in self.params("sensors"):
            rows = obs.sensor == p.index
            if p.axis < 3:
                Js[rows, p.axis, i] = 1.0
            else:
                w = left_jacobian(self.sensor_correction(x, p.index))[:, p.axis - 3]
                Js[rows, :, i] = np.cross(w, y[rows] - t_s[p.index])
        J = Js
        for s, rows in enumerate(rows_of):
            turned = np.swapaxes(Jb[rows], 1, 2).reshape(-1, 3) @ R_s[s].T  # (n P, 3): one BLAS product
            J[rows] += np.swapaxes(turned.reshape(len(rows), P, 3), 1, 2)
        for s, (rows, D) in dpred_dy.items():
            J[rows] = np.einsum("nij,njp->nip", D, J[rows])
        for s, terms in self._intrinsics_i.items():  # the projection's own parameters: d pixel / d component
            rows = rows_of[s]
            dpred = MEASUREMENTS[seen_by[s].kind].intrinsic_jacobian(y[rows], seen_by[s], [c for _, c in terms])
            J[np.ix_(rows, [0, 1, 2], [i for i, _ in terms])] = dpred  # (y does not depend on them)
        return pred, J

    def _forward(self, x, obs, rows, c, start, jacobian, joint_terms, chain_terms):
        """(p (M, 3), d p / d x (M, 3, P) or None): the points of observations `rows` (all on chain c) in the frame
        of the chain's link before joint `start` (0: the base). joint_terms: [solver.effect.JointTerm] of every
        observation (q[:, column] += value * regressor); chain_terms: [solver.effect.ChainTerm] of every chain (the
        origin k of chain `frame` moves by delta along direction)."""
        ac = self.arm_chains[c]
        chain = ac.chain
        n = len(chain.joint_names)
        cols, origin = self.columns[c], self.origin_index[c]
        M, P = len(rows), len(self.parameters)

        def value(i):
            return np.where(i >= 0, x[np.maximum(i, 0)], 0.0)

        position = {int(col): k for k, col in enumerate(cols)}
        terms = [(position[t.column], t.param, t.regressor[rows]) for t in joint_terms if t.column in position]
        q = obs.theta[np.ix_(rows, cols)]
        for k, i, regressor in terms:
            q[:, k] = q[:, k] + x[i] * regressor
        moved = {t.joint: t for t in chain_terms if t.frame == ac.name}  # origin k (n: the tip's offset) -> term
        sliding = [bool(chain.prismatic and chain.prismatic[k]) for k in range(n)]
        R = np.broadcast_to(np.eye(3), (M, 3, 3)).copy()
        t = np.zeros((M, 3))
        frames = {}  # per joint: (R before its origin, R_B, origin o, axis a, both in the mount's frame)
        for k in range(start, n):
            o = origin[k]
            offset = chain.T_origin[k, :3, 3] + (moved[k].delta * moved[k].direction if k in moved else 0.0)
            pose = value(self._pose_i[o])
            R_prev = R
            R_B = _times(R, chain.T_origin[k, :3, :3])
            t = t + _times(R, offset) + _times(R_B, pose[:3])
            R_A = _times(R_B, exp_so3(pose[3:]))
            a = _times(R_A, chain.axes[k])
            frames[k] = (R_prev, R_B, t.copy(), a)
            if sliding[k]:
                t = t + a * q[:, k, None]
                R = R_A
            else:
                R = _turned(R_A, chain.axes[k], q[:, k])
        offset_end = chain.T_end[:3, 3] + (moved[n].delta * moved[n].direction if n in moved else 0.0)
        R_prev_end = R
        t_end = t + _times(R, offset_end)
        R_end = _times(R, chain.T_end[:3, :3])
        point = obs.point[rows]
        tool = value(self._tool_i[c])
        E_tool = exp_so3(tool[3:])
        on_tools, levers = self.tool_points(x)
        on_tool = on_tools[point]  # (M, 3) on the tool, before its pose
        p_tip = on_tool @ E_tool.T + tool[:3]
        p = t_end + np.einsum("nij,nj->ni", R_end, p_tip)
        if not jacobian:
            return p, None
        Jb = np.zeros((M, 3, P))
        for k, i, regressor in terms:
            if k >= start:
                a, o = frames[k][3], frames[k][2]
                Jb[:, :, i] = regressor[:, None] * (a if sliding[k] else np.cross(a, p - o))
        for k in range(start, n):
            R_prev, R_B, o, a = frames[k]
            if k in moved:
                Jb[:, :, moved[k].param] = _times(R_prev, moved[k].direction)
            pose_i = self._pose_i[origin[k]]
            if np.any(pose_i >= 0):
                w = left_jacobian(value(pose_i)[3:])
                for comp in range(6):
                    if pose_i[comp] >= 0:
                        Jb[:, :, pose_i[comp]] = (R_B[:, :, comp] if comp < 3 else
                                                  np.cross(_times(R_B, w[:, comp - 3]), p - o))
        if n in moved:
            Jb[:, :, moved[n].param] = _times(R_prev_end, moved[n].direction)
        tool_i = self._tool_i[c]
        if np.any(tool_i >= 0):
            w = left_jacobian(tool[3:])
            turned = on_tool @ E_tool.T
            for comp in range(6):
                if tool_i[comp] >= 0:
                    Jb[:, :, tool_i[comp]] = (R_end[:, :, comp] if comp < 3 else
                                              np.einsum("nij,nj->ni", R_end, np.cross(w[:, comp - 3], turned)))
        for pi in np.unique(point):
            sel = point == pi
            i = self._scale_i[pi]
            if i >= 0:  # d lever / d m = Exp(r) lever, the scaled lever / (1 + m)
                Jb[sel, :, i] = _times(R_end[sel], E_tool @ (levers[pi] / (1.0 + x[i])))
            turn = value(self._point_i[pi, 3:])
            w = left_jacobian(turn)
            for comp in range(6):
                i = self._point_i[pi, comp]
                if i >= 0:
                    along = E_tool[:, comp] if comp < 3 else E_tool @ np.cross(w[:, comp - 3], levers[pi])
                    Jb[sel, :, i] = _times(R_end[sel], along)
        return p, Jb

    def component_mask(self, obs: Observations) -> np.ndarray:
        """(N, 3) which components of a prediction are measured (cameras: u, v only)."""
        mask = np.ones((len(obs), 3), dtype=bool)
        for s, sensor in enumerate(self.sensors):
            mask[obs.sensor == s] = MEASUREMENTS[sensor.kind].measured
        return mask
