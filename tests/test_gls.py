"""GLS for quantised readings (solver/gls.py): its normal equations are those of the dense covariance, its gradient
that of its cost, and on servos that stand anywhere in their step (the same place for every image of one command)
it recovers the offsets that ordinary least squares loses, with standard deviations that cover its errors."""

import numpy as np
import pytest

from naocal.sim.synthetic import dataset_parts, random_plan, random_truth
from naocal.solver.adapter import make_model_data
from naocal.solver.dataset import Dataset
from naocal.solver.fit import identify_dataset
from naocal.solver.gls import GLSProblem, angle_error_groups
from naocal.solver.joints import JOINT_INDEX, LEG_JOINTS
from naocal.solver.model import Model
from naocal.solver.registry import Registry

STEP = 2 * np.pi / 4096
DEG = np.pi / 180


def shared_step_dataset(rng, truth, *, n_stances_per_leg=16, pixel_noise_px=0.03, leg_cell=(-0.5, 0.5)):
    """Servos anywhere in their commanded step, one place per command: a leg joint's for all head postures of its
    stance, a head joint's for one image (the realistic mock's servo); readings the commanded step. `leg_cell`: where
    in its cell (in steps from the centre) a leg servo may rest (one side only: a load that pulls it one way)."""
    command, leg, stance, posture = random_plan(rng, n_stances_per_leg, 3)
    reading = np.round(command / STEP) * STEP
    u = rng.uniform(-0.5, 0.5, command.shape)
    legs = [JOINT_INDEX[j] for j in LEG_JOINTS]
    u[:, legs] = rng.uniform(*leg_cell, (len(u), len(legs)))
    first = np.r_[True, (stance[1:] != stance[:-1]) | (leg[1:] != leg[:-1])]
    u[:, legs] = u[np.maximum.accumulate(np.where(first, np.arange(len(u)), 0))][:, legs]  # one draw per stance
    true = reading + u * STEP
    data = make_model_data(true, leg, stance, posture)
    registry = Registry()
    uv = data.uv_px + Model(data, registry).residuals(registry.from_dict(truth))
    uv += rng.normal(0.0, pixel_noise_px, uv.shape)
    read = make_model_data(reading, leg, stance, posture)
    read.uv_px, read.commanded = uv, command
    meta, columns = dataset_parts(read, pixel_noise_px=None)
    return Dataset(meta, columns)


def offset_errors(fit, truth):
    r = fit.result
    names = [f"joint_offset.{j}" for j in LEG_JOINTS if j != "RHipYawPitch"]
    idx = [r.registry.index[n] for n in names]
    err = r.values[idx] - np.array([truth[n] for n in names])
    return err, err / r.std[idx]


def test_angle_error_groups_follow_the_held_commands():
    rng = np.random.default_rng(1)
    dataset = shared_step_dataset(rng, random_truth(rng), n_stances_per_leg=3)
    from naocal.solver.adapter import model_data_from_dataset
    data = model_data_from_dataset(dataset, angles="measured")
    groups = dict(angle_error_groups(data, np.full(len(data.joints), STEP)))
    knee = groups[data.column("LKneePitch")]
    yaw = groups[data.column("HeadYaw")]
    for (lg, st) in {(a, b) for a, b in zip(data.target, data.stance)}:
        images = np.flatnonzero((data.target == lg) & (data.stance == st))
        if lg == "L":
            assert len(set(knee[images])) == 1  # one command held for the stance's three images
        assert len(set(yaw[images])) == len(images)  # the head moves for every image
    assert len(set(knee[data.target == "L"])) == 3


def test_gls_normal_equations_are_those_of_the_dense_covariance_and_the_gradient_that_of_the_cost():
    rng = np.random.default_rng(2)
    truth = random_truth(rng)
    dataset = shared_step_dataset(rng, truth, n_stances_per_leg=2)
    from naocal.solver.adapter import model_data_from_dataset
    data = model_data_from_dataset(dataset, angles="measured")
    registry = Registry()
    x0 = registry.from_dict(truth) * 0.9
    sigma = 0.05
    problem = GLSProblem(data, registry, x0, np.full(len(data.joints), STEP), sigma)
    free = registry.pack(x0)
    normal = problem(free)
    # the dense covariance, built directly from its definition
    r, J = problem.equations.dense(free)
    Js = J * problem.equations.scales
    a = problem.A.toarray()
    S = sigma ** 2 * np.eye(len(r)) + STEP ** 2 / 12 * a @ a.T
    np.testing.assert_allclose(normal.A, Js.T @ np.linalg.solve(S, Js), rtol=1e-6, atol=1e-9 * np.abs(normal.A).max())
    np.testing.assert_allclose(normal.g, Js.T @ np.linalg.solve(S, r), rtol=1e-6, atol=1e-9 * np.abs(normal.g).max())
    assert normal.cost == pytest.approx(0.5 * r @ np.linalg.solve(S, r), rel=1e-8)
    # the gradient against finite differences of the cost (scaled variables, the covariance held)
    scales = problem.equations.scales
    for k in (0, 5, len(free) - 1):
        h = 1e-6
        up, down = free.copy(), free.copy()
        up[k] += h * scales[k]
        down[k] -= h * scales[k]
        numeric = (problem(up).cost - problem(down).cost) / (2 * h)
        assert numeric == pytest.approx(normal.g[k], rel=1e-4, abs=1e-6 * np.abs(normal.g).max())


def test_gls_recovers_the_offsets_ordinary_least_squares_loses_to_shared_step_errors():
    """Three seeds: the ordinary fit's worst offset error is several times GLS's, and GLS's errors lie within 3.5 of
    its standard deviations (the mock's servo, the design's noise model; the pixels of the model itself)."""
    ols, gls, z = [], [], []
    for seed in range(3):
        rng = np.random.default_rng(700 + seed)
        truth = random_truth(rng)
        dataset = shared_step_dataset(rng, truth)
        plain = identify_dataset(dataset, gls=False)
        refined = identify_dataset(dataset, gls=True)
        assert plain.angles == refined.angles == "measured" and refined.gls and not plain.gls
        assert "generalised least squares" in refined.describe() and refined.as_dict()["generalised_least_squares"]
        ols.append(np.max(np.abs(offset_errors(plain, truth)[0])))
        err, zz = offset_errors(refined, truth)
        gls.append(np.max(np.abs(err)))
        z.extend(np.abs(zz))
    # measured: ordinary 0.19-0.46 deg, GLS 0.020-0.028 deg (z up to 2.0)
    assert max(gls) < 0.05 * DEG and min(ols) > 3 * max(gls), (np.degrees(ols), np.degrees(gls))
    assert max(z) < 3.5, max(z)


def test_a_load_that_holds_every_servo_on_one_side_of_its_cell_is_within_the_standard_deviations():
    """Leg servos resting in the upper half of their cells in every stance (on its back, gravity loads the pitch
    joints the same way in all of them): the offsets absorb the shift, which no residual shows; the standard
    deviations say so (solver.gls.rest_bias_variance). Without that term: z up to 6-7."""
    z, errors = [], []
    for seed in range(3):
        rng = np.random.default_rng(900 + seed)
        truth = random_truth(rng)
        fit = identify_dataset(shared_step_dataset(rng, truth, leg_cell=(0.1, 0.5)), gls=True)
        assert fit.gls
        err, zz = offset_errors(fit, truth)
        errors.extend(np.abs(err))
        z.extend(np.abs(zz))
    assert max(errors) > 0.2 * STEP  # the shift is there (the data cannot remove it)
    assert max(z) < 3.5, max(z)
    registry = fit.result.registry
    std = fit.result.std[registry.index["joint_offset.LKneePitch"]]
    assert std >= STEP / np.sqrt(12)  # never below where the servo may rest in its cell


def test_gls_in_chunks_equals_gls_in_one_chunk_and_the_dense_jackknife(monkeypatch):
    """Chunks of 8 images (stances cut by chunk edges): the same fit, standard deviations and residuals as one chunk
    to 1e-9, and the jackknife covariance (its left-out systems solved 5 clusters at a time) is the one built from
    the dense (2N x 2N) covariance."""
    from naocal.solver import gls
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.gls import _blocks, identify_gls

    monkeypatch.setattr(gls, "JACKKNIFE_BLOCK", 5)
    rng = np.random.default_rng(5)
    truth = random_truth(rng)
    data = model_data_from_dataset(shared_step_dataset(rng, truth, n_stances_per_leg=6), angles="measured")
    registry = Registry(("intrinsics",))
    x0 = registry.from_dict(truth) * 0.9
    step, sigma = np.full(len(data.joints), STEP), 0.05
    whole = identify_gls(data, registry, x0, step, sigma, chunk_rows=10 ** 9)
    chunked = identify_gls(data, registry, x0, step, sigma, chunk_rows=8 * 24)
    assert len(GLSProblem(data, registry, x0, step, sigma, chunk_rows=8 * 24).blocks) >= 4
    assert whole.success and chunked.success and chunked.iterations == whole.iterations
    np.testing.assert_allclose(chunked.values, whole.values, rtol=0, atol=1e-9 * registry.scales.min())
    np.testing.assert_allclose(chunked.std, whole.std, rtol=1e-9)
    np.testing.assert_allclose(chunked.residuals_px, whole.residuals_px, rtol=0, atol=1e-9)
    # the jackknife from its definition, with the dense covariance and a boolean mask per cluster
    problem = GLSProblem(data, registry, x0, step, sigma)
    free = registry.pack(whole.values)
    r, J = problem.equations.dense(free)
    Js = J * problem.equations.scales
    a = problem.A.toarray()
    S = sigma ** 2 * np.eye(len(r)) + STEP ** 2 / 12 * a @ a.T
    SJ, u = np.linalg.solve(S, Js), np.linalg.solve(S, r)
    cluster = _blocks(problem.data, problem)
    of_coordinate = cluster[np.repeat(problem.data.image_of_row, 2)]
    C = int(cluster.max()) + 1
    assert 1 < C < problem.data.n_images
    A = Js.T @ SJ
    deltas = np.array([np.linalg.lstsq(A - Js[of_coordinate == c].T @ SJ[of_coordinate == c],
                                       Js[of_coordinate == c].T @ u[of_coordinate == c], rcond=None)[0]
                       for c in range(C)])
    centred = deltas - deltas.mean(axis=0)
    scales = problem.equations.scales
    dense = (C - 1) / C * centred.T @ centred * np.outer(scales, scales) + np.diag(
        gls.rest_bias_variance(problem.data, registry, step))
    np.testing.assert_allclose(whole.covariance, dense, rtol=1e-6, atol=1e-9 * np.abs(dense).max())
    # each image's score Js_m^T Sigma^-1 r_m, in chunks
    starts = 2 * np.searchsorted(problem.data.image_of_row, np.arange(problem.data.n_images))
    scores = np.add.reduceat(Js * u[:, None], starts, axis=0)
    chunked_scores = GLSProblem(data, registry, x0, step, sigma, chunk_rows=8 * 24)(free).image_scores
    np.testing.assert_allclose(chunked_scores, scores, rtol=1e-6, atol=1e-9 * np.abs(scores).max())
