"""The measurement model: predicted pixel positions of the target vertices and their exact Jacobian.

    q            = theta + sum of the effects' joint terms (value * regressor)         (Eq. 2, plus effects)
    T_base_tip   = FK of the chain to the target's frame, with the effects' chain terms
    T_base_cam   = FK of the chain to the camera, with the effects' camera terms        (Eq. 3)
    p'           = the target's nominal vertex, with the effects' target terms          (Eq. 4)
    p_cam        = T_cam_base @ T_base_tip @ p'
    (u, v)       = solver.camera's projection, with the effects' projection terms      (Eq. 1)
    residual     = predicted - detected, px

The five hook points are the effects' (solver/effect.py, solver/effects/); this module composes them and
differentiates exactly: every kinematic parameter moves a target rigidly relative to the camera, a twist per
image, and the camera model's interaction matrix turns twists into pixels. Everything is a pure function of
(ModelData, Registry, parameter vector).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from naocal.solver import camera as camera_model
from naocal.solver.effect import CameraTerm, Setup
from naocal.solver.effects import EFFECTS
from naocal.solver.errors import NaocalError
from naocal.solver.kinematics import chain_frames, chain_gravity_torques, joint_axes_and_origins
from naocal.solver.registry import Registry


@dataclass
class ModelData:
    """What the model needs from a dataset, as arrays. M images, N vertex rows, J joint columns.

    theta, direction, velocity, commanded, tau: (M, J) per image, columns in `joints` order.
    """

    image_of_row: np.ndarray  # (N,) index 0..M-1 into the per-image arrays
    vertex: np.ndarray  # (N,) vertex index on its board
    uv_px: np.ndarray  # (N, 2) detected vertex positions
    p_mount: np.ndarray  # (N, 3) nominal vertex positions in the frame the image's target is attached to, m
    target: np.ndarray  # (M,) the target each image shows (robot description names; the NAO's sandals 'L', 'R')
    image_id: np.ndarray  # (M,) the dataset's image index
    stance: np.ndarray  # (M,)
    head_posture: np.ndarray  # (M,)
    theta: np.ndarray  # (M, J) measured angles, rad
    direction: np.ndarray  # (M, J) approach direction -1/0/1
    velocity: np.ndarray | None  # (M, J) rad/s at t_joints, or None if the dataset has none
    cameras: dict  # camera name -> prior intrinsics {fx_px, fy_px, cx_px, cy_px, distortion, width_px, height_px}
    camera: np.ndarray | None = None  # (M,) the camera of each image (default: the robot's first default camera)
    joints: tuple | None = None  # the J joint columns (default: the robot description's joints)
    gravity_mps2: np.ndarray | None = None  # (M, 3) or (3,) gravity in the base frame (default: the robot's)
    robot: object = None  # solver.robot.RobotDescription (default: the NAO)
    loads: dict = field(default_factory=dict)  # target -> (board mass kg, board centre (3,) in its frame)
    tau: np.ndarray | None = None  # (M, J) static gravity torque at theta on hanging chains, N m (computed)
    angle_choice: object = None  # solver.adapter.AngleChoice: how theta was taken from a dataset (None: given)
    commanded: np.ndarray | None = None  # (M, J) commanded angles, when known

    def __post_init__(self):
        from naocal.solver.robot import nao

        self.robot = self.robot or nao()
        M = len(self.target)
        self.target = np.asarray(self.target).astype(str)
        if self.camera is None:
            self.camera = np.full(M, self.robot.default_cameras[0])
        self.camera = np.asarray(self.camera).astype(str)
        self.joints = tuple(self.joints or self.robot.joints)
        g = self.robot.gravity_mps2 if self.gravity_mps2 is None else self.gravity_mps2
        self.gravity_mps2 = np.array(np.broadcast_to(np.asarray(g, dtype=float), (M, 3)))
        for t in np.unique(self.target):
            if t not in self.loads:
                spec = self.robot.target(t)
                self.loads[t] = (spec.board.mass_kg, spec.centre)
        if "intrinsics" in self.cameras:  # a single intrinsics dict given: the default camera's
            self.cameras = {self.robot.default_cameras[0]: self.cameras}
        if self.tau is None:
            self.tau = gravity_torques_of(self, self.theta)

    # -- names the NAO code knows them by

    @property
    def leg(self) -> np.ndarray:
        """The NAO's name for the target: its sandals are named after their leg ('L', 'R')."""
        return self.target

    @property
    def intrinsics(self) -> dict:
        """The prior intrinsics of the data's only camera (ValueError with several cameras)."""
        used = np.unique(self.camera)
        if len(used) != 1:
            raise ValueError(f"the data use {len(used)} cameras ({', '.join(used)}): ask data.cameras[name]")
        return self.cameras[used[0]]

    @property
    def setup(self) -> Setup:
        """The robot and the cameras and targets these data use, in the description's order."""
        cams, tgts = set(self.camera.tolist()), set(self.target.tolist())
        return Setup(self.robot, tuple(c for c in self.robot.cameras if c in cams),
                     tuple(t for t in self.robot.targets if t in tgts))

    def column(self, joint: str) -> int:
        try:
            return self.joints.index(joint)
        except ValueError:
            raise NaocalError(f"the data have no angles of joint {joint!r} (they have {', '.join(self.joints)})") \
                from None

    @property
    def n_rows(self) -> int:
        return len(self.image_of_row)

    @property
    def n_images(self) -> int:
        return len(self.target)

    def is_sorted_by_target(self, order=None) -> bool:
        """Images grouped by target in `order` (default: the description's), rows in image order: the layout Model
        works on."""
        key = self._target_key(order)
        return bool(np.all(np.diff(key) >= 0) and np.all(np.diff(self.image_of_row) >= 0))

    def sorted_by_target(self, order=None) -> "ModelData":
        """The same data with images grouped by target (stable) and rows in image order."""
        if self.is_sorted_by_target(order):
            return self
        return self.reordered(np.argsort(self._target_key(order), kind="stable"))

    def _target_key(self, order):
        order = list(order or self.robot.targets)
        names, inverse = np.unique(self.target, return_inverse=True)
        order += [t for t in names if t not in order]
        return np.array([order.index(t) for t in names], dtype=int)[inverse.reshape(-1)]

    # the NAO's names
    is_sorted_by_leg = is_sorted_by_target
    sorted_by_leg = sorted_by_target

    def rows_of_images(self, images: np.ndarray) -> np.ndarray:
        return np.flatnonzero(np.isin(self.image_of_row, images))

    def subset(self, images) -> "ModelData":
        """The data of some images only (index 0..M-1), re-indexed."""
        images = np.asarray(sorted(set(np.asarray(images).tolist())), dtype=int)
        return self.reordered(images)

    def without_rows(self, rows) -> "ModelData":
        """The data less some vertex rows (e.g. mis-detected corners); images left without a row are dropped."""
        keep = np.ones(self.n_rows, dtype=bool)
        keep[np.asarray(rows, dtype=int)] = False
        out = self.reordered(np.arange(self.n_images))
        out.image_of_row, out.vertex = self.image_of_row[keep], self.vertex[keep]
        out.uv_px, out.p_mount = self.uv_px[keep], self.p_mount[keep]
        return out.subset(np.unique(out.image_of_row))

    def reordered(self, images) -> "ModelData":
        """The data of the images `images` (index 0..M-1), in that order, rows grouped by image."""
        images = np.asarray(images, dtype=int)
        position = -np.ones(self.n_images, dtype=int)
        position[images] = np.arange(len(images))
        kept = np.flatnonzero(position[self.image_of_row] >= 0)
        rows = kept[np.argsort(position[self.image_of_row[kept]], kind="stable")]
        per_image = lambda a: None if a is None else a[images]  # noqa: E731
        return ModelData(
            image_of_row=position[self.image_of_row[rows]], vertex=self.vertex[rows], uv_px=self.uv_px[rows],
            p_mount=self.p_mount[rows], target=self.target[images], image_id=self.image_id[images],
            stance=self.stance[images], head_posture=self.head_posture[images], theta=self.theta[images],
            direction=self.direction[images], velocity=per_image(self.velocity), cameras=self.cameras,
            camera=self.camera[images], joints=self.joints, gravity_mps2=self.gravity_mps2[images],
            robot=self.robot, loads=dict(self.loads), tau=self.tau[images], angle_choice=self.angle_choice,
            commanded=per_image(self.commanded),
        )


def gravity_torques_of(data: ModelData, q: np.ndarray) -> np.ndarray:
    """(M, J) static gravity torque at the angles q (M, J) on the joints of each image's target chain, for targets
    on chains that hang free (zero elsewhere: a supporting chain carries the body, which is not modelled)."""
    tau = np.zeros_like(np.asarray(q, dtype=float))
    for t in np.unique(data.target):
        spec = data.robot.target(t)
        if spec.load != "hanging":
            continue
        images = np.flatnonzero(data.target == t)
        chain = data.robot.chain(spec.frame)
        cols = np.array([data.column(j) for j in chain.joint_names], dtype=int)
        mass, centre = data.loads[t]
        tau[np.ix_(images, cols)] = chain_gravity_torques(chain, q[np.ix_(images, cols)], data.gravity_mps2[images],
                                                          load_mass_kg=mass, load_com_m=centre)
    return tau


class Layout:
    """Where things are in one (data, registry) pair: the images and rows of each target and camera, the chains,
    their joint columns and each effect's parameters. What the effects' hooks look things up in."""

    def __init__(self, data: ModelData, registry: Registry):
        setup = registry.setup
        if data.robot is not setup.robot:
            raise NaocalError(f"the data are of robot {data.robot.name!r} ({data.robot.path}), the registry of "
                              f"{setup.robot.name!r} ({setup.robot.path})")
        for kind, used, known in (("target", data.target, setup.targets), ("camera", data.camera, setup.cameras)):
            extra = sorted(set(used.tolist()) - set(known))
            if extra:
                raise NaocalError(f"the data show {kind}(s) {', '.join(extra)}, which the model was not made for "
                                  f"({', '.join(known)}): build the registry with Registry.for_data")
        self.data, self.registry, self.robot = data, registry, setup.robot
        self.n_images, self.n_rows = data.n_images, data.n_rows
        self.targets = tuple(t for t in setup.targets if np.any(data.target == t))
        self.cameras = tuple(c for c in setup.cameras if np.any(data.camera == c))
        starts = np.searchsorted(data.image_of_row, np.arange(data.n_images + 1))
        self.target_images, self.target_rows = {}, {}
        for t in self.targets:
            images = np.flatnonzero(data.target == t)
            self.target_images[t] = slice(int(images[0]), int(images[-1]) + 1)  # contiguous: data sorted by target
            self.target_rows[t] = slice(int(starts[images[0]]), int(starts[images[-1] + 1]))
        single = len(self.cameras) == 1
        self.camera_images = {c: slice(None) if single else np.flatnonzero(data.camera == c) for c in self.cameras}
        self.camera_rows = {c: slice(None) if single else np.flatnonzero(data.camera[data.image_of_row] == c)
                            for c in self.cameras}
        self.chains, self.columns = {}, {}
        for frame in [self.robot.target(t).frame for t in self.targets] + \
                     [self.robot.camera(c).frame for c in self.cameras]:
            chain = self.robot.chain(frame)
            self.chains[frame] = chain
            self.columns[frame] = np.array([data.column(j) for j in chain.joint_names], dtype=int)
        self._params = {}
        for i, p in enumerate(registry.parameters):
            self._params.setdefault(p.effect, []).append((i, p))

    def params(self, effect_name: str) -> list:
        """[(index in the full vector, Parameter)] of one effect."""
        return self._params.get(effect_name, [])

    def column(self, joint: str) -> int:
        return self.data.column(joint)

    def chains_in_use(self) -> list:
        """[(frame, Chain)] of the chains to the targets and cameras the data use."""
        return list(self.chains.items())

    def origin_of(self, parameter, frame: str) -> int | None:
        """The index in the chain to `frame` of the joint whose origin `parameter` moves (its `joint`); None when
        that joint is not on the chain."""
        chain = self.chains[frame]
        return chain.index(parameter.joint) if parameter.joint in chain.joint_names else None

    def target_frame(self, target: str) -> str:
        return self.robot.target(target).frame

    def camera_frame(self, camera: str) -> str:
        return self.robot.camera(camera).frame


def _index(cols: np.ndarray):
    """A slice for contiguous columns (views, fast), else the index array."""
    if len(cols) and np.all(np.diff(cols) == 1):
        return slice(int(cols[0]), int(cols[-1]) + 1)
    return cols


def _add(joint_twists, images, cols, v, w):
    """joint_twists[images, :3, cols] += v and [images, 3:, cols] += w, for a slice or an index array of images."""
    if isinstance(images, slice):
        cols = _index(cols)
        joint_twists[images, :3, cols] += v
        joint_twists[images, 3:, cols] += w
    else:
        joint_twists[np.ix_(images, np.arange(3), cols)] += v
        joint_twists[np.ix_(images, np.arange(3, 6), cols)] += w


def _cross(a, b):
    """Cross product over the last axis (faster than np.cross for small broadcast arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))  # filled in place: np.stack costs more than the maths
    out[..., 0], out[..., 1], out[..., 2] = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return out


def _yield_to_gravity(q0, compliance, chain, gravity, load, *, sag_guess=None, tolerance_rad=1e-13,
                      max_iterations=20):
    """Solve q = q0 + C tau(q) for one chain's angles (m, k) by Newton's method, from q0 + sag_guess (m, k).

    Returns q (m, k), tau(q) (m, k) and A = I - C dtau/dq (m, k, k), the matrix the implicit derivative needs.
    """
    q = q0.copy() if sag_guess is None else q0 + sag_guess
    eye = np.eye(q0.shape[1])
    torques = lambda q: chain_gravity_torques(chain, q, gravity, load_mass_kg=load[0], load_com_m=load[1],  # noqa
                                              jacobian=True)
    for _ in range(max_iterations):
        tau, dtau = torques(q)
        A = eye - compliance[:, None] * dtau
        misfit = q0 + compliance * tau - q
        if np.max(np.abs(misfit), initial=0.0) < tolerance_rad:
            break
        step = np.linalg.solve(A, misfit[..., None])[..., 0]
        if not np.all(np.isfinite(step)):
            raise FloatingPointError(f"elasticity: no equilibrium for compliances {compliance} rad/(N m)")
        q = q + step
    else:  # rounding can keep the misfit just above the tolerance: the last iterate is as good as it gets
        tau, dtau = torques(q)
        A = eye - compliance[:, None] * dtau
    return q, tau, A


@dataclass
class _Terms:
    """The effects' terms at one parameter vector (hooks 2-5)."""

    chain: list
    camera: dict  # camera -> CameraTerm
    target: list
    projection: list
    shifts: dict  # frame -> {joint index: origin shift (3,)}, the chain terms summed

    @classmethod
    def of(cls, effects, layout, values) -> "_Terms":
        chain = [t for e in effects for t in e.chain_terms(layout, values)]
        camera = {}
        for term in (t for e in effects for t in e.camera_terms(layout, values)):
            camera[term.camera] = _combined(camera.get(term.camera), term)
        shifts = {}
        for term in chain:
            frame_shifts = shifts.setdefault(term.frame, {})
            frame_shifts[term.joint] = frame_shifts.get(term.joint, 0.0) + term.delta * term.direction
        return cls(chain, camera, [t for e in effects for t in e.target_terms(layout, values)],
                   [t for e in effects for t in e.projection_terms(layout, values)], shifts)


def _combined(a: CameraTerm | None, b: CameraTerm) -> CameraTerm:
    """One camera's terms of two effects as one: translations add; one rotation (the rotation generators are the
    camera frame's, which another rotation would turn)."""
    if a is None:
        return b
    if a.rotation is not None and b.rotation is not None:
        raise ValueError(f"two effects rotate camera {a.camera!r}: one effect owns a camera's rotation")
    translation = a.translation if b.translation is None else (
        b.translation if a.translation is None else a.translation + b.translation)
    return CameraTerm(a.camera, a.rotation if a.rotation is not None else b.rotation,
                      a.rotation_params + b.rotation_params, translation, a.translation_params + b.translation_params)


@dataclass
class _Poses:
    """Per image (M): the target's frame (R_bt, t_bt) and the camera (R_bc, t_bc) in the base frame; the target's
    frame in the camera frame (R_ct, t_ct); the chains' joint frames for the Jacobian."""

    R_bt: np.ndarray
    t_bt: np.ndarray
    R_bc: np.ndarray
    t_bc: np.ndarray
    R_cb: np.ndarray = None
    R_ct: np.ndarray = None
    t_ct: np.ndarray = None
    target_frames: dict = field(default_factory=dict)
    camera_frames: dict = field(default_factory=dict)


class Model:
    """Residuals and exact Jacobian of one dataset under one registry.

    Works on the data sorted by target (`self.data`), so each target's images and rows are contiguous slices.
    """

    def __init__(self, data: ModelData, registry: Registry):
        self.data = data = data.sorted_by_target(registry.setup.targets)
        self.registry = registry
        self.layout = layout = Layout(data, registry)
        self.effects = [EFFECTS[name] for name in registry.effects]
        terms = [t for e in self.effects for t in e.joint_terms(layout)]
        M, J, P, K = data.n_images, len(data.joints), len(registry), len(terms)
        self.joint_param = np.array([t.param for t in terms], dtype=int)
        self.joint_col = np.array([t.column for t in terms], dtype=int)
        self.regressor = np.stack([t.regressor for t in terms], axis=1) if K else np.zeros((M, 0))
        self.gravity = np.array([t.gravity for t in terms], dtype=bool)
        self._entry_to_joint = np.zeros((K, J))
        self._entry_to_joint[np.arange(K), self.joint_col] = 1.0
        self._entry_to_param = np.zeros((K, P))
        self._entry_to_param[np.arange(K), self.joint_param] = 1.0
        camera_cols = {int(c) for cam in layout.cameras for c in layout.columns[layout.camera_frame(cam)]}
        self._moves_cameras = bool(camera_cols & set(self.joint_col.tolist()))  # joint terms on camera chains
        self._elastic_targets = [t for t in layout.targets if self.robot.target(t).load == "hanging"]
        counts = np.bincount(data.image_of_row, minlength=data.n_images)
        self._regular = bool(data.n_images and np.all(counts == counts[0]))  # same vertex count in every image
        self._camera_cache = {}
        self._sag = {}  # target -> last solved elastic sag (m, k): where Newton starts next time, not a result
        self._distinct = {} if self.gravity.any() else self._distinct_configurations()

    @property
    def robot(self):
        return self.layout.robot

    def _distinct_configurations(self) -> dict:
        """target -> (one image of each distinct configuration of its chain, the configuration of each image), for
        targets whose images share configurations (the head postures of one stance): without elasticity a chain's
        angles are theta plus the joint terms' regressors times values, so images equal in both are equal at every
        parameter vector and their chain is computed once."""
        from naocal.solver.scoretest import row_ids

        layout, out = self.layout, {}
        for t in layout.targets:
            images, cols = layout.target_images[t], layout.columns[layout.target_frame(t)]
            entries = np.isin(self.joint_col, cols)
            ids = row_ids(np.column_stack([self.data.theta[images][:, cols], self.regressor[images][:, entries]]))
            n = int(ids.max(initial=-1)) + 1
            if n <= 0.75 * len(ids):
                first = np.empty(n, dtype=np.int64)
                first[ids] = np.arange(len(ids))  # an image of each configuration (any: they are equal)
                out[t] = (first, ids)
        return out

    # ---------------------------------------------------------------------------------- hook 1: joint angles

    def joint_angles(self, values) -> np.ndarray:
        """q (M, J): measured angles plus every joint-level term."""
        return self.joint_state(values)[0]

    def joint_state(self, values, *, jacobian=False):
        """q (M, J), the regressors (M, K) at q, and with `jacobian` dq/dvalues (M, J, P) (else None).

        Elasticity makes q implicit: a joint yields to the gravity torque at the angle it actually has,
        q = q0 + C tau(q) with q0 = theta + the other terms and C the compliances. We solve it per target chain by
        Newton's method and differentiate it by the implicit function theorem: dq/dp = (I - C dtau/dq)^-1
        d(q0 + C tau)/dp.
        """
        values = np.asarray(values, dtype=float)
        data, layout = self.data, self.layout
        steady = ~self.gravity
        q = data.theta + (self.regressor[:, steady] * values[self.joint_param[steady]]) @ self._entry_to_joint[steady]
        regressor, yield_matrix = self.regressor, {}
        if self.gravity.any():
            regressor = self.regressor.copy()
            regressor[:, self.gravity] = 0.0  # only a hanging target's own chain yields
            compliance = values[self.joint_param[self.gravity]] @ self._entry_to_joint[self.gravity]  # (J,)
            for t in self._elastic_targets:
                images, frame = layout.target_images[t], layout.target_frame(t)
                cols = layout.columns[frame]
                q0 = q[images][:, cols]
                q_t, tau, A = _yield_to_gravity(q0, compliance[cols], layout.chains[frame],
                                                data.gravity_mps2[images], data.loads[t], sag_guess=self._sag.get(t))
                self._sag[t] = q_t - q0  # the next evaluation (a nearby step) starts from this sag
                q[images, _index(cols)] = q_t
                position = {int(c): k for k, c in enumerate(cols)}
                entries = np.flatnonzero(self.gravity & np.isin(self.joint_col, cols))
                regressor[images, entries] = tau[:, [position[int(c)] for c in self.joint_col[entries]]]
                yield_matrix[t] = A
        if not jacobian:
            return q, regressor, None
        M, P = data.n_images, len(values)
        dq = np.zeros((M, len(data.joints), P))
        dq[:, self.joint_col, self.joint_param] = regressor
        for t, A in yield_matrix.items():
            images, cols = layout.target_images[t], _index(layout.columns[layout.target_frame(t)])
            dq[images, cols] = np.linalg.solve(A, dq[images, cols])
        return q, regressor, dq

    # ---------------------------------------------------------------------------------- residuals

    def residuals(self, values) -> np.ndarray:
        """Predicted minus detected pixel positions, (N, 2), rows as in `self.data`."""
        return self.evaluate(values, jacobian=False)[0]

    def board_twist_jacobian(self, values) -> np.ndarray:
        """(N, 2, 6): d residual / d twist (v, w) of each image's board in the camera frame, v in m, w in rad.

        Its six columns per image span every rigid motion of that board relative to the camera (what kinematic
        errors can do); the diagnostics split residuals into this rigid part and a non-rigid remainder.
        """
        return self.evaluate(values, jacobian=False, _twist_only=True)[1]

    def _camera_fk(self, camera, q_cols, shifts, end_shift):
        """Camera chain FK, cached: without head terms the camera's angles never change during a fit."""
        key = (q_cols.tobytes(), repr(shifts), None if end_shift is None else end_shift.tobytes())
        cached = self._camera_cache.get(camera)
        if cached is None or cached[0] != key:
            frames, T = chain_frames(self.layout.chains[self.layout.camera_frame(camera)], q_cols,
                                     origin_shifts_m=shifts, end_shift_m=end_shift)
            cached = self._camera_cache[camera] = (key, frames, T)
        return cached[1], cached[2]

    def evaluate(self, values, *, jacobian=True, _twist_only=False):
        """Residuals (N, 2) and, if asked, the Jacobian (N, 2, P) with respect to the full parameter vector."""
        values = np.asarray(values, dtype=float)
        elastic = bool(self.gravity.any()) and jacobian and not _twist_only
        residual, projection, pose, terms, regressor, dq = self._project(values, elastic)
        if not (jacobian or _twist_only):
            return residual, None
        L = projection.twist_jacobian()  # (N, 2, 6): d pixel / d twist of the point relative to the camera
        if _twist_only:
            return residual, L
        twists = self._twists(len(values), pose, terms, regressor, dq)
        return residual, self._jacobian(L, twists, projection, terms)

    def factored(self, values):
        """Residuals (N, 2) and the Jacobian in two factors: J[rows of image m] = F[rows of m] @ T[m].

        F (N, 2, C): pixels per twist of each point (six columns) and per projection term (one column each);
        T (M, C, P): each image's twists per parameter, and a unit row per projection term. The normal equations
        J^T J = sum_m T_m^T (F_m^T F_m) T_m then need only each image's small C x C matrix (NormalEquations), never
        the (N, 2, P) Jacobian: every kinematic parameter moves an image's board rigidly."""
        values = np.asarray(values, dtype=float)
        residual, projection, pose, terms, regressor, dq = self._project(values, bool(self.gravity.any()))
        L = projection.twist_jacobian()
        twists = self._twists(len(values), pose, terms, regressor, dq)
        if not terms.projection:
            return residual, L, twists
        K = len(terms.projection)
        F = np.zeros(L.shape[:2] + (6 + K,))
        F[:, :, :6] = L
        T = np.zeros((twists.shape[0], 6 + K, twists.shape[2]))
        T[:, :6] = twists
        for k, term in enumerate(terms.projection):
            rows = self.layout.camera_rows[term.camera]
            F[rows, :, 6 + k] = projection.intrinsic_jacobian(term.component)[rows]
            T[:, 6 + k, term.param] = 1.0
        return residual, F, T

    def _project(self, values, elastic):
        """The residuals at `values` and what their derivatives need: (residual, projection, poses, terms,
        regressors, dq/dvalues (with `elastic`, else None))."""
        q, regressor, dq = self.joint_state(values, jacobian=elastic)  # hook 1: joint terms
        terms = _Terms.of(self.effects, self.layout, values)  # hooks 2-5: chain, camera, target, projection terms
        pose = self._poses(q, terms)
        p_cam = self._in_camera(self._target_points(terms), pose)
        projection = camera_model.project(p_cam, *self._intrinsics(terms.projection))
        return projection.uv_px - self.data.uv_px, projection, pose, terms, regressor, dq

    def _poses(self, q, terms) -> _Poses:
        """Every image's target frame and camera in the base frame, and the target frame in the camera frame."""
        data, layout = self.data, self.layout
        M = data.n_images
        poses = _Poses(np.empty((M, 3, 3)), np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, 3)))
        for t in layout.targets:  # the chains to the targets, with the chain terms
            images, frame = layout.target_images[t], layout.target_frame(t)
            q_chain, shifts = q[images][:, layout.columns[frame]], terms.shifts.get(frame)
            distinct = self._distinct.get(t)
            if distinct is not None and all(np.ndim(v) <= 1 for v in (shifts or {}).values()):
                frames, T_end = chain_frames(layout.chains[frame], q_chain[distinct[0]], origin_shifts_m=shifts)
                frames, T_end = frames[distinct[1]], T_end[distinct[1]]
            else:
                frames, T_end = chain_frames(layout.chains[frame], q_chain, origin_shifts_m=shifts)
            poses.R_bt[images], poses.t_bt[images] = T_end[:, :3, :3], T_end[:, :3, 3]
            poses.target_frames[t] = frames
        for c in layout.cameras:  # T_base_cam = T_base_parent @ Trans(translation) @ T_parent_cam0 @ rotation
            images, frame = layout.camera_images[c], layout.camera_frame(c)
            term = terms.camera.get(c)
            frames, T = self._camera_fk(c, q[images][:, layout.columns[frame]], terms.shifts.get(frame),
                                        None if term is None else term.translation)
            poses.R_bc[images] = T[:, :3, :3] if term is None or term.rotation is None else T[:, :3, :3] @ term.rotation
            poses.t_bc[images] = T[:, :3, 3]
            poses.camera_frames[c] = frames
        poses.R_cb = np.swapaxes(poses.R_bc, 1, 2)
        poses.R_ct = poses.R_cb @ poses.R_bt
        poses.t_ct = (poses.R_cb @ (poses.t_bt - poses.t_bc)[..., None])[..., 0]  # matmul: 2-5x einsum's speed
        return poses

    def _target_points(self, terms) -> np.ndarray:
        """The vertices in their targets' frames, (N, 3), with the target terms."""
        points = self.data.p_mount
        if terms.target:
            points = points.copy()
            for term in terms.target:
                rows = self.layout.target_rows[term.target]
                points[rows] = self.data.p_mount[rows] @ term.R.T + term.t
        return points

    def _in_camera(self, points, pose) -> np.ndarray:
        """The vertices in their images' camera frames, (N, 3)."""
        data = self.data
        N, M = data.n_rows, data.n_images
        if self._regular:  # batched per image: (M, V, 3) @ (M, 3, 3)^T
            V = N // M
            return (points.reshape(M, V, 3) @ np.swapaxes(pose.R_ct, 1, 2) + pose.t_ct[:, None, :]).reshape(N, 3)
        img = data.image_of_row
        return np.einsum("nij,nj->ni", pose.R_ct[img], points) + pose.t_ct[img]

    def _twists(self, P, pose, terms, regressor, dq) -> np.ndarray:
        """(M, 6, P): d twist (v, w) of each image's target relative to its camera (camera frame, dp = v + w x p) /
        d parameter. Joints and chain terms move it through the chains, camera terms move the camera, target
        terms the board."""
        data, layout = self.data, self.layout
        M = data.n_images
        twists = np.zeros((M, 6, P))
        joint_twists = np.zeros((M, 6, len(data.joints)))
        for t in layout.targets:
            images, frame = layout.target_images[t], layout.target_frame(t)
            self._chain_twists(layout.chains[frame], pose.target_frames[t], images, layout.columns[frame], pose,
                               +1.0, joint_twists, twists, [term for term in terms.chain if term.frame == frame])
        for c in layout.cameras:  # the camera moves: the point moves the opposite way
            images, frame = layout.camera_images[c], layout.camera_frame(c)
            chain, frames = layout.chains[frame], pose.camera_frames[c]
            self._chain_twists(chain, frames, images, layout.columns[frame], pose, -1.0,
                               joint_twists if self._moves_cameras else None, twists,
                               [term for term in terms.chain if term.frame == frame])
            term = terms.camera.get(c)
            if term is not None:
                for param, w in term.rotation_params:
                    twists[images, 3:, param] += w
                R_parent = frames[:, -1, :3, :3] if len(chain.joint_names) else np.eye(3)
                for param, unit in term.translation_params:
                    twists[images, :3, param] -= np.einsum("mij,mj->mi", pose.R_cb[images], R_parent @ unit)
        if dq is not None:  # elastic: dq/dp from the implicit equilibrium
            twists += joint_twists @ dq
        elif len(self.joint_param):
            entries = joint_twists[:, :, self.joint_col] * regressor[:, None, :]  # (M, 6, K)
            twists += (entries.reshape(-1, entries.shape[2]) @ self._entry_to_param).reshape(M, 6, P)
        for term in terms.target:
            images = layout.target_images[term.target]
            for param, v, w in term.params:  # a shift (v) or a turn (w): the other part is zero, skipped
                if np.any(v):
                    twists[images, :3, param] += pose.R_ct[images] @ v
                if np.any(w):
                    w_c = pose.R_ct[images] @ w
                    twists[images, :3, param] += _cross(pose.t_ct[images], w_c)
                    twists[images, 3:, param] += w_c
        return twists

    def _chain_twists(self, chain, frames, images, columns, pose, sign, joint_twists, twists, chain_terms):
        """The twists of one chain's joints (into joint_twists, unless None) and chain terms (into twists), signed
        +1 for a target's chain, -1 for a camera's."""
        if joint_twists is not None and len(chain.joint_names):
            axes, origins = joint_axes_and_origins(frames, chain)
            R_bc = pose.R_bc[images]  # rows of R_bc are the columns of R_cb: x @ R_bc = (R_cb @ x^T)^T
            z_c = axes @ R_bc
            o_c = (origins - pose.t_bc[images, None, :]) @ R_bc
            _add(joint_twists, images, columns, sign * np.swapaxes(_cross(o_c, z_c), 1, 2),
                 sign * np.swapaxes(z_c, 1, 2))
        for term in chain_terms:
            twists[images, :3, term.param] += sign * np.einsum(
                "mij,mj->mi", pose.R_cb[images], self._before(frames, term.joint) @ term.direction)

    def _jacobian(self, L, twists, projection, terms) -> np.ndarray:
        """(N, 2, P): pixels per twist times twists, plus the projection terms' own columns."""
        data = self.data
        N, M, P = data.n_rows, data.n_images, twists.shape[2]
        if self._regular:
            J = np.matmul(L.reshape(M, 2 * (N // M), 6), twists).reshape(N, 2, P)
        else:
            J = np.einsum("nik,nkp->nip", L, twists[data.image_of_row])
        for term in terms.projection:
            rows = self.layout.camera_rows[term.camera]
            J[rows, :, term.param] += projection.intrinsic_jacobian(term.component)[rows]
        return J

    @staticmethod
    def _before(frames, k):
        """(m, 3, 3) orientation of the frame before joint k (the previous joint's child frame; the base for k=0)."""
        return frames[:, k - 1, :3, :3] if k > 0 else np.eye(3)

    def _intrinsics(self, projection_terms):
        """(fx, fy, cx, cy, k): scalars for one camera, per-row arrays for several."""
        layout, data = self.layout, self.data
        values = {}
        for c in layout.cameras:
            prior = data.cameras[c]
            k = camera_model.distortion_of(prior)
            values[c] = {"fx": prior["fx_px"], "fy": prior["fy_px"], "cx": prior["cx_px"], "cy": prior["cy_px"],
                         **dict(zip(("k1", "k2", "p1", "p2", "k3"), k))}
        for term in projection_terms:
            values[term.camera][term.component] += term.value
        names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
        if len(layout.cameras) == 1:
            v = values[layout.cameras[0]]
            return v["fx"], v["fy"], v["cx"], v["cy"], tuple(v[n] for n in names[4:])
        index = {c: i for i, c in enumerate(layout.cameras)}
        of_row = np.array([index[c] for c in data.camera])[data.image_of_row]
        table = np.array([[values[c][n] for n in names] for c in layout.cameras])[of_row]  # (N, 9)
        return table[:, 0], table[:, 1], table[:, 2], table[:, 3], tuple(table[:, 4 + i] for i in range(5))

