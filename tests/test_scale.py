"""Identification in chunks (issue 13, scale): the normal equations accumulated over chunks of images equal the
dense ones, their gradient is the cost's, and a chunked solve gives the dense solve's result. Speed and memory are
measured by benchmarks/bench_scale.py, not here."""

import numpy as np
import pytest

from naocal.solver.effect import Setup
from naocal.solver.effects import ALL_EFFECTS
from naocal.solver.identify import NormalEquations, identify, normal_equations
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.robot import nao
from naocal.sim.synthetic import random_truth, synthesize, synthesize_views


@pytest.fixture(scope="module")
def small():
    rng = np.random.default_rng(7)
    truth = random_truth(rng, ("elasticity",))
    return synthesize(rng, truth, effects=("elasticity",), n_stances_per_leg=5, n_head_postures=2), truth


def dense_normal(model, registry, values):
    """The straightforward way: the whole Jacobian, then J^T J and J^T r."""
    r, J = model.evaluate(values)
    J = registry.free_jacobian(J.reshape(r.size, -1))
    return J.T @ J, J.T @ r.reshape(-1), float(r.reshape(-1) @ r.reshape(-1))


@pytest.mark.parametrize("effects, tie", [((), False), (("elasticity",), True)])
def test_chunked_normal_equations_equal_the_dense_ones(small, effects, tie):
    data, truth = small
    registry = Registry(effects, tie_hip_yaw_pitch=tie)
    values = registry.from_dict({k: 0.7 * v for k, v in truth.items()})
    values = registry.unpack(registry.pack(values), values)  # tied parameters follow their source
    model = Model(data, registry)
    A, g, rss, n = normal_equations(model, registry, values, chunk_rows=50)  # 2 images a chunk
    A_dense, g_dense, rss_dense = dense_normal(model, registry, values)
    assert n == 2 * data.n_rows
    np.testing.assert_allclose(A, A_dense, rtol=1e-9, atol=1e-9 * np.abs(A_dense).max())
    np.testing.assert_allclose(g, g_dense, rtol=1e-9, atol=1e-9 * np.abs(g_dense).max())
    assert rss == pytest.approx(rss_dense, rel=1e-9)


def test_accumulated_gradient_matches_finite_differences(small):
    data, truth = small
    registry = Registry(("elasticity",))
    base = registry.from_dict({k: 0.5 * v for k, v in truth.items()})
    equations = NormalEquations(data, registry, base, chunk_rows=60)
    assert len(equations.parts) > 5
    free = registry.pack(base)
    normal = equations(free)
    scales = equations.scales
    for k in range(len(free)):
        h = 1e-4 * scales[k]
        up, down = free.copy(), free.copy()
        up[k] += h
        down[k] -= h
        numeric = (equations(up, jacobian=False).cost - equations(down, jacobian=False).cost) / (2 * h)
        # g is the gradient in scaled variables: d cost / d x_k = g_k / scale_k
        assert normal.g[k] / scales[k] == pytest.approx(numeric, rel=1e-5, abs=1e-6 * abs(normal.g).max() / scales[k])


def test_chunked_solve_equals_the_one_chunk_solve(small):
    data, _ = small
    registry = Registry(("elasticity",))
    whole = identify(data, registry, chunk_rows=10 ** 9)
    chunked = identify(data, registry, chunk_rows=50)
    assert whole.success and chunked.success
    np.testing.assert_allclose(chunked.values, whole.values, rtol=0, atol=1e-9 * registry.scales.min())
    np.testing.assert_allclose(chunked.std, whole.std, rtol=1e-9)
    np.testing.assert_allclose(chunked.residuals_px, whole.residuals_px, atol=1e-9)
    assert chunked.iterations == whole.iterations


def test_robust_loss_and_minpack_run_on_chunks(small):
    data, _ = small
    for kwargs in (dict(loss="soft_l1", loss_scale_px=0.5), dict(solver="minpack")):
        whole = identify(data, Registry(), chunk_rows=10 ** 9, **kwargs)
        chunked = identify(data, Registry(), chunk_rows=70, **kwargs)
        np.testing.assert_allclose(chunked.values, whole.values, atol=1e-9 * Registry().scales.min())
        np.testing.assert_allclose(chunked.std, whole.std, rtol=1e-9)


@pytest.fixture(scope="module")
def wide():
    """Two cameras, three targets (boards of 24 and 9 vertices: images of different sizes), every effect (the
    intrinsics' and distortion's projection terms too), moving joints, parameters away from zero."""
    setup = Setup(nao(), ("bottom", "top"), ("L", "R", "floor"))
    rng = np.random.default_rng(3)
    data = synthesize_views(rng, random_truth(rng, setup=setup), setup, n_stances=4, n_postures=2,
                            velocity_rad_s=0.3, within_limits=False)
    registry = Registry(ALL_EFFECTS, setup=setup)
    x = registry.scales * rng.uniform(-1.0, 1.0, len(registry))
    elastic = [registry.index[p.name] for p in registry.parameters if p.effect == "elasticity"]
    x[elastic] = np.abs(x[elastic])
    return data, registry, x


def test_factored_jacobian_is_the_jacobian(wide):
    """J[rows of image m] = F[rows] @ T[m] (Model.factored), with projection terms, two cameras, uneven images."""
    data, registry, x = wide
    model = Model(data, registry)
    r, J = model.evaluate(x)
    r_f, F, T = model.factored(x)
    assert F.shape[2] > 6  # the projection terms have their own columns
    np.testing.assert_array_equal(r_f, r)
    J_f = np.einsum("nkc,ncp->nkp", F, T[model.data.image_of_row])
    np.testing.assert_allclose(J_f, J, rtol=0, atol=1e-12 * np.abs(J).max())


def test_factored_normal_equations_equal_the_dense_ones_with_weights_and_uneven_images(wide):
    """A = J^T J, g = J^T sqrt(w) r, the cost and each image's score J_m^T sqrt(w_m) r_m, chunked (a few images per
    chunk, chunks of uneven images) and whole, against the whole Jacobian."""
    data, registry, x = wide
    model = Model(data, registry)
    counts = np.bincount(model.data.image_of_row)
    assert len(set(counts.tolist())) > 1
    weights = np.random.default_rng(4).uniform(0.2, 1.0, model.data.n_rows)
    r, J = model.evaluate(x)
    Js = registry.free_jacobian(J.reshape(r.size, -1)) * registry.scales[registry.free_index]
    rw = r.reshape(-1) * np.repeat(np.sqrt(weights), 2)
    starts = 2 * np.searchsorted(model.data.image_of_row, np.arange(model.data.n_images))
    scores = np.add.reduceat(Js * rw[:, None], starts, axis=0)
    for chunk_rows in (10 ** 9, 40):
        equations = NormalEquations(model.data, registry, x, chunk_rows=chunk_rows)
        normal = equations(registry.pack(x), weights=weights)
        np.testing.assert_allclose(normal.A, Js.T @ Js, rtol=1e-9, atol=1e-9 * np.abs(Js.T @ Js).max())
        np.testing.assert_allclose(normal.g, Js.T @ rw, rtol=1e-9, atol=1e-9 * np.abs(Js.T @ rw).max())
        assert normal.cost == pytest.approx(0.5 * rw @ rw, rel=1e-12)
        np.testing.assert_allclose(normal.image_scores, scores, rtol=1e-9, atol=1e-9 * np.abs(scores).max())
        np.testing.assert_allclose(normal.residuals, r, rtol=0, atol=1e-9)  # elastic sag: Newton to 1e-13 rad


def test_row_ids_are_numpys_unique_rows():
    """naocal.solver.scoretest.row_ids (the stance clusters' row labels) equals np.unique(axis=0)'s inverse: negative values,
    repeated rows, one column, no rows."""
    from naocal.solver.scoretest import row_ids

    rng = np.random.default_rng(9)
    for shape in ((200, 12), (50, 1), (0, 3), (7, 0)):
        a = rng.integers(-3, 3, size=shape).astype(np.int64)
        expected = np.unique(a, axis=0, return_inverse=True)[1].reshape(-1) if a.size else np.zeros(len(a), int)
        np.testing.assert_array_equal(row_ids(a), expected)
    a = rng.integers(-2, 2, size=(300, 4))
    assert len(set(row_ids(a).tolist())) == len(np.unique(a, axis=0)) < 300


@pytest.mark.parametrize("effects", [(), ("backlash", "time_lag", "link_lengths")])
def test_chains_computed_once_per_distinct_configuration_change_nothing(effects):
    """The head postures of a stance share their leg's configuration: its chain is computed once for them
    (Model._distinct_configurations), with residuals and Jacobian those of a chain per image, also where joint
    terms differ within a stance (approach direction, a moving image's velocity) and with chain terms (link
    lengths)."""
    rng = np.random.default_rng(11)
    data = synthesize(rng, random_truth(rng), n_stances_per_leg=5, n_head_postures=3)  # 3 images a stance
    data.direction = np.repeat(data.direction[::3], 3, axis=0)
    data.direction[4] *= -1  # one image approached from the other side
    data.velocity = np.zeros_like(data.theta)
    data.velocity[[7, 20]] = 0.2  # two images taken while moving
    registry = Registry(effects)
    x = registry.scales * rng.uniform(-1.0, 1.0, len(registry))
    model = Model(data, registry)
    n_configurations = sum(len(first) for first, _ in model._distinct.values())
    assert set(model._distinct) == {"L", "R"}
    assert n_configurations == (10 if not effects else 13)
    r, J = model.evaluate(x)
    model._distinct = {}
    r_each, J_each = model.evaluate(x)
    np.testing.assert_allclose(r, r_each, rtol=0, atol=1e-12)
    np.testing.assert_allclose(J, J_each, rtol=0, atol=1e-12 * np.abs(J).max())
