"""Synthetic datasets from the model itself: known truth for tests and benchmarks.

The stances here only satisfy visibility (all 24 vertices inside the image with a margin, board facing the
camera); they are not checked for collisions and are not meant to be sent to a robot.
"""

from __future__ import annotations

import numpy as np

from naocal.solver.robot import default_intrinsics
from naocal.solver.joints import HEAD_COLUMNS, JOINTS, LEG_COLUMNS, LEGS, leg_joints
from naocal.solver.kinematics import camera_fk, leg_fk, project_sole_points
from naocal.solver.adapter import make_model_data  # noqa: F401 (its home is solver.adapter; tests import it here too)
from naocal.solver.model import Model, ModelData
from naocal.solver.nao_model import board_vertices_sole
from naocal.solver.registry import Registry
from naocal.solver.urdf import nominal_urdf

DEFAULT_INTRINSICS = default_intrinsics()  # the NAO bottom camera's prior (solver/data/nao.json)


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


def random_views(rng, setup, n_stances=12, n_postures=2, *, within_limits=True, margin_px=20.0,
                 max_tries=20000) -> ModelData:
    """ModelData (zero detections) of random views of every target of `setup` by every camera: for each target
    `n_stances` random stances of its chain, each seen by each camera at `n_postures` random postures of the
    camera's chain from which all of the board's vertices lie inside the image (`margin_px`) in front of it.

    Stances are drawn within the URDF's joint limits (0.05 rad inside); camera chains too unless not
    `within_limits` (+-pi/2 then: views a real robot may not reach, for tests of the model's mathematics).
    """
    from naocal.solver.camera import project_points, transform_to_camera
    from naocal.solver.kinematics import chain_frames

    robot = setup.robot
    joints = robot.joints

    def draw(chain, limited, n):
        lower = np.array([robot.urdf.joints[j].lower for j in chain.joint_names]) + 0.05
        upper = np.array([robot.urdf.joints[j].upper for j in chain.joint_names]) - 0.05
        if not limited:
            lower, upper = np.full(len(lower), -np.pi / 2), np.full(len(upper), np.pi / 2)
        return rng.uniform(lower, upper, size=(n, len(lower)))

    rows = []  # (theta, target, camera, stance, posture)
    for target in setup.targets:
        spec = robot.target(target)
        t_chain = robot.chain(spec.frame)
        V = spec.vertices()
        for stance in range(n_stances):
            for _ in range(max_tries):
                q_t = draw(t_chain, True, 1)[0]
                T_bt = chain_frames(t_chain, q_t[None])[1][0]
                p_base = V @ T_bt[:3, :3].T + T_bt[:3, 3]
                normal = T_bt[:3, :3] @ spec.T_frame_board[:3, 2]
                found = []
                for camera in setup.cameras:
                    intr = robot.camera(camera).intrinsics()
                    c_chain = robot.camera_chain(camera)
                    q_c = draw(c_chain, within_limits, 256)
                    T_bc = chain_frames(c_chain, q_c)[1]
                    uv, depth = project_points(transform_to_camera(T_bc, p_base[None]), intr)
                    ok = (np.all(depth > 0.05, axis=1) & np.all(uv >= margin_px, axis=(1, 2))
                          & np.all(uv[..., 0] <= intr["width_px"] - 1 - margin_px, axis=1)
                          & np.all(uv[..., 1] <= intr["height_px"] - 1 - margin_px, axis=1)
                          & ((p_base.mean(axis=0) - T_bc[:, :3, 3]) @ normal < 0))
                    found += [(camera, c_chain, q_c[k]) for k in np.flatnonzero(ok)[:n_postures]]
                if len(found) == n_postures * len(setup.cameras):
                    break
            else:
                raise RuntimeError(f"no view of target {target} found in {max_tries} tries")
            for posture, (camera, c_chain, q_c) in enumerate(found):
                theta = np.zeros(len(joints))
                for chain, q in ((t_chain, q_t), (c_chain, q_c)):
                    for j, value in zip(chain.joint_names, q):
                        theta[joints.index(j)] = value
                rows.append((theta, target, camera, stance, posture))
    M = len(rows)
    counts = [robot.target(r[1]).board.n_vertices for r in rows]
    cameras = {c: robot.camera(c).intrinsics() for c in setup.cameras}
    return ModelData(
        image_of_row=np.repeat(np.arange(M), counts), vertex=np.concatenate([np.arange(n) for n in counts]),
        uv_px=np.zeros((sum(counts), 2)), p_mount=np.concatenate([robot.target(r[1]).vertices() for r in rows]),
        target=np.array([r[1] for r in rows]), image_id=np.arange(M), stance=np.array([r[3] for r in rows]),
        head_posture=np.array([r[4] for r in rows]), theta=np.array([r[0] for r in rows]),
        direction=rng.choice([-1.0, 1.0], size=(M, len(joints))), velocity=None, cameras=cameras,
        camera=np.array([r[2] for r in rows]), joints=joints, robot=robot,
    ).sorted_by_target(setup.targets)


def synthesize_views(rng, truth: dict, setup, *, effects=(), n_stances=12, n_postures=2, pixel_noise_px=0.1,
                     velocity_rad_s=0.0, within_limits=True) -> ModelData:
    """`random_views` whose detections are the model's predictions at `truth` plus noise (any setup: cameras,
    targets); with `velocity_rad_s`, every image moves at random joint velocities of that size."""
    data = random_views(rng, setup, n_stances, n_postures, within_limits=within_limits)
    if velocity_rad_s:
        data.velocity = rng.choice([-1.0, 1.0], size=data.theta.shape) * velocity_rad_s
    registry = Registry(effects, setup=setup)
    data.uv_px = Model(data, registry).residuals(registry.from_dict(truth)) + rng.normal(
        0.0, pixel_noise_px, size=data.uv_px.shape)
    return data


def random_truth(rng, effects=(), *, joint_offset_rad=0.02, camera_rad=0.05, board_m=0.003, board_rad=0.02,
                 setup=None):
    """Parameter values of realistic size for the base model and the given effects."""
    registry = Registry(effects, setup=setup)
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
    for p in Registry(effects, setup=setup, tie_shared_motors=True).parameters:  # one motor: one offset (the NAO's
        if p.tied_to:  # HipYawPitch pair), as on the robot
            truth[p.name] = truth[p.tied_to]
    return truth


def dataset_parts(data: ModelData, *, robot_id="synthetic", pixel_noise_px=None, source="naocal synthetic"):
    """(meta, columns) of a naocal.dataset/2 holding `data`; commanded angles default to the measured ones. Gravity
    goes to dataset.json when it is the same for every image, else to the per-image gravity columns."""
    robot = data.robot
    meta = {
        "schema": "naocal.dataset/2",
        "robot": {"id": robot_id, "model": "NAO H25 V5", "description": robot.name},
        "cameras": {name: {"width_px": int(intr.get("width_px", 640)), "height_px": int(intr.get("height_px", 480)),
                           "fx_px": float(intr["fx_px"]), "fy_px": float(intr["fy_px"]), "cx_px": float(intr["cx_px"]),
                           "cy_px": float(intr["cy_px"]),
                           "distortion": [float(d) for d in intr.get("distortion", [0.0] * 5)]}
                    for name, intr in data.cameras.items() if name in set(data.camera.tolist())},
        "targets": {},
        "joints": list(data.joints),
        "source": source,
    }
    for t in dict.fromkeys(data.target.tolist()):
        board = robot.target(t).board
        mass, centre = data.loads[t]
        meta["targets"][t] = {"columns": board.columns, "rows": board.rows, "square_m": board.square_m,
                              "mass_kg": float(mass), "centre_m": [float(c) for c in centre]}
    uniform = bool(np.all(data.gravity_mps2 == data.gravity_mps2[:1]))
    if uniform and data.n_images:
        meta["gravity_mps2"] = [float(g) for g in data.gravity_mps2[0]]
    if pixel_noise_px is not None:
        meta["pixel_noise_px"] = float(pixel_noise_px)
    img = data.image_of_row
    columns = {
        "image": data.image_id[img], "camera": data.camera[img], "target": data.target[img],
        "stance": data.stance[img], "head_posture": data.head_posture[img], "vertex": data.vertex,
        "u_px": data.uv_px[:, 0], "v_px": data.uv_px[:, 1],
        "x_mount_m": data.p_mount[:, 0], "y_mount_m": data.p_mount[:, 1], "z_mount_m": data.p_mount[:, 2],
        "t_image_s": data.image_id[img] * 2.0 + 1.0, "t_joints_s": data.image_id[img] * 2.0 + 1.0,
    }
    for c, joint in enumerate(data.joints):
        columns[joint] = data.theta[img, c]
        columns["cmd_" + joint] = (data.theta if data.commanded is None else data.commanded)[img, c]
        columns["dir_" + joint] = data.direction[img, c]
        if data.velocity is not None:
            columns["vel_" + joint] = data.velocity[img, c]
    if not uniform:
        for k, axis in enumerate("xyz"):
            columns[f"gravity_{axis}_mps2"] = data.gravity_mps2[img, k]
    return meta, columns
