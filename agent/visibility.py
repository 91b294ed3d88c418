"""Can a camera (bottom or top) see a sandal well? Projection margins, viewing angle, square size, and occlusion.

Pure, vectorised functions of the nominal model, plus `OcclusionChecker`, which casts rays in the nominal PyBullet
body (body.nao_body.NaoBody) from the camera to the printed board: the other leg, the own foot or the
head must not hide any part of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from naocal.body.nao_body import T_WORLD_TORSO, NaoBody
from naocal.body.pybullet_quiet import pybullet
from naocal.solver.camera import project_points
from naocal.solver.kinematics import camera_fk, leg_fk, project_sole_points
from naocal.solver.nao_model import BOARD_CENTER_X_M, BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M, board_vertices_sole
from naocal.solver.transforms import transform_points


@dataclass(frozen=True)
class ViewRules:
    """What a usable view of a board is.

    margin_px : every vertex at least this far inside the image (room for the camera's unknown rotation offset,
        which moves the whole board by up to fx * offset px before the agent has estimated it).
    max_tilt_deg : largest angle between the board's normal and the line of sight to its centre.
    min_square_px : smallest projected distance between neighbouring vertices.
    min_depth_m : every vertex at least this far in front of the camera.
    """

    margin_px: float = 40.0
    max_tilt_deg: float = 60.0
    min_square_px: float = 12.0
    min_depth_m: float = 0.08


def board_probe_points_sole(pad_squares: float = 0.25) -> np.ndarray:
    """Points whose view must be clear, (48, 3) in the sole frame: the 6 x 4 inner vertices' grid extended by
    `pad_squares` of a square on every side. The outer squares near the ankle lie partly under the foot by design
    (the vertices start just beyond the toes), so the outer square corners themselves are not required."""
    n_x, n_y = BOARD_COLUMNS - 1, BOARD_ROWS - 1
    xs = BOARD_CENTER_X_M + (np.arange(n_x) - (n_x - 1) / 2.0) * BOARD_SQUARE_M
    ys = (np.arange(n_y) - (n_y - 1) / 2.0) * BOARD_SQUARE_M
    pad = pad_squares * BOARD_SQUARE_M
    xs = np.concatenate([[xs[0] - pad], xs, [xs[-1] + pad]])
    ys = np.concatenate([[ys[0] - pad], ys, [ys[-1] + pad]])
    xx, yy = np.meshgrid(xs, ys)
    return np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], axis=-1)


def view_margin_px(uv_px, width_px, height_px) -> np.ndarray:
    """(N,) smallest distance (px) of any point to the image border; negative when a point is outside."""
    u, v = uv_px[..., 0], uv_px[..., 1]
    return np.min(np.minimum.reduce([u, width_px - 1 - u, v, height_px - 1 - v]), axis=-1)


def _rules_ok(uv, depth, cos_tilt, intrinsics, rules: ViewRules) -> np.ndarray:
    """The view rules on projected vertices uv (..., 24, 2), depths (..., 24) and tilt cosines (...)."""
    ok = np.all(depth > rules.min_depth_m, axis=-1) & (cos_tilt >= np.cos(np.radians(rules.max_tilt_deg)))
    uv = np.where(ok[..., None, None], uv, -1e9)  # behind the camera: no projection to speak of
    ok &= view_margin_px(uv, intrinsics["width_px"], intrinsics["height_px"]) >= rules.margin_px
    grid = uv.reshape(uv.shape[:-2] + (BOARD_ROWS - 1, BOARD_COLUMNS - 1, 2))
    step_rows = np.linalg.norm(np.diff(grid, axis=-3), axis=-1).reshape(uv.shape[:-2] + (-1,))
    step_cols = np.linalg.norm(np.diff(grid, axis=-2), axis=-1).reshape(uv.shape[:-2] + (-1,))
    ok &= np.minimum(step_rows.min(axis=-1), step_cols.min(axis=-1)) >= rules.min_square_px
    return ok


def _board_centre_and_normal(T_torso_sole):
    centre = T_torso_sole[:, :3, 3] + T_torso_sole[:, :3, 0] * BOARD_CENTER_X_M
    return centre, T_torso_sole[:, :3, 2]


def views_ok(T_torso_cam, T_torso_sole, intrinsics, rules: ViewRules = ViewRules(), camera_offset=None) -> np.ndarray:
    """(N,) True where the nominal model sees all 24 vertices of the board well (see ViewRules).

    T_torso_cam, T_torso_sole : (N, 4, 4), paired views.
    camera_offset : optional (3, 3) rotation of the camera in its own frame (Eq. 3's Rot_y Rot_x Rot_z), e.g. the
        prior of a real head's camera rotation.
    """
    if camera_offset is not None:
        T_torso_cam = T_torso_cam.copy()
        T_torso_cam[:, :3, :3] = T_torso_cam[:, :3, :3] @ camera_offset
    uv, depth = project_sole_points(T_torso_cam, T_torso_sole, board_vertices_sole(), intrinsics)
    centre, normal = _board_centre_and_normal(T_torso_sole)
    sight = centre - T_torso_cam[:, :3, 3]
    cos_tilt = -np.einsum("ni,ni->n", normal, sight) / np.linalg.norm(sight, axis=1)
    return _rules_ok(uv, depth, cos_tilt, intrinsics, rules)


def view_matrix(q_leg, leg, q_head, intrinsics, rules: ViewRules = ViewRules(), camera_offset=None,
                camera: str = "bottom") -> np.ndarray:
    """(N, H) visibility of N leg stances (N, 6) of `leg` under H head postures (H, 2) through `camera`: every
    pair."""
    T_sole = leg_fk(np.atleast_2d(q_leg), leg)
    T_cam = camera_fk(np.atleast_2d(q_head), camera)
    if camera_offset is not None:
        T_cam[:, :3, :3] = T_cam[:, :3, :3] @ camera_offset
    n, h = len(T_sole), len(T_cam)
    V = board_vertices_sole()
    p_torso = np.einsum("nij,kj->nki", T_sole[:, :3, :3], V) + T_sole[:, None, :3, 3]  # (n, 24, 3)
    R, t = T_cam[:, :3, :3], T_cam[:, :3, 3]
    # p_cam = R_h^T (p - t_h) for every camera h, as one matrix product.
    R_cat = np.transpose(R, (1, 0, 2)).reshape(3, 3 * h)
    p_cam = (p_torso.reshape(-1, 3) @ R_cat).reshape(n, len(V), h, 3) - np.einsum("hji,hj->hi", R, t)[None, None]
    p_cam = np.transpose(p_cam, (0, 2, 1, 3))  # (n, h, 24, 3)
    uv, depth = project_points(p_cam, intrinsics)  # solver.camera: the one projection, with distortion
    centre, normal = _board_centre_and_normal(T_sole)
    sight = centre[:, None, :] - t[None, :, :]
    cos_tilt = -np.einsum("ni,nhi->nh", normal, sight) / np.linalg.norm(sight, axis=2)
    return _rules_ok(uv, depth, cos_tilt, intrinsics, rules)


class OcclusionChecker:
    """Ray tests in the nominal body: is any part of a sandal's printed grid hidden from a camera?"""

    RAY_SHORTENING_M = 0.003  # stop each ray just above the board so that the board's own plate does not count

    def __init__(self, body: NaoBody):
        self.body = body
        self._points_sole = board_probe_points_sole()

    def hidden_points(self, stance, leg: str, camera: str = "bottom") -> int:
        """How many of the board's probe points (board_probe_points_sole) are hidden from `camera` at `stance` (14
        angles, solver.joints.JOINTS order)."""
        from naocal.solver.joints import HEAD_COLUMNS, LEG_COLUMNS

        stance = np.asarray(stance, dtype=float)
        self.body.set_angles(stance)
        T_world_cam = T_WORLD_TORSO @ camera_fk(stance[HEAD_COLUMNS][None], camera)[0]
        T_world_sole = T_WORLD_TORSO @ leg_fk(stance[LEG_COLUMNS[leg]][None], leg)[0]
        targets = transform_points(T_world_sole, self._points_sole)
        origin = T_world_cam[:3, 3]
        rays = targets - origin
        lengths = np.linalg.norm(rays, axis=1, keepdims=True)
        ends = origin + rays * (1.0 - self.RAY_SHORTENING_M / lengths)
        starts = np.repeat(origin[None], len(ends), axis=0)
        hits = pybullet.rayTestBatch(starts.tolist(), ends.tolist(), physicsClientId=self.body.client)
        return sum(1 for hit in hits if hit[0] != -1)

    def is_visible(self, stance, leg: str, camera: str = "bottom") -> bool:
        return self.hidden_points(stance, leg, camera) == 0
