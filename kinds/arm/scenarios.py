"""Synthetic measurements of the Franka Panda made by naocal's own model (no PyBullet): the near-flat directions of
issue 24 (docs/ARM.md, "Priors and weak directions"), one home for the tests (tests/test_arm_priors.py) and the
benchmark (benchmarks/bench_arm_priors.py) that run them, and the panda's hidden errors the arm's tests draw."""

from __future__ import annotations

import math

import numpy as np

from naocal.kinds.arm.model import ArmModel, Observations, Sensor
from naocal.kinds.arm.dataset import resolve_robot

CAMERA = {"width_px": 1280, "height_px": 1024, "fx_px": 1400.0, "fy_px": 1400.0, "cx_px": 639.5, "cy_px": 511.5,
          "distortion": [0.02, -0.01, 0.001, -0.0005, 0.0]}


def panda():
    """(URDF path, base, tip, chain, link names, load) of pybullet_data's Franka Panda, base to hand."""
    from naocal.kinds.arm.dataset import arm_chain

    urdf, base, tip = resolve_robot("franka_panda", None)
    return (urdf, base, tip) + arm_chain(urdf, base, tip, urdf)


def tool() -> dict:
    from naocal.kinds.arm.sim import tool_points

    return tool_points()


def true_errors(seed=1):
    """The panda's hidden errors: joint offsets 0.01-0.5 deg, link lengths 0.1-2 mm (random signs)."""
    rng = np.random.default_rng(seed)
    _, _, _, chain, names, _ = panda()
    truth = {f"joint_offset.{j}": math.radians(rng.uniform(0.01, 0.5)) * rng.choice((-1, 1))
             for j in chain.joint_names}
    for k, name in enumerate(names):
        offset = chain.T_origin[k, :3, 3] if k < len(chain.joint_names) else chain.T_end[:3, 3]
        if np.linalg.norm(offset) > 1e-9:
            truth[f"link_length.{name}"] = rng.uniform(1e-4, 2e-3) * rng.choice((-1, 1))
    return truth


FRAMES = {("tracker", "rotation"): (0.4, -0.3, 1.2), ("tracker", "translation"): (1.5, -2.0, 0.3),
          ("camera", "rotation"): (0.01, 0.02, -0.01), ("camera", "translation"): (2.5, 0.1, -0.4)}
LOW = np.array([-2.5, -1.5, -2.5, -2.8, -2.5, 0.3, -2.5])  # the panda's stances (tests/test_arm.py's)
HIGH = np.array([2.5, 1.5, 2.5, -0.4, 2.5, 3.4, 2.5])


def narrow(sensor, points, effects, truth, *, still, width, n_poses=40, seed=0, noise=True):
    """(model with `effects`, observations) of the panda seen by one sensor ('tracker' or 'camera') at `points` of
    its tool, the joints `still` (0-based) within +-`width` rad of their mid-range in every pose (what makes a
    direction nearly flat), the rest anywhere; measured at `truth` (joint offsets, link lengths, points), with the
    sensor's noise unless `noise` is off (the same poses)."""
    _, _, _, chain, names, load = panda()
    rng = np.random.default_rng(seed)
    s = Sensor("tracker", "points", noise=1e-4) if sensor == "tracker" else Sensor("camera", "camera", dict(CAMERA),
                                                                                   0.2)
    pts = {p: tool()[p] for p in points}
    theta = rng.uniform(LOW, HIGH, (n_poses, 7))
    theta[:, still] = (LOW + HIGH)[still] / 2 + rng.uniform(-width, width, (n_poses, len(still)))
    pose = np.repeat(np.arange(n_poses), len(pts))
    obs = Observations(theta[pose], pose, np.zeros(len(pose), int), np.tile(np.arange(len(pts)), n_poses),
                       np.zeros((len(pose), 3)))
    truth_model = ArmModel(chain, pts, [s], ("joint_offsets", "link_lengths", "points"), load=load, link_names=names)
    x = np.array([FRAMES[(sensor, n.split(".")[2])]["xyz".index(n[-1])] if n.startswith("sensor.")
                  else truth.get(n, 0.0) for n in truth_model.names])
    if sensor == "camera":
        truth_model.R0[0] = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])  # looks back at the arm
    pred = truth_model.predict(x, obs)
    noise = s.noise * rng.normal(size=pred.shape) * noise
    if sensor == "camera":
        noise[:, 2] = 0.0
        obs.measured = pred + noise
        obs = obs.subset((pred[:, 0] > 0) & (pred[:, 0] < 1280) & (pred[:, 1] > 0) & (pred[:, 1] < 1024))
    else:
        obs.measured = pred + noise
    return ArmModel(chain, pts, [s], effects, load=load, link_names=names), obs


def scenario(case, seed=0, noise=True):
    """The near-flat directions of issue 24, on the panda: (a) a joint's offset against a turn of the marker body
    (per-marker points, a camera) when the joint after it barely turns; (b) link lengths from poses that barely
    move the wrist (a self-touch-like narrow set); (c) a tracker's one reflector with a free position, the wrist
    barely moving. Returns (model, observations, truth, the parameters the flat direction is mostly made of); `seed`
    draws other errors and poses (benchmarks/bench_arm_priors.py)."""
    rng = np.random.default_rng(5 + seed)
    errors = true_errors(1 + seed)
    truth = {k: v for k, v in errors.items() if k.startswith("joint_offset.")}
    if case == "a":
        markers = ("m1", "m2", "m3", "m4")
        truth.update({f"point.{m}.{a}": rng.uniform(1e-3, 2e-3) * rng.choice((-1, 1)) for m in markers for a in "xyz"})
        model, obs = narrow("camera", markers, ("joint_offsets", "points"), truth, still=[6], width=0.003, seed=seed, noise=noise)
        return model, obs, truth, ("joint_offset.panda_joint7",)
    truth.update({k: v for k, v in errors.items() if k.startswith("link_length.")})
    if case == "b":
        model, obs = narrow("tracker", ("t1", "t2", "t3"), ("joint_offsets", "link_lengths"), truth, still=[4, 5, 6],
                            width=0.001, seed=seed, noise=noise)
        return model, obs, truth, ("link_length.panda_link4", "link_length.panda_link6")  # +-0.64 each
    truth.update({f"point.t1.{a}": rng.uniform(1e-3, 2e-3) * rng.choice((-1, 1)) for a in "xyz"})
    model, obs = narrow("tracker", ("t1",), ("joint_offsets", "link_lengths", "points"), truth, still=[4, 5, 6],
                        width=0.003, seed=seed, noise=noise)
    return model, obs, truth, ("joint_offset.panda_joint6",)
