"""Rotations and rigid transforms as pure, vectorised numpy functions.

Angles may be arrays of any shape S; results then have shape S + (3, 3) or S + (4, 4).
"""

import numpy as np


def rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(np.shape(c) + (3, 3))


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(np.shape(c) + (3, 3))


def d_rot_x(angle):
    """Derivative of rot_x with respect to its angle."""
    c, s = np.cos(angle), np.sin(angle)
    z = np.zeros_like(c)
    return np.stack([z, z, z, z, -s, -c, z, c, -s], axis=-1).reshape(np.shape(c) + (3, 3))


def d_rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    z = np.zeros_like(c)
    return np.stack([-s, z, c, z, z, z, -c, z, -s], axis=-1).reshape(np.shape(c) + (3, 3))


def d_rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    z = np.zeros_like(c)
    return np.stack([-s, -c, z, c, -s, z, z, z, z], axis=-1).reshape(np.shape(c) + (3, 3))


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
