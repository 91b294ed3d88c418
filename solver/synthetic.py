"""Synthetic datasets from the model itself: known truth for tests and benchmarks.

The stances here only satisfy visibility (all 24 vertices inside the image with a margin, board facing the
camera); they are not checked for collisions and are not meant to be sent to a robot.
"""

from __future__ import annotations

import numpy as np

from solver.joints import JOINTS, LEGS, leg_joints
from solver.kinematics import camera_fk, leg_fk, project_sole_points
from solver.model import HEAD_COLUMNS, LEG_COLUMNS, Model, ModelData, compute_gravity_torques
from solver.nao_model import board_vertices_sole
from solver.registry import Registry
from solver.urdf import nominal_urdf

DEFAULT_INTRINSICS = {"fx_px": 600.0, "fy_px": 600.0, "cx_px": 320.0, "cy_px": 240.0,
                      "distortion": [0.0, 0.0, 0.0, 0.0, 0.0], "width_px": 640, "height_px": 480}


def board_in_view(T_torso_cam, T_torso_sole, intrinsics=DEFAULT_INTRINSICS, margin_px=20.0):
    """(N,) True where all vertices project inside the image with a margin and the board faces the camera."""
    V = board_vertices_sole()
    uv, x = project_sole_points(T_torso_cam, T_torso_sole, V, intrinsics)
    u, v = uv[..., 0], uv[..., 1]
    inside = ((x > 0.05) & (u > margin_px) & (u < intrinsics["width_px"] - 1 - margin_px)
              & (v > margin_px) & (v < intrinsics["height_px"] - 1 - margin_px)).all(axis=1)
    centre = T_torso_sole[:, :3, 3] + T_torso_sole[:, :3, 0] * V[:, 0].mean() - T_torso_cam[:, :3, 3]
    facing = np.einsum("ni,ni->n", T_torso_sole[:, :3, 2], centre) < 0
    return inside & facing


def random_plan(rng, n_stances_per_leg=24, n_head_postures=3, intrinsics=DEFAULT_INTRINSICS):
    """Measured-angle table (M, 14) and leg/stance/posture labels of a random visible plan."""
    urdf = nominal_urdf()
    thetas, legs, stances, postures = [], [], [], []
    for leg in LEGS:
        names = leg_joints(leg)
        lower = np.array([urdf.joints[j].lower for j in names]) + 0.05
        upper = np.array([urdf.joints[j].upper for j in names]) - 0.05
        found = 0
        while found < n_stances_per_leg:
            q_leg = rng.uniform(lower, upper, size=(1, 6))
            heads = np.column_stack([rng.uniform(-0.5, 0.5, 64), rng.uniform(0.2, 0.48, 64)])
            ok = board_in_view(camera_fk(heads), np.repeat(leg_fk(q_leg, leg), 64, axis=0), intrinsics)
            if ok.sum() < n_head_postures:
                continue
            chosen = heads[np.flatnonzero(ok)[:n_head_postures]]
            for h, head in enumerate(chosen):
                theta = np.zeros(len(JOINTS))
                theta[LEG_COLUMNS[leg]] = q_leg[0]
                theta[HEAD_COLUMNS] = head
                thetas.append(theta), legs.append(leg), stances.append(found), postures.append(h)
            found += 1
    return np.array(thetas), np.array(legs), np.array(stances), np.array(postures)


def make_model_data(theta, leg, stance, head_posture, *, direction=None, velocity=None,
                    intrinsics=DEFAULT_INTRINSICS, gravity_torso_mps2=(-9.81, 0.0, 0.0)) -> ModelData:
    """ModelData for every vertex of every image, with zero detections (fill uv_px afterwards)."""
    M = len(theta)
    V = board_vertices_sole()
    g = np.asarray(gravity_torso_mps2, dtype=float)
    return ModelData(
        image_of_row=np.repeat(np.arange(M), len(V)), vertex=np.tile(np.arange(len(V)), M),
        uv_px=np.zeros((M * len(V), 2)), p_sole=np.tile(V, (M, 1)), leg=np.asarray(leg),
        image_id=np.arange(M), stance=np.asarray(stance), head_posture=np.asarray(head_posture),
        theta=np.asarray(theta, dtype=float),
        direction=np.zeros_like(theta) if direction is None else np.asarray(direction, dtype=float),
        tau=compute_gravity_torques(np.asarray(theta, dtype=float), np.asarray(leg), g),
        velocity=velocity, intrinsics=dict(intrinsics), gravity_torso_mps2=g,
    )


def synthesize(rng, truth: dict, *, effects=(), n_stances_per_leg=24, n_head_postures=3, pixel_noise_px=0.1,
               encoder_resolution_rad=0.0, direction=None, velocity=None):
    """A ModelData whose detections are the model's predictions at `truth` (parameter name -> value) plus noise.

    With `encoder_resolution_rad`, the measured angles are the true servo angles quantised to that resolution,
    so the model sees quantisation error as a real robot does.
    """
    theta, leg, stance, posture = random_plan(rng, n_stances_per_leg, n_head_postures)
    if direction is None:
        direction = rng.choice([-1.0, 1.0], size=theta.shape)
    data = make_model_data(theta, leg, stance, posture, direction=direction, velocity=velocity)
    registry = Registry(effects)
    uv = data.uv_px + Model(data, registry).residuals(registry.from_dict(truth))
    theta_servo = theta.copy()
    if encoder_resolution_rad:
        theta = np.round(theta / encoder_resolution_rad) * encoder_resolution_rad
        data = make_model_data(theta, leg, stance, posture, direction=direction, velocity=velocity)
    data.uv_px = uv + rng.normal(0.0, pixel_noise_px, size=uv.shape)
    data.commanded = theta_servo  # the servo drives its sensor exactly to the command (as the mock does)
    return data


def random_truth(rng, effects=(), *, joint_offset_rad=0.02, camera_rad=0.05, board_m=0.003, board_rad=0.02):
    """Parameter values of realistic size for the base model and the given effects."""
    registry = Registry(effects)
    truth = {}
    for p in registry.parameters:
        if p.effect == "joint_offsets":
            truth[p.name] = rng.uniform(-joint_offset_rad, joint_offset_rad)
        elif p.effect == "camera_rotation":
            truth[p.name] = rng.uniform(-camera_rad, camera_rad)
        elif p.effect == "board_mount":
            truth[p.name] = rng.uniform(-board_rad, board_rad) if p.unit == "rad" else rng.uniform(-board_m, board_m)
        else:
            truth[p.name] = rng.uniform(-1.0, 1.0) * p.scale
    return truth


def dataset_parts(data: ModelData, *, robot_id="synthetic", pixel_noise_px=None, source="naocal synthetic"):
    """(meta, columns) of a naocal.dataset/1 holding `data`; commanded angles default to the measured ones."""
    from solver.nao_model import BOARD_CENTER_X_M, BOARD_COLUMNS, BOARD_ROWS, BOARD_SQUARE_M, SANDAL_MASS_KG

    intr = data.intrinsics
    meta = {
        "schema": "naocal.dataset/1",
        "robot": {"id": robot_id, "model": "NAO H25 V5"},
        "camera": {"name": "bottom", "width_px": int(intr.get("width_px", 640)),
                   "height_px": int(intr.get("height_px", 480)), "fx_px": float(intr["fx_px"]),
                   "fy_px": float(intr["fy_px"]), "cx_px": float(intr["cx_px"]), "cy_px": float(intr["cy_px"]),
                   "distortion": [float(d) for d in intr.get("distortion", [0.0] * 5)]},
        "board": {"columns": BOARD_COLUMNS, "rows": BOARD_ROWS, "square_m": BOARD_SQUARE_M,
                  "center_x_m": BOARD_CENTER_X_M, "mass_kg": SANDAL_MASS_KG},
        "source": source,
        "gravity_torso_mps2": [float(g) for g in data.gravity_torso_mps2],
    }
    if pixel_noise_px is not None:
        meta["pixel_noise_px"] = float(pixel_noise_px)
    img = data.image_of_row
    columns = {
        "image": data.image_id[img], "leg": data.leg[img], "stance": data.stance[img],
        "head_posture": data.head_posture[img], "vertex": data.vertex,
        "u_px": data.uv_px[:, 0], "v_px": data.uv_px[:, 1],
        "x_sole_m": data.p_sole[:, 0], "y_sole_m": data.p_sole[:, 1], "z_sole_m": data.p_sole[:, 2],
        "t_image_s": data.image_id[img] * 2.0 + 1.0, "t_joints_s": data.image_id[img] * 2.0 + 1.0,
    }
    for c, joint in enumerate(JOINTS):
        columns[joint] = data.theta[img, c]
        columns["cmd_" + joint] = (data.theta if data.commanded is None else data.commanded)[img, c]
        columns["dir_" + joint] = data.direction[img, c]
        if data.velocity is not None:
            columns["vel_" + joint] = data.velocity[img, c]
    return meta, columns
