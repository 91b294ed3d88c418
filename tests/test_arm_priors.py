"""Priors (soft bounds) in the one fit (solver.identify.Prior) and the arm's use of them (issue 24): the posterior of
a linear problem is Bayes' exact one, a robust loss never bends a prior's row, and the arm reports which parameters
its priors held."""

import numpy as np
import pytest

from naocal.solver.identify import Normal, Prior, last_pass_cached, solve


class LinearEquations:
    """r = J x - y, one row per observation (each its own cluster), in the shape solver.identify.solve wants."""

    def __init__(self, J, y, scales):
        self.J, self.y, self.scales = J, y, np.asarray(scales, dtype=float)

    def __call__(self, free, *, weights=None, jacobian=True):
        r = self.J @ free - self.y
        rw = r if weights is None else r * np.sqrt(weights)
        Js = self.J * self.scales
        return Normal(Js.T @ Js, Js.T @ rw, 0.5 * float(rw @ rw), r[:, None], Js * rw[:, None])

    def dense(self, free):
        return self.J @ free - self.y, self.J


def _problem(seed=0):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(40, 3))
    J[:, 2] = J[:, 1] + 1e-3 * rng.normal(size=40)  # x1 and x2 nearly the same direction: the prior decides
    y = J @ np.array([1.0, 0.3, -0.2]) + rng.normal(size=40)
    return J, y


def test_a_prior_gives_the_exact_gaussian_posterior_and_is_counted_in_the_covariance():
    J, y = _problem()
    equations = LinearEquations(J, y, [1.0, 0.1, 0.1])
    prior = Prior(np.array([1, 2]), np.array([0.0, 0.1]), np.array([0.5, 0.2]))
    solution = solve(equations, last_pass_cached(equations), np.zeros(3), prior=prior)
    P = np.diag([0.0, 1 / 0.5 ** 2, 1 / 0.2 ** 2])
    mean = np.linalg.solve(J.T @ J + P, J.T @ y + P @ np.array([0.0, 0.0, 0.1]))
    assert np.allclose(solution.free, mean, atol=1e-8)
    spread = solution.spread(np.arange(40), ["a", "b", "c"])
    s2 = 2 * solution.final.cost / (40 + 2 - 3)
    assert np.allclose(spread.covariance_iid, np.linalg.inv(J.T @ J + P) * s2, rtol=1e-6)
    # the data alone barely separate b from c: their posterior stds are near the priors', not the data's 1e3
    std = np.sqrt(np.diag(spread.covariance))
    assert std[1] < 0.5 and std[2] < 0.2
    # without the prior, the same solve is the plain least squares
    plain = solve(equations, last_pass_cached(equations), np.zeros(3))
    assert np.allclose(plain.free, np.linalg.lstsq(J, y, rcond=None)[0], atol=1e-6)


@pytest.mark.parametrize("loss", ["soft_l1", "huber", "cauchy"])
def test_a_robust_loss_bends_the_data_but_never_the_prior(loss):
    """A prior 20 of its stds from the data's answer: a robust loss applied to its row would all but drop it (x0
    back at the data's 1.0); kept quadratic, the answer is Bayes' exact one (the data's rows stay inside the bend)."""
    rng = np.random.default_rng(1)
    J = rng.normal(size=(2000, 2))
    y = J @ np.array([1.0, 2.0]) + 0.05 * rng.normal(size=2000)
    equations = LinearEquations(J, y, [1.0, 1.0])
    prior = Prior(np.array([0]), np.array([0.9]), np.array([0.005]))
    solution = solve(equations, last_pass_cached(equations), np.zeros(2), loss=loss, loss_scale=1.0, prior=prior)
    P = np.diag([1 / 0.005 ** 2, 0.0])
    exact = np.linalg.solve(J.T @ J + P, J.T @ y + P @ np.array([0.9, 0.0]))
    data_only = np.linalg.lstsq(J, y, rcond=None)[0]
    assert solution.success
    assert data_only[0] - exact[0] > 3e-3  # the prior moves it measurably
    assert abs(solution.free[0] - exact[0]) < 2e-4
