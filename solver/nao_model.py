"""The nominal NAO: kinematic chains, masses, the checkerboard sandals and the camera, from the URDF.

A `Chain` is a serial chain of revolute joints from the torso frame to an end frame (a sole or a camera).
Every number comes from solver/data/nao_v50.urdf; nothing here is hand-typed except the sandal.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from solver.joints import HEAD_JOINTS, leg_joints
from solver.transforms import make_transform, rot_rpy
from solver.urdf import Urdf, nominal_urdf

# Checkerboard sandal (Kastner, Roefer, Laue): 7 x 5 squares of 0.025 m, 24 inner vertices,
# centre 0.170 m in front of the ankle projection in the sole plane, printed face towards +z of the sole frame.
BOARD_COLUMNS = 7  # squares along x of the sole frame
BOARD_ROWS = 5  # squares along y of the sole frame
BOARD_SQUARE_M = 0.025
BOARD_CENTER_X_M = 0.170
SANDAL_MASS_KG = 0.10  # taken at the board centre
N_VERTICES = (BOARD_COLUMNS - 1) * (BOARD_ROWS - 1)

CAMERA_JOINTS = {"bottom": "CameraBottom_sensor_fixedjoint", "top": "CameraTop_sensor_fixedjoint"}
SOLE_JOINTS = {"L": "LLeg_effector_fixedjoint", "R": "RLeg_effector_fixedjoint"}
THIGH_JOINT_INDEX = 2  # HipPitch: its child frame is the thigh, which carries the knee origin
TIBIA_JOINT_INDEX = 3  # KneePitch: its child frame is the tibia, which carries the ankle origin


@dataclass(frozen=True)
class Chain:
    """Revolute joints from the torso to an end frame.

    T_origin[k] is the fixed pose of joint k's frame in its parent's frame (before rotating about axes[k]);
    link_mass[k] and link_com[k] (in joint k's child frame) describe the link joint k moves.
    """

    joint_names: tuple[str, ...]
    T_origin: np.ndarray  # (k, 4, 4)
    axes: np.ndarray  # (k, 3) unit axes in the joint frames
    T_end: np.ndarray  # (4, 4): pose of the end frame in the last joint's child frame
    link_mass: np.ndarray  # (k,) kg
    link_com: np.ndarray  # (k, 3) m


def _joint_origin(urdf: Urdf, name: str) -> np.ndarray:
    joint = urdf.joints[name]
    return make_transform(rot_rpy(*joint.rpy), joint.xyz)


def _build_chain(urdf: Urdf, joint_names, end_joint: str) -> Chain:
    joints = [urdf.joints[n] for n in joint_names]
    for parent, child in zip(joints, joints[1:]):
        assert child.parent == parent.child, f"{child.name} does not follow {parent.name} in the URDF"
    assert urdf.joints[end_joint].parent == joints[-1].child
    return Chain(
        joint_names=tuple(joint_names),
        T_origin=np.stack([_joint_origin(urdf, n) for n in joint_names]),
        axes=np.array([j.axis for j in joints]),
        T_end=_joint_origin(urdf, end_joint),
        link_mass=np.array([urdf.links[j.child].mass for j in joints]),
        link_com=np.array([urdf.links[j.child].com for j in joints]),
    )


@functools.lru_cache(maxsize=None)
def leg_chain(leg: str) -> Chain:
    """Torso -> sole of leg 'L' or 'R'."""
    return _build_chain(nominal_urdf(), leg_joints(leg), SOLE_JOINTS[leg])


@functools.lru_cache(maxsize=None)
def head_chain(camera: str = "bottom") -> Chain:
    """Torso -> camera frame ('bottom' or 'top'), NAO camera convention: x optical axis, y left, z up."""
    return _build_chain(nominal_urdf(), HEAD_JOINTS, CAMERA_JOINTS[camera])


def board_vertices_sole(
    columns: int = BOARD_COLUMNS, rows: int = BOARD_ROWS, square_m: float = BOARD_SQUARE_M,
    center_x_m: float = BOARD_CENTER_X_M,
) -> np.ndarray:
    """Nominal inner vertices of a sandal in its sole frame, (n_vertices, 3).

    Vertex index = row * (columns - 1) + col; col counts along +x of the sole frame (away from the ankle),
    row along +y (to the robot's left). Vertex 0 is the one nearest the ankle on the right (-y) side.
    """
    cols = np.arange(columns - 1) - (columns - 2) / 2.0
    rws = np.arange(rows - 1) - (rows - 2) / 2.0
    x = center_x_m + cols[None, :] * square_m
    y = rws[:, None] * square_m
    xx, yy = np.broadcast_arrays(x, y)
    return np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], axis=-1)


def total_mass_kg() -> float:
    return float(sum(link.mass for link in nominal_urdf().links.values()))
