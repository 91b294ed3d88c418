"""From a dataset (solver.dataset, any version) to what the model works on (solver.model.ModelData): per-image
arrays, the robot description it names, and the choice of joint angles (measured readings or commands)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from naocal.solver.model import ModelData
from naocal.solver.quantisation import reading_resolution
from naocal.solver.robot import load_robot


@dataclass
class AngleChoice:
    """How the joint angles theta were taken from a dataset's measured and commanded columns."""

    mode: str  # 'measured', 'commanded' or 'cell' ('auto': the cell rule; solver.fit lets the data choose)
    resolution_rad: dict  # joint -> detected encoder step (rad), for joints whose readings are quantised
    n_commanded: int  # joint readings replaced by their command
    n_total: int

    def describe(self) -> str:
        if self.mode not in ("auto", "cell") or not self.n_commanded:
            return f"joint angles: {self.mode} readings"
        steps = sorted({round(np.degrees(r), 4) for r in self.resolution_rad.values()})
        return (f"joint angles: readings quantised to {', '.join(f'{s:g}' for s in steps)} deg; used the command for "
                f"{self.n_commanded} of {self.n_total} still joint readings whose command lies inside the reading's "
                "quantisation cell (the servo drives its sensor to the command; the reading only says which cell)")


def choose_angles(measured, commanded, velocity, mode="auto", *, joints=None, still_rad_per_s=1e-3):
    """theta (M, J) from measured and commanded angles (M, J), per `mode`, and an AngleChoice saying what was done.

    'measured' is the paper's choice. 'cell' (and 'auto', which only solver.fit.identify_dataset, fitting every
    choice, can decide by the data) also uses measured angles, except for joints whose readings are
    quantised (solver.quantisation.reading_resolution): there, for a still joint whose command lies inside its
    reading's quantisation cell, the command is the better estimate (quantisation error up to half a step, shared by
    every image of a stance, otherwise dominates the leg offsets). 'commanded' uses the commands throughout.
    joints : the J column names (default: the NAO's), for AngleChoice.resolution_rad.
    """
    from naocal.solver.joints import JOINTS

    measured = np.asarray(measured, dtype=float)
    commanded = np.asarray(commanded, dtype=float)
    joints = tuple(joints or JOINTS)
    if mode == "measured":
        return measured.copy(), AngleChoice(mode, {}, 0, measured.size)
    if mode == "commanded":
        return commanded.copy(), AngleChoice(mode, {}, measured.size, measured.size)
    if mode not in ("auto", "cell"):
        raise ValueError(f"unknown angle mode {mode!r}: expected measured, commanded, cell or auto")
    theta = measured.copy()
    still = np.ones(measured.shape, dtype=bool) if velocity is None else np.abs(velocity) < still_rad_per_s
    steps = reading_resolution(measured, still)  # moving joints' readings may be interpolated
    resolutions, replaced = {}, 0
    for c, joint in enumerate(joints):
        step = steps[c]
        if step <= 0:
            continue
        resolutions[joint] = float(step)
        inside = still[:, c] & (np.abs(commanded[:, c] - measured[:, c]) <= 0.5 * step + 1e-9)
        theta[inside, c] = commanded[inside, c]
        replaced += int(inside.sum())
    return theta, AngleChoice(mode, resolutions, replaced, measured.size)


def encoder_resolution(readings, **kwargs) -> float | None:
    """The step one joint's readings lie on (rad), or None if they are not quantised (see `reading_resolution`,
    which also uses the other joints' readings and so is not fooled by a joint that visits few values)."""
    step = reading_resolution(np.asarray(readings, dtype=float)[:, None], min_values=3, **kwargs)[0]
    return float(step) if step > 0 else None


def model_data_from_dataset(dataset, angles: str = "auto") -> ModelData:
    """ModelData from a read dataset (solver.dataset.Dataset, version 1 or 2): per-image arrays, rows grouped by
    target in the robot description's order.

    Per-image values (target, camera, stance, posture, angles, gravity) are taken from the first row of each
    image; the reader has already checked that they agree within an image. `angles` chooses theta (see
    `choose_angles`); what was done is in the returned data's `angle_choice`.
    """
    dataset = dataset.as_v2()
    meta, cols = dataset.meta, dataset.columns
    robot = load_robot(meta["robot"].get("description", "nao"))
    joints = dataset.joints
    image = np.asarray(cols["image"], dtype=np.int64)
    image_ids, first_row, image_of_row = np.unique(image, return_index=True, return_inverse=True)
    velocity = dataset.joint_matrix("vel_")[first_row] if dataset.has_velocities else None
    commanded = dataset.joint_matrix("cmd_")[first_row]
    theta, choice = choose_angles(dataset.joint_matrix("")[first_row], commanded, velocity, angles, joints=joints)
    cameras = {}
    for name, camera in meta["cameras"].items():
        distortion = list(camera.get("distortion") or [0.0] * 5) + [0.0] * 5
        cameras[name] = {"fx_px": float(camera["fx_px"]), "fy_px": float(camera["fy_px"]),
                         "cx_px": float(camera["cx_px"]), "cy_px": float(camera["cy_px"]),
                         "width_px": int(camera["width_px"]), "height_px": int(camera["height_px"]),
                         "distortion": [float(d) for d in distortion[:5]]}
    loads = {name: (float(board["mass_kg"]),
                    np.asarray(board.get("centre_m", robot.target(name).centre), dtype=float))
             for name, board in meta["targets"].items()}
    if "gravity_x_mps2" in cols:
        gravity = np.column_stack([cols[f"gravity_{a}_mps2"] for a in "xyz"]).astype(float)[first_row]
    else:
        gravity = np.asarray(meta.get("gravity_mps2", robot.gravity_mps2), dtype=float)
    order = np.lexsort((np.asarray(cols["vertex"]), image_of_row))  # rows grouped by image
    data = ModelData(
        image_of_row=image_of_row[order], vertex=np.asarray(cols["vertex"], dtype=np.int64)[order],
        uv_px=np.column_stack([cols["u_px"], cols["v_px"]]).astype(float)[order],
        p_mount=np.column_stack([cols["x_mount_m"], cols["y_mount_m"], cols["z_mount_m"]]).astype(float)[order],
        target=np.asarray(cols["target"]).astype(str)[first_row], image_id=image_ids,
        stance=np.asarray(cols["stance"], dtype=np.int64)[first_row],
        head_posture=np.asarray(cols["head_posture"], dtype=np.int64)[first_row], theta=theta,
        direction=dataset.joint_matrix("dir_")[first_row], velocity=velocity, cameras=cameras,
        camera=np.asarray(cols["camera"]).astype(str)[first_row], joints=joints, gravity_mps2=gravity, robot=robot,
        loads=loads, angle_choice=choice, commanded=commanded,
    )
    return data.sorted_by_target()


def make_model_data(theta, leg, stance, head_posture, *, direction=None, velocity=None,
                    intrinsics=None, gravity_torso_mps2=(-9.81, 0.0, 0.0)) -> ModelData:
    """ModelData of the NAO's bottom camera for every vertex of every image of the sandals `leg` (M,), with zero
    detections (fill uv_px afterwards): what the agent's planner and estimator evaluate the model on for stances it
    plans or has measured. theta (M, 14) in solver.joints.JOINTS order; intrinsics default to the description's."""
    from naocal.solver.robot import default_intrinsics
    from naocal.solver.joints import JOINTS
    from naocal.solver.robot import nao

    intrinsics = default_intrinsics() if intrinsics is None else intrinsics

    M = len(theta)
    robot = nao()
    leg = np.asarray(leg).astype(str)
    counts = {t: robot.target(t).board.n_vertices for t in np.unique(leg)}
    n = np.array([counts[t] for t in leg], dtype=int)
    image_of_row = np.repeat(np.arange(M), n)
    vertex = np.concatenate([np.arange(k) for k in n]) if M else np.zeros(0, dtype=int)
    p_mount = np.concatenate([robot.target(t).vertices() for t in leg]) if M else np.zeros((0, 3))
    theta = np.asarray(theta, dtype=float)
    return ModelData(
        image_of_row=image_of_row, vertex=vertex, uv_px=np.zeros((len(vertex), 2)), p_mount=p_mount, target=leg,
        image_id=np.arange(M), stance=np.asarray(stance), head_posture=np.asarray(head_posture), theta=theta,
        direction=np.zeros_like(theta) if direction is None else np.asarray(direction, dtype=float),
        velocity=velocity, cameras={robot.default_cameras[0]: dict(intrinsics)}, joints=JOINTS,
        gravity_mps2=np.asarray(gravity_torso_mps2, dtype=float), robot=robot,
    )
