"""The NAO's joint names and their order (from its robot description, solver/data/nao.json): the column order of
every (..., 14) joint-angle array of the NAO-specific code (agent, backends). The solver itself reads joints from
the robot description a dataset names."""

from __future__ import annotations

import numpy as np

from naocal.solver.robot import nao

_NAO = nao()
JOINTS = _NAO.joints  # the dataset's 14 joints, in the dataset's order
HEAD_JOINTS = _NAO.named_chain("head").joint_names
LEFT_LEG_JOINTS = _NAO.named_chain("left_leg").joint_names
RIGHT_LEG_JOINTS = _NAO.named_chain("right_leg").joint_names
LEG_JOINTS = LEFT_LEG_JOINTS + RIGHT_LEG_JOINTS
LEG_JOINT_SUFFIXES = tuple(j[1:] for j in LEFT_LEG_JOINTS)
JOINT_INDEX = {name: i for i, name in enumerate(JOINTS)}
LEGS = ("L", "R")  # the sandal targets are named after their leg


def leg_joints(leg: str) -> tuple[str, ...]:
    """The six joints of leg 'L' or 'R', hip to ankle."""
    if leg == "L":
        return LEFT_LEG_JOINTS
    if leg == "R":
        return RIGHT_LEG_JOINTS
    raise ValueError(f"unknown leg {leg!r}: expected 'L' or 'R'")

# Column indices of the NAO's (..., 14) arrays: the head's and each leg's joints.
HEAD_COLUMNS = np.array([JOINT_INDEX[j] for j in HEAD_JOINTS])
LEG_COLUMNS = {leg: np.array([JOINT_INDEX[j] for j in leg_joints(leg)]) for leg in LEGS}
