"""Forward kinematics, the projection of sole points and static gravity torques: pure functions, vectorised over
configurations.

Generic functions take a `Chain` (solver.robot: any serial chain of a URDF); the NAO's own helpers (leg_fk,
camera_fk, gravity_torques of a leg) wrap them. Shapes: N configurations, k joints of the chain. Every pose is
T_base_<frame> (N, 4, 4), every point in m.
"""

from __future__ import annotations

import functools

import numpy as np

from naocal.solver.camera import project_points, transform_to_camera
from naocal.solver.nao_model import (
    BOARD_CENTER_X_M, SANDAL_MASS_KG, THIGH_JOINT_INDEX, TIBIA_JOINT_INDEX, Chain, head_chain, leg_chain,
)
from naocal.solver.transforms import rot_axis_angle, rot_x, rot_y, rot_z


def chain_frames(chain: Chain, q, *, length_deltas_m=None, origin_shifts_m=None, end_shift_m=None):
    """Poses of every joint's child frame and of the end frame in the chain's base frame.

    Parameters
    ----------
    q : (N, k) joint angles, rad.
    length_deltas_m : optional dict {joint index: (N,) or scalar} lengthening the joint's origin offset
        along its direction (used for thigh and tibia length corrections), m.
    origin_shifts_m : optional dict {joint index: (3,) or (N, 3)} added to the joint's origin translation, in the
        frame before the joint (the previous joint's child frame), m.
    end_shift_m : optional (3,) added to the end frame's translation in the last joint's child frame, m.

    Returns
    -------
    T_base_joint : (N, k, 4, 4) pose of joint k's child frame (after its rotation).
    T_base_end : (N, 4, 4).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, k = q.shape
    if k != len(chain.joint_names):
        raise ValueError(f"expected {len(chain.joint_names)} joint angles per row, got {k}")
    frames = np.zeros((n, k, 4, 4))
    frames[:, :, 3, 3] = 1.0
    R, t = None, np.zeros((n, 3))  # R None: the identity (the base frame), no product needed
    for j, (rotation, R_origin) in enumerate(_joint_rotations(chain)):
        offset = chain.T_origin[j, :3, 3]
        if length_deltas_m is not None and j in length_deltas_m:
            delta = np.asarray(length_deltas_m[j], dtype=float)
            offset = offset + delta[..., None] * (offset / np.linalg.norm(offset))
        if origin_shifts_m is not None and j in origin_shifts_m:
            offset = offset + np.asarray(origin_shifts_m[j], dtype=float)
        if R is None:
            t = t + offset
        else:
            t = t + (R @ offset[..., None])[..., 0] if np.ndim(offset) > 1 else t + R @ offset
        R_joint = rotation(q[:, j])
        R_joint = R_joint if R_origin is None else R_origin @ R_joint
        R = R_joint if R is None else R @ R_joint
        frames[:, j, :3, :3] = R
        frames[:, j, :3, 3] = t
    if R is None:
        R = np.broadcast_to(np.eye(3), (n, 3, 3))
    end = chain.T_end[:3, 3] if end_shift_m is None else chain.T_end[:3, 3] + np.asarray(end_shift_m, dtype=float)
    T_end = np.zeros((n, 4, 4))
    T_end[:, :3, :3] = R @ chain.T_end[:3, :3]
    T_end[:, :3, 3] = t + R @ end
    T_end[:, 3, 3] = 1.0
    return frames, T_end


_ROTATIONS = {}  # id(chain) -> (chain, [(rotation of the joint's angles, R_origin or None for the identity)])


def _joint_rotations(chain: Chain) -> list:
    """Each joint's rotation function (rot_x/y/z for an axis along x, y or z, else Rodrigues') and its origin's
    rotation (None: the identity), looked up once per chain: per call they cost more than the maths of a solve."""
    known = _ROTATIONS.get(id(chain))
    if known is None or known[0] is not chain:
        plan = []
        for axis, T in zip(chain.axes, chain.T_origin):
            axis = np.array(axis, dtype=float)
            R_origin = None if np.array_equal(T[:3, :3], np.eye(3)) else T[:3, :3].copy()
            unit = [i for i in range(3) if axis[i] == 1.0 and np.count_nonzero(axis) == 1]  # as rot_axis_angle
            rotation = (rot_x, rot_y, rot_z)[unit[0]] if unit else functools.partial(rot_axis_angle, axis)
            plan.append((rotation, R_origin))
        known = _ROTATIONS[id(chain)] = (chain, plan)
    return known[1]


def leg_length_deltas(thigh_delta_m=0.0, tibia_delta_m=0.0) -> dict:
    """Length corrections for `chain_frames` of a leg: thigh (hip to knee) and tibia (knee to ankle)."""
    return {THIGH_JOINT_INDEX + 1: thigh_delta_m, TIBIA_JOINT_INDEX + 1: tibia_delta_m}


def leg_fk(q_leg, leg: str, *, thigh_delta_m=0.0, tibia_delta_m=0.0):
    """T_torso_sole (N, 4, 4) for leg angles (N, 6) of leg 'L' or 'R'."""
    deltas = None
    if np.any(thigh_delta_m) or np.any(tibia_delta_m):
        deltas = leg_length_deltas(thigh_delta_m, tibia_delta_m)
    return chain_frames(leg_chain(leg), q_leg, length_deltas_m=deltas)[1]


def camera_fk(q_head, camera: str = "bottom"):
    """T_torso_camera (N, 4, 4) for head angles (N, 2) = (HeadYaw, HeadPitch). NAO camera frame."""
    return chain_frames(head_chain(camera), q_head)[1]


def project_sole_points(T_torso_cam, T_torso_sole, points_sole, intrinsics):
    """Pixel positions and depths of sole-frame points, for N views (solver.camera's projection and distortion).

    Parameters
    ----------
    T_torso_cam, T_torso_sole : (N, 4, 4) poses in the torso frame.
    points_sole : (K, 3) points in the sole frame, m.
    intrinsics : dict with fx_px, fy_px, cx_px, cy_px (and optionally distortion).

    Returns
    -------
    uv_px : (N, K, 2), depth_m : (N, K) along the optical axis (NAO camera x).
    """
    p_torso = np.einsum("nij,kj->nki", T_torso_sole[:, :3, :3], points_sole) + T_torso_sole[:, None, :3, 3]
    return project_points(transform_to_camera(T_torso_cam, p_torso), intrinsics)


def joint_axes_and_origins(T_torso_joint, chain: Chain):
    """Unit axes (N, k, 3) and positions (N, k, 3) of the chain's joints in the torso frame."""
    axes = (T_torso_joint[..., :3, :3] @ chain.axes[:, :, None])[..., 0]  # matmul: 3x einsum's speed
    return axes, T_torso_joint[..., :3, 3]


def gravity_torques(q_leg, leg: str, gravity_torso_mps2=(-9.81, 0.0, 0.0), *,
                    sandal_mass_kg=SANDAL_MASS_KG, sandal_com_sole_m=(BOARD_CENTER_X_M, 0.0, 0.0), jacobian=False):
    """Static gravity torques (N m) about a NAO leg's joints, (N, 6), with a sandal: `chain_gravity_torques` of the
    leg 'L' or 'R'."""
    return chain_gravity_torques(leg_chain(leg), q_leg, gravity_torso_mps2, load_mass_kg=sandal_mass_kg,
                                 load_com_m=sandal_com_sole_m, jacobian=jacobian)


def chain_gravity_torques(chain: Chain, q, gravity_mps2, *, load_mass_kg=0.0, load_com_m=(0.0, 0.0, 0.0),
                          jacobian=False):
    """Static torque (N m) that gravity exerts about each joint's axis of a chain hanging from its base, (N, k);
    with `jacobian`, also d tau / d q (N, k, k), [n, j, i] = d tau_j / d q_i.

    gravity_mps2 : (3,) or (N, 3), in the base frame. load_mass_kg at load_com_m (in the chain's end frame): what the
    end carries (the NAO's sandal: the board's mass at its centre).
    Joint j carries every link distal to it (the link j moves and all after it) plus the load. With
    P_j = sum_l m_l (c_l - o_j) the first mass moment of that load about the joint, tau_j = z_j . (P_j x g).
    Positive tau_j turns the chain in +q_j.
    """
    frames, T_end = chain_frames(chain, q)
    z, origins = joint_axes_and_origins(frames, chain)
    n, k = z.shape[:2]
    g = np.broadcast_to(np.asarray(gravity_mps2, dtype=float), (n, 3))
    coms = np.einsum("nkij,kj->nki", frames[..., :3, :3], chain.link_com) + frames[..., :3, 3]
    load = T_end[:, :3, :3] @ np.asarray(load_com_m, dtype=float) + T_end[:, :3, 3]
    masses = np.concatenate([chain.link_mass, [load_mass_kg]])
    points = np.concatenate([coms, load[:, None, :]], axis=1)  # (N, k + 1, 3)
    # Loads distal to each joint: mass W_j and mass-weighted position sum, by a reverse cumulative sum.
    W = np.cumsum(masses[::-1])[::-1][:-1]  # (k,)
    weighted = np.cumsum((masses[:, None] * points)[:, ::-1], axis=1)[:, ::-1][:, :-1]  # (N, k, 3)
    P = weighted - W[:, None] * origins  # (N, k, 3)
    moment = np.cross(P, g[:, None, :])  # (N, k, 3)
    tau = np.einsum("nji,nji->nj", z, moment)
    if not jacobian:
        return tau
    # Turning joint i by dq about z_i (through o_i) moves everything distal to i rigidly. For i <= j the load, o_j
    # and z_j all turn: d tau_j = (z_i x z_j).(P_j x g) + (z_j.P_j)(z_i.g) - (z_j.z_i)(P_j.g). For i > j only the
    # part of the load beyond i moves, about o_i: d tau_j = (z_j.P_i)(z_i.g) - (z_j.z_i)(P_i.g).
    zz = np.einsum("nja,nia->nji", z, z)
    zg = np.einsum("nja,na->nj", z, g)  # (N, k)
    Pg = np.einsum("nja,na->nj", P, g)
    zP = np.einsum("nja,nia->nji", z, P)  # [j, i] = z_j . P_i
    turn = np.einsum("nija,nja->nji", np.cross(z[:, :, None, :], z[:, None, :, :]), moment)  # (z_i x z_j).(P_j x g)
    lower = turn + np.diagonal(zP, axis1=1, axis2=2)[:, :, None] * zg[:, None, :] - zz * Pg[:, :, None]
    upper = zP * zg[:, None, :] - zz * Pg[:, None, :]
    dtau = np.where(np.tril(np.ones((k, k), dtype=bool))[None], lower, upper)
    return tau, dtau
