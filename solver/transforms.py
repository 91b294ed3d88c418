"""Rotations and rigid transforms as pure, vectorised numpy functions.

Angles may be arrays of any shape S; results then have shape S + (3, 3) or S + (4, 4).
"""

import numpy as np


def _matrices(c, entries):
    """(shape of c) + (3, 3) zeros with the given entries {(row, col): array or constant}: filled in place, as
    stacking nine arrays costs more than the maths on the small arrays of a solve."""
    R = np.zeros(np.shape(c) + (3, 3))
    for (i, j), value in entries.items():
        R[..., i, j] = value
    return R


def rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(0, 0): 1.0, (1, 1): c, (1, 2): -s, (2, 1): s, (2, 2): c})


def rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(0, 0): c, (0, 2): s, (1, 1): 1.0, (2, 0): -s, (2, 2): c})


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(0, 0): c, (0, 1): -s, (1, 0): s, (1, 1): c, (2, 2): 1.0})


def d_rot_x(angle):
    """Derivative of rot_x with respect to its angle."""
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(1, 1): -s, (1, 2): -c, (2, 1): c, (2, 2): -s})


def d_rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(0, 0): -s, (0, 2): c, (2, 0): -c, (2, 2): -s})


def d_rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return _matrices(c, {(0, 0): -s, (0, 1): -c, (1, 0): c, (1, 1): -s})


def skew(v):
    """Cross-product matrix: skew(v) @ w == np.cross(v, w)."""
    v = np.asarray(v, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack([o, -z, y, z, o, -x, -y, x, o], axis=-1).reshape(v.shape[:-1] + (3, 3))


def rot_axis_angle(axis, angle):
    """Rotation by `angle` (shape S) about the unit vector `axis` (3,): Rodrigues' formula."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    for i, rot in enumerate((rot_x, rot_y, rot_z)):
        if axis[i] == 1.0 and np.count_nonzero(axis) == 1:
            return rot(angle)
    K = skew(axis)
    angle = angle[..., None, None]
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def rot_rpy(roll, pitch, yaw):
    """URDF fixed-axis roll, pitch, yaw: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def rpy_from_rot(R):
    """Inverse of rot_rpy for a single 3x3 rotation (pitch within +-pi/2)."""
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    roll = np.arctan2(R[2, 1], R[2, 2])
    yaw = np.arctan2(R[1, 0], R[0, 0])
    return float(roll), float(pitch), float(yaw)


def make_transform(R, t):
    """4x4 homogeneous transform(s) from rotation(s) (..., 3, 3) and translation(s) (..., 3)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T):
    """Inverse of rigid transform(s) (..., 4, 4)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def transform_points(T, p):
    """Apply transform(s) (..., 4, 4) to point(s) (..., 3)."""
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]
