"""The measurement model: predicted pixel positions of the board vertices and their exact Jacobian.

    q            = theta + sum over joint-level terms (value * regressor)           (Eq. 2, plus effects)
    T_torso_cam  = T_torso_cam(q_head) @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw)   (Eq. 3)
    p_sole'      = Rot_z(rot_z) @ Trans_x(x) @ Trans_y(y) @ p_sole                 (Eq. 4)
    p_cam        = T_cam_torso @ T_torso_sole(q_leg) @ p_sole'
    (u, v)       = (cx, cy) + (fx, fy) * distort(-y/x, -z/x)                         (Eq. 1, OpenCV distortion)
    residual     = predicted - detected, px

Everything here is a pure function of (ModelData, Registry, parameter vector).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.joints import HEAD_JOINTS, JOINT_INDEX, JOINTS, LEGS, leg_joints
from solver.kinematics import chain_frames, gravity_torques, joint_axes_and_origins, leg_length_deltas
from solver.nao_model import THIGH_JOINT_INDEX, TIBIA_JOINT_INDEX, head_chain, leg_chain
from solver.registry import Registry
from solver.transforms import d_rot_x, d_rot_y, d_rot_z, rot_x, rot_y, rot_z

LEG_COLUMNS = {leg: np.array([JOINT_INDEX[j] for j in leg_joints(leg)]) for leg in LEGS}
HEAD_COLUMNS = np.array([JOINT_INDEX[j] for j in HEAD_JOINTS])


@dataclass
class ModelData:
    """What the model needs from a dataset, as arrays. M images, N vertex rows.

    theta, direction, velocity, tau: (M, 14) per image, columns in solver.joints.JOINTS order.
    """

    image_of_row: np.ndarray  # (N,) index 0..M-1 into the per-image arrays
    vertex: np.ndarray  # (N,) vertex index on its board
    uv_px: np.ndarray  # (N, 2) detected vertex positions
    p_sole: np.ndarray  # (N, 3) nominal vertex positions in the sole frame, m
    leg: np.ndarray  # (M,) 'L' or 'R'
    image_id: np.ndarray  # (M,) the dataset's image index
    stance: np.ndarray  # (M,)
    head_posture: np.ndarray  # (M,)
    theta: np.ndarray  # (M, 14) measured angles, rad
    direction: np.ndarray  # (M, 14) approach direction -1/0/1
    tau: np.ndarray  # (M, 14) static gravity torque at theta (leg joints of the image's leg), N m
    velocity: np.ndarray | None  # (M, 14) rad/s at t_joints, or None if the dataset has none
    intrinsics: dict  # fx_px, fy_px, cx_px, cy_px, distortion (5,)
    gravity_torso_mps2: np.ndarray = field(default_factory=lambda: np.array([-9.81, 0.0, 0.0]))
    angle_choice: "AngleChoice | None" = None  # how theta was taken from a dataset (None: given directly)
    commanded: np.ndarray | None = None  # (M, 14) commanded angles, when known

    @property
    def n_rows(self) -> int:
        return len(self.image_of_row)

    @property
    def n_images(self) -> int:
        return len(self.leg)

    def is_sorted_by_leg(self) -> bool:
        """Images of leg L before those of R, and rows in image order: the layout Model works on."""
        leg_key = (self.leg == "R").astype(int)
        return bool(np.all(np.diff(leg_key) >= 0) and np.all(np.diff(self.image_of_row) >= 0))

    def sorted_by_leg(self) -> "ModelData":
        """The same data with images ordered L then R (stable) and rows in image order."""
        if self.is_sorted_by_leg():
            return self
        order = np.argsort((self.leg == "R").astype(int), kind="stable")
        return self.reordered(order)

    def rows_of_images(self, images: np.ndarray) -> np.ndarray:
        return np.flatnonzero(np.isin(self.image_of_row, images))

    def subset(self, images) -> "ModelData":
        """The data of some images only (index 0..M-1), re-indexed."""
        images = np.asarray(sorted(set(np.asarray(images).tolist())), dtype=int)
        return self.reordered(images)

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
            p_sole=self.p_sole[rows], leg=self.leg[images], image_id=self.image_id[images],
            stance=self.stance[images], head_posture=self.head_posture[images], theta=self.theta[images],
            direction=self.direction[images], tau=self.tau[images], velocity=per_image(self.velocity),
            intrinsics=self.intrinsics, gravity_torso_mps2=self.gravity_torso_mps2, angle_choice=self.angle_choice,
            commanded=per_image(self.commanded),
        )


def compute_gravity_torques(theta, leg, gravity_torso_mps2):
    """(M, 14) gravity torque on the joints of each image's own leg (zero elsewhere)."""
    tau = np.zeros_like(theta)
    for name in LEGS:
        images = np.flatnonzero(leg == name)
        if len(images):
            cols = LEG_COLUMNS[name]
            tau[np.ix_(images, cols)] = gravity_torques(theta[np.ix_(images, cols)], name, gravity_torso_mps2)
    return tau


@dataclass
class _Terms:
    """Precomputed layout of one (data, registry) pair: which entries of the parameter vector do what."""

    joint_param: np.ndarray  # (K,) parameter index of each joint-level entry
    joint_col: np.ndarray  # (K,) joint column it acts on
    regressor: np.ndarray  # (M, K) multiplier of the parameter's value for each image
    index: dict  # parameter name -> full index
    uses_head: bool  # some term acts on a head joint
    elastic: np.ndarray  # (K,) bool: the entry is a compliance (its regressor is tau at the model's own angles)


def _terms(data: ModelData, registry: Registry) -> _Terms:
    params, cols, regs, elastic = [], [], [], []
    M = data.n_images
    for i, p in enumerate(registry.parameters):
        effect = p.effect
        if effect == "time_lag":
            if data.velocity is None:
                raise ValueError("the time_lag effect needs joint velocities (vel_<Joint> columns) in the dataset")
            for c in range(len(JOINTS)):
                params.append(i), cols.append(c), regs.append(data.velocity[:, c]), elastic.append(False)
            continue
        if p.joint is None:
            continue
        c = JOINT_INDEX[p.joint]
        if effect in ("joint_offsets", "head_offsets"):
            reg = np.ones(M)
        elif effect == "elasticity":
            reg = data.tau[:, c]  # replaced by tau at the model's angles in Model.joint_state
        elif effect == "backlash":
            reg = data.direction[:, c]
        else:
            raise AssertionError(effect)
        params.append(i), cols.append(c), regs.append(reg), elastic.append(effect == "elasticity")
    regressor = np.stack(regs, axis=1) if regs else np.zeros((M, 0))
    cols = np.array(cols, dtype=int)
    uses_head = bool(np.isin(cols, HEAD_COLUMNS).any())
    return _Terms(np.array(params, dtype=int), cols, regressor, registry.index, uses_head,
                  np.array(elastic, dtype=bool))


def _get(values, terms, name, default=0.0):
    i = terms.index.get(name)
    return default if i is None else values[i]


def _distort(xn, yn, k):
    """OpenCV distortion of normalised coordinates and its 2x2 Jacobian (N, 2, 2)."""
    k1, k2, p1, p2, k3 = k
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = 2.0 * k1 + r2 * (4.0 * k2 + 6.0 * k3 * r2)  # d radial / d r2, times 2
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    D = np.empty(xn.shape + (2, 2))
    D[:, 0, 0] = radial + g * xn * xn + 2.0 * p1 * yn + 6.0 * p2 * xn
    D[:, 0, 1] = g * xn * yn + 2.0 * p1 * xn + 2.0 * p2 * yn
    D[:, 1, 0] = g * xn * yn + 2.0 * p1 * xn + 2.0 * p2 * yn
    D[:, 1, 1] = radial + g * yn * yn + 6.0 * p1 * yn + 2.0 * p2 * xn
    return xd, yd, r2, D


def _cross(a, b):
    """Cross product over the last axis (faster than np.cross for small broadcast arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _yield_to_gravity(q0, compliance, leg, gravity_torso_mps2, *, sag_guess=None, tolerance_rad=1e-13,
                      max_iterations=20):
    """Solve q = q0 + C tau(q) for one leg's angles (m, 6) by Newton's method, from q0 + sag_guess (m, 6).

    Returns q (m, 6), tau(q) (m, 6) and A = I - C dtau/dq (m, 6, 6), the matrix the implicit derivative needs.
    """
    q = q0.copy() if sag_guess is None else q0 + sag_guess
    eye = np.eye(q0.shape[1])
    for _ in range(max_iterations):
        tau, dtau = gravity_torques(q, leg, gravity_torso_mps2, jacobian=True)
        A = eye - compliance[:, None] * dtau
        misfit = q0 + compliance * tau - q
        if np.max(np.abs(misfit), initial=0.0) < tolerance_rad:
            break
        step = np.linalg.solve(A, misfit[..., None])[..., 0]
        if not np.all(np.isfinite(step)):
            raise FloatingPointError(f"elasticity: no equilibrium for compliances {compliance} rad/(N m)")
        q = q + step
    else:  # rounding can keep the misfit just above the tolerance: the last iterate is as good as it gets
        tau, dtau = gravity_torques(q, leg, gravity_torso_mps2, jacobian=True)
        A = eye - compliance[:, None] * dtau
    return q, tau, A


class Model:
    """Residuals and exact Jacobian of one dataset under one registry.

    Works on the data sorted by leg (`self.data`), so each leg's images and rows are contiguous slices.
    """

    def __init__(self, data: ModelData, registry: Registry):
        self.data = data = data.sorted_by_leg()
        self.registry = registry
        self.terms = t = _terms(data, registry)
        n_images_L = int(np.sum(data.leg == "L"))
        n_rows_L = int(np.searchsorted(data.image_of_row, n_images_L))
        self.image_slices = {"L": slice(0, n_images_L), "R": slice(n_images_L, data.n_images)}
        self.row_slices = {"L": slice(0, n_rows_L), "R": slice(n_rows_L, data.n_rows)}
        P, K = len(registry), len(t.joint_param)
        self._entry_to_joint = np.zeros((K, len(JOINTS)))
        self._entry_to_joint[np.arange(K), t.joint_col] = 1.0
        self._entry_to_param = np.zeros((K, P))
        self._entry_to_param[np.arange(K), t.joint_param] = 1.0
        counts = np.bincount(data.image_of_row, minlength=data.n_images)
        self._regular = bool(data.n_images and np.all(counts == counts[0]))  # same vertex count in every image
        self._head_cache = None
        self._sag = {}  # leg -> last solved elastic sag (m, 6): where Newton starts next time, not a result

    def _head_fk(self, q_head):
        """Head chain FK, cached: without head terms the head angles never change during a fit."""
        key = q_head.tobytes()
        if self._head_cache is None or self._head_cache[0] != key:
            self._head_cache = (key, *chain_frames(head_chain("bottom"), q_head))
        return self._head_cache[1], self._head_cache[2]

    def joint_angles(self, values) -> np.ndarray:
        """q (M, 14): measured angles plus every joint-level term."""
        return self.joint_state(values)[0]

    def joint_state(self, values, *, jacobian=False):
        """q (M, 14), the regressors (M, K) at q, and with `jacobian` dq/dvalues (M, 14, P) (else None).

        Elasticity makes q implicit: a joint yields to the gravity torque at the angle it actually has,
        q = q0 + C tau(q) with q0 = theta + the other terms and C the compliances. We solve it per leg by Newton's
        method and differentiate it by the implicit function theorem: dq/dp = (I - C dtau/dq)^-1 d(q0 + C tau)/dp.
        """
        t, values = self.terms, np.asarray(values, dtype=float)
        steady = ~t.elastic
        q = self.data.theta + (t.regressor[:, steady] * values[t.joint_param[steady]]) @ self._entry_to_joint[steady]
        regressor, yield_matrix = t.regressor, {}
        if t.elastic.any():
            regressor = t.regressor.copy()
            compliance = values[t.joint_param[t.elastic]] @ self._entry_to_joint[t.elastic]  # (14,)
            for leg in LEGS:
                images, cols = self.image_slices[leg], LEG_COLUMNS[leg]
                if images.start == images.stop:
                    continue
                q0_leg = q[images][:, cols]
                q_leg, tau, A = _yield_to_gravity(q0_leg, compliance[cols], leg, self.data.gravity_torso_mps2,
                                                  sag_guess=self._sag.get(leg))
                self._sag[leg] = q_leg - q0_leg  # the next evaluation (a nearby step) starts from this sag
                q[images, cols[0]:cols[-1] + 1] = q_leg
                regressor[images, np.flatnonzero(t.elastic)] = 0.0  # this leg's images: only its own joints yield
                on_leg = t.elastic & np.isin(t.joint_col, cols)
                regressor[images, np.flatnonzero(on_leg)] = tau[:, np.searchsorted(cols, t.joint_col[on_leg])]
                yield_matrix[leg] = A
        if not jacobian:
            return q, regressor, None
        M, P = self.data.n_images, len(values)
        dq = np.zeros((M, len(JOINTS), P))
        dq[:, t.joint_col, t.joint_param] = regressor
        for leg, A in yield_matrix.items():
            images, cols = self.image_slices[leg], LEG_COLUMNS[leg]
            dq[images, cols[0]:cols[-1] + 1] = np.linalg.solve(A, dq[images, cols[0]:cols[-1] + 1])
        return q, regressor, dq

    def residuals(self, values) -> np.ndarray:
        """Predicted minus detected pixel positions, (N, 2), rows as in `self.data`."""
        return self.evaluate(values, jacobian=False)[0]

    def board_twist_jacobian(self, values) -> np.ndarray:
        """(N, 2, 6): d residual / d twist (v, w) of each image's board in the camera frame, v in m, w in rad.

        Its six columns per image span every rigid motion of that board relative to the camera (what kinematic
        errors can do); the diagnostics split residuals into this rigid part and a non-rigid remainder.
        """
        return self.evaluate(values, jacobian=False, _twist_only=True)[1]

    def evaluate(self, values, *, jacobian=True, _twist_only=False):
        """Residuals (N, 2) and, if asked, the Jacobian (N, 2, P) with respect to the full parameter vector."""
        data, t = self.data, self.terms
        values = np.asarray(values, dtype=float)
        img = data.image_of_row
        N, M = data.n_rows, data.n_images
        elastic = bool(t.elastic.any()) and jacobian and not _twist_only
        q, regressor, dq_dvalues = self.joint_state(values, jacobian=elastic)

        # Legs (Eq. 2): sole poses, and for the Jacobian the joint axes, origins and link directions.
        R_ts, t_ts = np.empty((M, 3, 3)), np.empty((M, 3))
        leg_axes, leg_origins, link_dirs = np.zeros((M, 6, 3)), np.zeros((M, 6, 3)), np.zeros((M, 2, 3))
        for leg in LEGS:
            images = self.image_slices[leg]
            if images.start == images.stop:
                continue
            chain = leg_chain(leg)
            deltas = leg_length_deltas(_get(values, t, f"link_length.{leg}.thigh"),
                                       _get(values, t, f"link_length.{leg}.tibia"))
            frames, T_end = chain_frames(chain, q[images][:, LEG_COLUMNS[leg]], length_deltas_m=deltas)
            R_ts[images], t_ts[images] = T_end[:, :3, :3], T_end[:, :3, 3]
            if jacobian:
                leg_axes[images], leg_origins[images] = joint_axes_and_origins(frames, chain)
                for k, j in enumerate((THIGH_JOINT_INDEX, TIBIA_JOINT_INDEX)):
                    offset = chain.T_origin[j + 1][:3, 3]
                    link_dirs[images, k] = frames[:, j, :3, :3] @ (offset / np.linalg.norm(offset))

        # Head and camera (Eq. 3): R_tc = R_tc0 @ R_off.
        chain = head_chain("bottom")
        head_frames, T_torso_cam0 = self._head_fk(q[:, HEAD_COLUMNS])
        roll, pitch, yaw = (_get(values, t, f"camera.{a}") for a in ("roll", "pitch", "yaw"))
        Ry, Rx, Rz = rot_y(pitch), rot_x(roll), rot_z(yaw)
        R_off = Ry @ Rx @ Rz
        R_tc = T_torso_cam0[:, :3, :3] @ R_off
        t_tc = T_torso_cam0[:, :3, 3]
        R_ct = np.swapaxes(R_tc, 1, 2)
        R_cs = R_ct @ R_ts  # pose of the sole in the camera frame, per image
        t_cs = np.einsum("mij,mj->mi", R_ct, t_ts - t_tc)

        # Board mount (Eq. 4), per leg.
        p_board = np.empty((N, 3))
        board_rot = {}
        for leg in LEGS:
            rows = self.row_slices[leg]
            rz = _get(values, t, f"board.{leg}.rot_z")
            c, s = np.cos(rz), np.sin(rz)
            px = data.p_sole[rows, 0] + _get(values, t, f"board.{leg}.trans_x")
            py = data.p_sole[rows, 1] + _get(values, t, f"board.{leg}.trans_y")
            p_board[rows, 0], p_board[rows, 1], p_board[rows, 2] = c * px - s * py, s * px + c * py, data.p_sole[rows, 2]
            board_rot[leg] = (c, s, px, py)
        if self._regular:  # batched per image: (M, V, 3) @ (M, 3, 3)^T
            V = N // M
            p_cam = (p_board.reshape(M, V, 3) @ np.swapaxes(R_cs, 1, 2) + t_cs[:, None, :]).reshape(N, 3)
        else:
            p_cam = np.einsum("nij,nj->ni", R_cs[img], p_board) + t_cs[img]

        # Projection (Eq. 1) with the prior distortion plus the distortion effect.
        intr = data.intrinsics
        fx = intr["fx_px"] + _get(values, t, "intrinsics.fx")
        fy = intr["fy_px"] + _get(values, t, "intrinsics.fy")
        cx = intr["cx_px"] + _get(values, t, "intrinsics.cx")
        cy = intr["cy_px"] + _get(values, t, "intrinsics.cy")
        k = np.array(intr.get("distortion", (0, 0, 0, 0, 0)), dtype=float).copy()
        k[0] += _get(values, t, "distortion.k1")
        k[1] += _get(values, t, "distortion.k2")
        x, y, z = p_cam[:, 0], p_cam[:, 1], p_cam[:, 2]
        inv_x = 1.0 / x
        xn, yn = -y * inv_x, -z * inv_x
        xd, yd, r2, D = _distort(xn, yn, k)
        residual = np.stack([cx + fx * xd, cy + fy * yd], axis=1) - data.uv_px
        if not (jacobian or _twist_only):
            return residual, None

        # Every kinematic parameter moves the board rigidly relative to the camera: a twist (v, w) per image in the
        # camera frame, dp = v + w x p. Per vertex, d(u, v)/d twist is the 2 x 6 interaction matrix L = [A, p x a_i].
        L = np.empty((N, 2, 6))
        for row, f, D_xn, D_yn in ((0, fx, D[:, 0, 0], D[:, 0, 1]), (1, fy, D[:, 1, 0], D[:, 1, 1])):
            a0 = -(D_xn * xn + D_yn * yn) * f * inv_x  # d u / d p_cam (row 0) or d v / d p_cam (row 1)
            a1 = -D_xn * f * inv_x
            a2 = -D_yn * f * inv_x
            L[:, row, 0], L[:, row, 1], L[:, row, 2] = a0, a1, a2
            L[:, row, 3] = y * a2 - z * a1  # p x a
            L[:, row, 4] = z * a0 - x * a2
            L[:, row, 5] = x * a1 - y * a0
        if _twist_only:
            return residual, L

        P = len(values)
        twists = np.zeros((M, 6, P))  # per image: d(v, w) / d parameter
        joint_twists = np.zeros((M, 6, len(JOINTS)))
        for leg in LEGS:
            images = self.image_slices[leg]
            if images.start == images.stop:
                continue
            z_c = np.einsum("mij,mkj->mki", R_ct[images], leg_axes[images])
            o_c = np.einsum("mij,mkj->mki", R_ct[images], leg_origins[images] - t_tc[images, None, :])
            joint_twists[images, :3, LEG_COLUMNS[leg][0]:LEG_COLUMNS[leg][-1] + 1] = np.swapaxes(_cross(o_c, z_c), 1, 2)
            joint_twists[images, 3:, LEG_COLUMNS[leg][0]:LEG_COLUMNS[leg][-1] + 1] = np.swapaxes(z_c, 1, 2)
            if f"board.{leg}.rot_z" in t.index:
                c, s, _, _ = board_rot[leg]
                w = R_cs[images, :, 2]  # the sole's z axis in the camera frame
                i = t.index[f"board.{leg}.rot_z"]
                twists[images, :3, i] = _cross(t_cs[images], w)
                twists[images, 3:, i] = w
                twists[images, :3, t.index[f"board.{leg}.trans_x"]] = R_cs[images] @ np.array([c, s, 0.0])
                twists[images, :3, t.index[f"board.{leg}.trans_y"]] = R_cs[images] @ np.array([-s, c, 0.0])
            if f"link_length.{leg}.thigh" in t.index:
                dirs_c = np.einsum("mij,mkj->mik", R_ct[images], link_dirs[images])  # (m, 3, 2)
                i = t.index[f"link_length.{leg}.thigh"]
                twists[images, :3, i:i + 2] = dirs_c
        if t.uses_head:
            head_axes, head_origins = joint_axes_and_origins(head_frames, chain)
            z_c = np.einsum("mij,mkj->mki", R_ct, head_axes)
            o_c = np.einsum("mij,mkj->mki", R_ct, head_origins - t_tc[:, None, :])
            # The camera turns about the head joint: the point moves the opposite way.
            joint_twists[:, :3, HEAD_COLUMNS] = -np.swapaxes(_cross(o_c, z_c), 1, 2)
            joint_twists[:, 3:, HEAD_COLUMNS] = -np.swapaxes(z_c, 1, 2)
        if elastic:
            twists += joint_twists @ dq_dvalues
        elif len(t.joint_param):
            entries = joint_twists[:, :, t.joint_col] * regressor[:, None, :]  # (M, 6, K)
            twists += (entries.reshape(-1, entries.shape[2]) @ self._entry_to_param).reshape(M, 6, P)
        if "camera.pitch" in t.index:
            # p_cam = R_off^T p_cam0, so dp = dR^T R_off p_cam: a rotation with w = vee(dR^T R_off).
            for name, dR in (("camera.pitch", d_rot_y(pitch) @ Rx @ Rz), ("camera.roll", Ry @ d_rot_x(roll) @ Rz),
                             ("camera.yaw", Ry @ Rx @ d_rot_z(yaw))):
                G = dR.T @ R_off
                twists[:, 3:, t.index[name]] = (G[2, 1], G[0, 2], G[1, 0])

        if self._regular:
            V = N // M
            J = np.matmul(L.reshape(M, 2 * V, 6), twists).reshape(N, 2, P)
        else:
            J = np.einsum("nik,nkp->nip", L, twists[img])

        # Intrinsics and distortion.
        for name, col, axis in (("intrinsics.fx", xd, 0), ("intrinsics.fy", yd, 1),
                                ("intrinsics.cx", 1.0, 0), ("intrinsics.cy", 1.0, 1)):
            if name in t.index:
                J[:, axis, t.index[name]] = col
        for name, power in (("distortion.k1", 1), ("distortion.k2", 2)):
            if name in t.index:
                rp = r2 ** power
                J[:, 0, t.index[name]] = fx * xn * rp
                J[:, 1, t.index[name]] = fy * yn * rp
        return residual, J


def encoder_resolution(readings: np.ndarray, *, tolerance=1e-9) -> float | None:
    """The grid a joint's readings lie on (rad), or None if they are not quantised.

    Quantised readings are integer multiples of one step; we take the smallest gap between distinct readings as
    the candidate step and accept it only if every reading is a whole multiple of it.
    """
    values = np.unique(np.asarray(readings, dtype=float))
    if len(values) < 3:
        return None
    gaps = np.diff(values)
    step = float(gaps[gaps > tolerance].min()) if np.any(gaps > tolerance) else 0.0
    if step <= 0:
        return None
    # the smallest gap may be a multiple of the true step (a few stances leave wide gaps); try its integer fractions
    for divisor in range(1, 101):
        candidate = step / divisor
        multiples = values / candidate
        if np.all(np.abs(multiples - np.round(multiples)) < 1e-6):
            return candidate
    return None


@dataclass
class AngleChoice:
    """How the joint angles theta were taken from a dataset's measured and commanded columns."""

    mode: str  # 'measured', 'commanded' or 'auto'
    resolution_rad: dict  # joint -> detected encoder step (rad), for joints whose readings are quantised
    n_commanded: int  # joint readings replaced by their command
    n_total: int

    def describe(self) -> str:
        if self.mode != "auto" or not self.n_commanded:
            return f"joint angles: {self.mode} readings"
        steps = sorted({round(np.degrees(r), 4) for r in self.resolution_rad.values()})
        return (f"joint angles: readings quantised to {', '.join(f'{s:g}' for s in steps)} deg; used the command for "
                f"{self.n_commanded} of {self.n_total} still joint readings whose command lies inside the reading's "
                "quantisation cell (the servo drives its sensor to the command; the reading only says which cell)")


def choose_angles(measured, commanded, velocity, mode="auto", *, still_rad_per_s=1e-3):
    """theta (M, 14) from measured and commanded angles (M, 14), per `mode`, and an AngleChoice saying what was done.

    'measured' is the paper's choice. 'auto' also uses measured angles, except for joints whose readings are
    quantised: there, for a still joint whose command lies inside its reading's quantisation cell, the command is
    the better estimate (quantisation error up to half a step, shared by every image of a stance, otherwise
    dominates the leg offsets). 'commanded' uses the commands throughout.
    """
    measured = np.asarray(measured, dtype=float)
    commanded = np.asarray(commanded, dtype=float)
    if mode == "measured":
        return measured.copy(), AngleChoice(mode, {}, 0, measured.size)
    if mode == "commanded":
        return commanded.copy(), AngleChoice(mode, {}, measured.size, measured.size)
    if mode != "auto":
        raise ValueError(f"unknown angle mode {mode!r}: expected measured, commanded or auto")
    theta = measured.copy()
    still = np.ones(measured.shape, dtype=bool) if velocity is None else np.abs(velocity) < still_rad_per_s
    resolutions, replaced = {}, 0
    for c, joint in enumerate(JOINTS):
        step = encoder_resolution(measured[still[:, c], c])  # moving joints' readings may be interpolated
        if step is None:
            continue
        resolutions[joint] = step
        inside = still[:, c] & (np.abs(commanded[:, c] - measured[:, c]) <= 0.5 * step + 1e-9)
        theta[inside, c] = commanded[inside, c]
        replaced += int(inside.sum())
    return theta, AngleChoice(mode, resolutions, replaced, measured.size)


def model_data_from_dataset(dataset, angles: str = "auto") -> ModelData:
    """ModelData from a read `naocal.dataset/1` (solver.dataset.Dataset): per-image arrays, rows sorted by leg.

    Per-image values (leg, stance, posture, angles) are taken from the first row of each image; the reader has
    already checked that they agree within an image. `angles` chooses theta (see `choose_angles`); what was done
    is in the returned data's `angle_choice`.
    """
    cols = dataset.columns
    image = np.asarray(cols["image"], dtype=np.int64)
    image_ids, first_row, image_of_row = np.unique(image, return_index=True, return_inverse=True)
    velocity = dataset.joint_matrix("vel_")[first_row] if dataset.has_velocities else None
    commanded = dataset.joint_matrix("cmd_")[first_row]
    theta, choice = choose_angles(dataset.joint_matrix("")[first_row], commanded, velocity, angles)
    direction = dataset.joint_matrix("dir_")[first_row]
    leg = np.asarray(cols["leg"]).astype(str)[first_row]
    camera = dataset.meta["camera"]
    distortion = list(camera.get("distortion") or [0.0] * 5) + [0.0] * 5
    intrinsics = {
        "fx_px": float(camera["fx_px"]), "fy_px": float(camera["fy_px"]),
        "cx_px": float(camera["cx_px"]), "cy_px": float(camera["cy_px"]),
        "width_px": int(camera["width_px"]), "height_px": int(camera["height_px"]),
        "distortion": [float(d) for d in distortion[:5]],
    }
    gravity = np.asarray(dataset.meta.get("gravity_torso_mps2", (-9.81, 0.0, 0.0)), dtype=float)
    order = np.lexsort((np.asarray(cols["vertex"]), image_of_row))  # rows grouped by image
    data = ModelData(
        image_of_row=image_of_row[order], vertex=np.asarray(cols["vertex"], dtype=np.int64)[order],
        uv_px=np.column_stack([cols["u_px"], cols["v_px"]]).astype(float)[order],
        p_sole=np.column_stack([cols["x_sole_m"], cols["y_sole_m"], cols["z_sole_m"]]).astype(float)[order],
        leg=leg, image_id=image_ids, stance=np.asarray(cols["stance"], dtype=np.int64)[first_row],
        head_posture=np.asarray(cols["head_posture"], dtype=np.int64)[first_row], theta=theta,
        direction=direction, tau=compute_gravity_torques(theta, leg, gravity), velocity=velocity,
        intrinsics=intrinsics, gravity_torso_mps2=gravity, angle_choice=choice, commanded=commanded,
    )
    return data.sorted_by_leg()
