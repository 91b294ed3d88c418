"""Random stances in which a mock robot's camera sees one sandal whole: a small sampler for the mock's tests.

Candidates are random commands within the joint limits with the legs raised (HipPitch negative) and the head
pitched down towards the feet. A candidate is kept when, on the mock's TRUE robot (command + offsets), all 24
vertices of one board project inside the image with a margin, the board faces the camera within
`max_view_angle_deg`, nothing of the robot lies between the camera and a ring around each vertex, and the stance is
safe (no collision, no ground contact) on the straight way from the mock's default posture, through which
`capture_at` passes between stances.
"""

from __future__ import annotations

import numpy as np

from naocal.backends.mock import DEFAULT_POSTURE
from naocal.solver.joints import JOINT_INDEX, JOINTS, LEGS, leg_joints
from naocal.solver.kinematics import camera_fk, leg_fk
from naocal.solver.limits import head_pitch_limits
from naocal.solver.nao_model import BOARD_SQUARE_M

RING_M = 0.2 * BOARD_SQUARE_M  # clearance around each vertex (in the board plane) that must be in sight


def _random_commands(mock, rng, n: int) -> np.ndarray:
    limits = mock.joint_limits()
    lower = np.array([limits[j][0] for j in JOINTS]) + 0.02
    upper = np.array([limits[j][1] for j in JOINTS]) - 0.02
    Q = rng.uniform(lower, upper, size=(n, len(JOINTS)))
    for leg in LEGS:
        Q[:, JOINT_INDEX[f"{leg}HipPitch"]] = rng.uniform(-1.5, -0.2, n)
    Q[:, JOINT_INDEX["HeadYaw"]] = rng.uniform(-0.6, 0.6, n)
    upper_pitch = np.array([head_pitch_limits(y)[1] for y in Q[:, JOINT_INDEX["HeadYaw"]]])
    Q[:, JOINT_INDEX["HeadPitch"]] = rng.uniform(0.0, 1.0, n) * (upper_pitch - 0.01)
    Q[:, JOINT_INDEX["RHipYawPitch"]] = Q[:, JOINT_INDEX["LHipYawPitch"]]
    return Q


def _board_in_view(mock, Q_true: np.ndarray, leg: str, margin_px: float, max_view_angle_deg: float) -> np.ndarray:
    """(n,) all vertices of this leg's board inside the image with a margin, board facing the camera."""
    truth = mock.truth
    head = Q_true[:, [JOINT_INDEX["HeadYaw"], JOINT_INDEX["HeadPitch"]]]
    T_torso_cam = camera_fk(head)
    T_torso_cam[:, :3, :3] = T_torso_cam[:, :3, :3] @ truth.R_cam_offset()
    q_leg = Q_true[:, [JOINT_INDEX[j] for j in leg_joints(leg)]]
    T_torso_board = leg_fk(q_leg, leg, thigh_delta_m=truth.thigh_delta_m[leg],
                           tibia_delta_m=truth.tibia_delta_m[leg]) @ mock._T_sole_board[leg]
    T_cam_board = np.linalg.inv(T_torso_cam) @ T_torso_board
    V = mock._vertices_board
    p = np.einsum("nij,kj->nki", T_cam_board[:, :3, :3], V) + T_cam_board[:, None, :3, 3]
    cam = truth.camera
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = cam.project(p)
        inside = ((p[..., 0] > 0.05) & (uv[..., 0] > margin_px) & (uv[..., 0] < cam.width_px - 1 - margin_px)
                  & (uv[..., 1] > margin_px) & (uv[..., 1] < cam.height_px - 1 - margin_px)).all(axis=1)
        centre = T_cam_board[:, :3, 3]
        cos_view = -np.einsum("ni,ni->n", T_cam_board[:, :3, 2], centre) / np.linalg.norm(centre, axis=1)
    return inside & (cos_view > np.cos(np.radians(max_view_angle_deg)))


def _in_sight(mock, q_true: np.ndarray, leg: str) -> bool:
    """Nothing of the robot between the camera and each vertex or the ring of 8 points around it."""
    T_world_cam = mock._T_world_cam(q_true)
    T_world_board = mock._T_world_board(q_true, leg)
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(8)]) * RING_M
    points = (mock._vertices_board[:, None, :] + np.vstack([np.zeros(3), ring])[None]).reshape(-1, 3)
    points_world = points @ T_world_board[:3, :3].T + T_world_board[:3, 3]
    return not mock.body.hidden(q_true, T_world_cam[:3, 3], points_world).any()


def visible_stances(mock, n: int, seed: int = 0, *, margin_px: float = 25.0, max_view_angle_deg: float = 60.0,
                    both: bool = False, max_candidates: int = 200000):
    """`n` (command {joint: rad}, leg) pairs whose board `leg` the camera sees whole (module docstring); with
    `both`, stances in which it sees both boards whole."""
    rng = np.random.default_rng(seed)
    alpha = np.array([mock.truth.alpha_rad[j] for j in JOINTS])
    home = np.array([DEFAULT_POSTURE[j] for j in JOINTS])
    found = []
    tried = 0
    while len(found) < n and tried < max_candidates:
        Q = _random_commands(mock, rng, 4000)
        tried += len(Q)
        Q_true = Q + alpha
        ok = {leg: _board_in_view(mock, Q_true, leg, margin_px, max_view_angle_deg) for leg in LEGS}
        for i in np.flatnonzero((ok["L"] & ok["R"]) if both else (ok["L"] | ok["R"])):
            leg = "L" if ok["L"][i] else "R"
            if not all(mock.checker.is_safe(mock._true_static(home + f * (Q[i] - home)))
                       for f in np.linspace(0.1, 1.0, 10)):
                continue
            if not all(_in_sight(mock, Q_true[i], side) for side in (LEGS if both else (leg,))):
                continue
            found.append(({j: float(v) for j, v in zip(JOINTS, Q[i])}, leg))
            if len(found) == n:
                break
    if len(found) < n:
        raise RuntimeError(f"only {len(found)} visible stances in {tried} candidates")
    return found


def move_and_settle(mock, command: dict, speed_fraction: float = 1.0) -> float:
    """Command a stance and wait until it is reached; the time at which it was."""
    before = mock.servo_angles()
    mock.command(command, speed_fraction)
    t_still = mock.now() + mock.command_delay_s + max(
        abs(command[j] - before[j]) / (speed_fraction * mock.max_speeds()[j]) for j in command)
    mock.sleep(max(t_still - mock.now(), 0.0))
    return t_still


def capture_at(mock, command: dict, speed_fraction: float = 1.0):
    """Go home (the default posture), then to the stance; the first image exposed there (see settle_and_capture)."""
    move_and_settle(mock, DEFAULT_POSTURE, speed_fraction)
    return settle_and_capture(mock, command, speed_fraction)


def settle_and_capture(mock, command: dict, speed_fraction: float = 1.0):
    """Command a stance, wait until it is reached and an image exposed afterwards has arrived; that image."""
    t_still = move_and_settle(mock, command, speed_fraction)
    mock.sleep(mock.camera_delay_s + 0.1)
    image = mock.capture()
    assert image is not None and mock.exposure_time(image) > t_still
    return image
