"""Identification in chunks (issue 13, scale): the normal equations accumulated over chunks of images equal the
dense ones, their gradient is the cost's, and a chunked solve gives the dense solve's result. Speed and memory are
measured by benchmarks/bench_scale.py, not here."""

import numpy as np
import pytest

from solver.identify import NormalEquations, identify, normal_equations
from solver.model import Model
from solver.registry import Registry
from sim.synthetic import random_truth, synthesize


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
