"""The NAO's own config for the NAO-specific code (agent, backends): its leg and head chains and the checkerboard
sandals, all read from its robot description (solver/data/nao.json and the URDF). The solver reads the robot
description a dataset names instead.
"""

from __future__ import annotations

import functools

import numpy as np

from naocal.solver.robot import Board, Chain, nao  # noqa: F401 (Chain: the type of leg_chain and head_chain)

_NAO = nao()
_SANDAL = _NAO.target("L")

# Checkerboard sandal (Kastner, Roefer, Laue): 7 x 5 squares of 0.025 m, 24 inner vertices,
# centre 0.170 m in front of the ankle projection in the sole plane, printed face towards +z of the sole frame.
BOARD_COLUMNS = _SANDAL.board.columns  # squares along x of the sole frame
BOARD_ROWS = _SANDAL.board.rows  # squares along y of the sole frame
BOARD_SQUARE_M = _SANDAL.board.square_m
BOARD_CENTER_X_M = float(_SANDAL.centre[0])
SANDAL_MASS_KG = _SANDAL.board.mass_kg  # taken at the board centre
N_VERTICES = _SANDAL.board.n_vertices

CAMERA_JOINTS = {name: _NAO.urdf.joint_by_child(cam.frame).name for name, cam in _NAO.cameras.items()}
SOLE_JOINTS = {leg: _NAO.urdf.joint_by_child(_NAO.target(leg).frame).name for leg in ("L", "R")}
_LEG_CHAINS = {"L": "left_leg", "R": "right_leg"}
THIGH_JOINT_INDEX = _NAO.named_chain("left_leg").index("LKneePitch") - 1  # its child frame carries the knee origin
TIBIA_JOINT_INDEX = _NAO.named_chain("left_leg").index("LAnklePitch") - 1  # ... and the tibia the ankle origin


@functools.lru_cache(maxsize=None)
def leg_chain(leg: str) -> Chain:
    """Torso -> sole of leg 'L' or 'R'."""
    return _NAO.named_chain(_LEG_CHAINS[leg])


@functools.lru_cache(maxsize=None)
def head_chain(camera: str = "bottom") -> Chain:
    """Torso -> camera frame ('bottom' or 'top'), NAO camera convention: x optical axis, y left, z up."""
    return _NAO.camera_chain(camera)


def board_vertices_sole(
    columns: int = BOARD_COLUMNS, rows: int = BOARD_ROWS, square_m: float = BOARD_SQUARE_M,
    center_x_m: float = BOARD_CENTER_X_M,
) -> np.ndarray:
    """Nominal inner vertices of a sandal in its sole frame, (n_vertices, 3).

    Vertex index = row * (columns - 1) + col; col counts along +x of the sole frame (away from the ankle),
    row along +y (to the robot's left). Vertex 0 is the one nearest the ankle on the right (-y) side.
    """
    return Board(columns, rows, square_m).vertices() + np.array([center_x_m, 0.0, 0.0])


def total_mass_kg() -> float:
    return float(sum(link.mass for link in _NAO.urdf.links.values()))
