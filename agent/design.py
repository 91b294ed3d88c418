"""Experimental design: how much a stance tells about the parameters the agent fits (the paper's 21, and with the
GLS fit the intrinsics: `registry`), greedy D-optimal selection, and when a selection is precise enough.

The information of one stance (a leg posture seen under several head postures) is the Fisher information of its
vertex measurements about the parameters, in the registry's scaled units (value / scale):

    I_s = J^T W J,   W = (sigma_px^2 I + G Sigma_q G^T)^-1

J (rows = 2 x 24 x head postures, 21 columns) is the Model's exact Jacobian at the nominal robot. Pixel noise
(sigma_px) is independent per vertex, but the encoder quantisation error is not: a leg joint's reading error is
shared by all images of the stance (the leg does not move between head postures) and a head joint's by the 24
vertices of one image. G holds the Jacobian with respect to those joint readings (6 leg joints + 2 head joints per
image), Sigma_q = diag(sigma_q^2). Ignoring this, a design would believe that more vertices of one stance keep
adding precision; they do not.

How large sigma_q is depends on where the servo stands in its step. A servo that sees only its steps rests
anywhere in the commanded step's cell (sigma_q^2 = step^2 / 12), but gravity pulls it towards one edge: with the
load torque tau and the servo's stiffness K the rest is u + tau / (K step) steps from the cell's centre, clipped to
the cell, u uniform in [-1/2, 1/2) (backends/mock_servo.py). The fit takes the error as zero-mean (the reading is
the cell's centre), so what it meets per joint and stance is the error's second moment about the centre,
`load_error_moment`: 1/12 of a step squared unloaded, up to 1/4 (the joint always at the edge, a bias shared by
every stance loaded the same way) once the load pulls a full step. The paper plan's stances lie at 0.1-0.9 of a
step (realistic mock: K = 1300 N m/rad, loads up to 1.4 N m); a model without the load (1/12 everywhere) predicted
the optimal plan's worst std 1.6x too small and chose the stances it overrated.
"""

from __future__ import annotations

import numpy as np

from naocal.solver.joints import LEG_COLUMNS, LEG_JOINTS, leg_joints
from naocal.solver.kinematics import gravity_torques
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.robot import default_intrinsics
from naocal.solver.adapter import make_model_data

BASE_REGISTRY = Registry()  # the paper's 21 parameters


def load_error_moment(load_steps) -> np.ndarray:
    """E[x^2] of x = clip(u + a, -1/2, 1/2), u uniform in [-1/2, 1/2): the squared rest error (in steps squared) of a
    servo that rests anywhere in its cell and is pulled `load_steps` = tau / (K step) steps towards one edge."""
    a = np.minimum(np.abs(np.asarray(load_steps, dtype=float)), 1.0)
    return (0.125 - (a - 0.5) ** 3) / 3.0 + a / 4.0


def stance_information(theta, leg, stance, *, sigma_px=0.1, encoder_resolution_rad=np.radians(0.1),
                       intrinsics=None, registry: Registry = BASE_REGISTRY,
                       servo_stiffness_nm_per_rad: float | None = None) -> np.ndarray:
    """Fisher information of each stance, (S, P, P) in scaled parameter units.

    Parameters
    ----------
    theta : (M, 14) joint angles of the images, rad; the images of one stance must be consecutive and share
        their leg angles.
    leg, stance : (M,) labels; consecutive images with equal (leg, stance) form one stance (S stances).
    servo_stiffness_nm_per_rad : K of the load model (module docstring); None: the servo rests anywhere in its
        cell whatever the load (step^2 / 12).
    """
    theta = np.asarray(theta, dtype=float)
    leg, stance = np.asarray(leg), np.asarray(stance)
    extended = Registry(tuple(registry.effects) + ("head_offsets",))
    data = make_model_data(theta, leg, stance, np.zeros(len(theta), dtype=int),
                           intrinsics=intrinsics or default_intrinsics())
    model = Model(data, extended)
    # Model sorts by leg; undo it so that rows follow the given image order.
    _, J = model.evaluate(extended.zeros())
    order = np.argsort(model.data.image_id, kind="stable")
    rows_per_image = len(J) // len(theta)
    J = J.reshape(len(theta), rows_per_image * 2, -1)[order]  # (M, 48, P_ext)
    P = len(registry)
    scales = extended.scales
    J_params = J[..., :P] * scales[:P]
    head_cols = [extended.index["head_offset.HeadYaw"], extended.index["head_offset.HeadPitch"]]
    J_head = J[..., head_cols]  # d pixel / d head reading, rad

    starts = np.flatnonzero(np.r_[True, (leg[1:] != leg[:-1]) | (stance[1:] != stance[:-1])])
    ends = np.r_[starts[1:], len(theta)]
    step = encoder_resolution_rad
    info = np.empty((len(starts), P, P))
    for s, (a, b) in enumerate(zip(starts, ends)):
        n_img = b - a
        Jp = J_params[a:b].reshape(-1, P)
        leg_name = str(leg[a])
        leg_cols = [extended.index[f"joint_offset.{j}"] for j in leg_joints(leg_name)]
        G_leg = J[a:b][..., leg_cols].reshape(-1, 6)
        G_head = np.zeros((n_img * J.shape[1], 2 * n_img))
        for k in range(n_img):
            G_head[k * J.shape[1]:(k + 1) * J.shape[1], 2 * k:2 * k + 2] = J_head[a + k]
        G = np.hstack([G_leg, G_head])
        moment = np.full(G.shape[1], 1.0 / 12.0)
        if servo_stiffness_nm_per_rad is not None and step > 0:
            tau = gravity_torques(theta[a:a + 1, LEG_COLUMNS[leg_name]], leg_name)[0]
            moment[:6] = load_error_moment(tau / (servo_stiffness_nm_per_rad * step))
        info[s] = _gls_information(Jp, G, sigma_px, step * np.sqrt(moment))
    return info


def _gls_information(Jp, G, sigma_px, sigma_q) -> np.ndarray:
    """J^T (s^2 I + G diag(q^2) G^T)^-1 J by the Woodbury identity (G has few columns); sigma_q a scalar or one per
    column of G."""
    sigma_q = np.broadcast_to(np.asarray(sigma_q, dtype=float), (G.shape[1],))
    if not np.any(sigma_q > 0):
        return Jp.T @ Jp / sigma_px ** 2
    keep = sigma_q > 0
    G, sigma_q = G[:, keep], sigma_q[keep]
    GtJ = G.T @ Jp
    inner = np.diag((sigma_px / sigma_q) ** 2) + G.T @ G
    return (Jp.T @ Jp - GtJ.T @ np.linalg.solve(inner, GtJ)) / sigma_px ** 2


def predicted_std(information: np.ndarray, registry: Registry = BASE_REGISTRY) -> np.ndarray:
    """Standard deviation of each parameter (its own unit) from a total information matrix (P, P)."""
    cov = np.linalg.pinv(information)
    return np.sqrt(np.clip(np.diag(cov), 0.0, None)) * registry.scales


def log_det(information: np.ndarray) -> float:
    sign, value = np.linalg.slogdet(information)
    return float(value) if sign > 0 else -np.inf


def greedy_d_optimal(infos: np.ndarray, n_select: int, *, ridge: float | None = None) -> list[int]:
    """Greedy D-optimal choice of `n_select` stances: each step adds the one that most increases log det(A).

    infos : (S, P, P) information of each candidate. The start A = ridge * I makes the first steps well defined
    (default: 1e-6 of the mean diagonal of one candidate's information).
    """
    S, P, _ = infos.shape
    if ridge is None:
        ridge = 1e-6 * float(np.mean(np.einsum("sii->s", infos))) / P
    A = ridge * np.eye(P)
    chosen: list[int] = []
    available = np.ones(S, dtype=bool)
    for _ in range(min(n_select, S)):
        candidates = np.flatnonzero(available)
        sign, logdets = np.linalg.slogdet(A[None] + infos[candidates])
        logdets = np.where(sign > 0, logdets, -np.inf)
        best = int(candidates[int(np.argmax(logdets))])
        chosen.append(best)
        available[best] = False
        A = A + infos[best]
    return chosen


def joint_offset_indices(registry: Registry = BASE_REGISTRY) -> np.ndarray:
    return np.array([registry.index[f"joint_offset.{j}"] for j in LEG_JOINTS])


def matching_count(infos: np.ndarray, order: list[int], reference: np.ndarray,
                   registry: Registry = BASE_REGISTRY) -> dict:
    """How many of the greedily ordered stances `order` reach the precision of a reference information matrix.

    Two criteria: the D-criterion (log det, i.e. the volume of the confidence ellipsoid), and the worst predicted
    standard deviation of the 12 leg joint offsets. Returns {"d_criterion": n or None, "joint_offsets": n or None,
    "both": n or None} (None: not reached with all of `order`).
    """
    ref_logdet = log_det(reference)
    joints = joint_offset_indices(registry)
    ref_worst = float(np.max(predicted_std(reference, registry)[joints]))
    A = np.zeros_like(reference)
    found = {"d_criterion": None, "joint_offsets": None, "both": None}
    for n, s in enumerate(order, start=1):
        A = A + infos[s]
        d_ok = log_det(A) >= ref_logdet
        j_ok = bool(np.max(predicted_std(A, registry)[joints]) <= ref_worst)
        if d_ok and found["d_criterion"] is None:
            found["d_criterion"] = n
        if j_ok and found["joint_offsets"] is None:
            found["joint_offsets"] = n
        if d_ok and j_ok and found["both"] is None:
            found["both"] = n
            break
    return found


def reaching_count(infos: np.ndarray, order: list[int], target_worst_std_deg: float | None,
                   registry: Registry = BASE_REGISTRY) -> int | None:
    """How many of the greedily ordered stances `order` it takes until the predicted worst standard deviation of
    the 12 leg joint offsets is at most `target_worst_std_deg` (None: not reached with all of them, or no target)."""
    if target_worst_std_deg is None:
        return None
    joints = joint_offset_indices(registry)
    A = np.zeros(infos.shape[1:])
    for n, s in enumerate(order, start=1):
        A = A + infos[s]
        eigenvalues = np.linalg.eigvalsh(A)
        if eigenvalues[0] <= 1e-9 * eigenvalues[-1]:
            continue  # not every parameter determined yet (the pseudo-inverse would call them known)
        if np.degrees(np.max(predicted_std(A, registry)[joints])) <= target_worst_std_deg:
            return n
    return None
