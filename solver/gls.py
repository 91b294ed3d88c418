"""Generalised least squares for quantised joint readings: the fit that knows which images share an angle error.

A joint reading quantised to a step s says only which step cell the joint stands in: the true angle is off by an
error of variance s^2 / 12 (uniform in the cell), and that error is the same for every image taken while the
joint holds one command (a servo sent the target it already holds does not move): the leg joints' for all head
postures of a stance, the head joints' for one image. Ordinary least squares treats each pixel as independent,
so these shared errors, which move whole boards, land in the weakly determined offsets (the knees: an error of a
head reading turns the camera, which hides the foot's small sideways shift by which a knee offset differs from an
ankle offset). Measured on the realistic mock (benchmarks/precision_sources.py, seed 1, paper plan): the head
readings alone put 0.10 deg of standard deviation on LKneePitch, the leg readings 0.09 deg, the pixels 0.004.

GLS weights the residuals by the inverse of their covariance

    Sigma = sigma_px^2 I + sum_g q_g^2 a_g a_g^T

(a_g: how the residuals of group g's images move with its joint's angle, d r / d theta_j; q_g^2 = s^2 / 12), so
the fit leans on what those errors cannot mimic: the board's size and perspective, and the images whose readings
differ. Sigma^-1 by the Woodbury identity over the groups (a sparse k x k system, k = the groups), never the
(2N x 2N) matrix. The groups' a_g are taken at the start values (the ordinary fit): they change little.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.sparse import csc_matrix, diags
from scipy.sparse.linalg import splu

from solver.identify import (UNIDENTIFIABLE_RATIO, WEAK_RATIO, IdentificationResult, Normal, NormalEquations,
                             _direction, identifiability, levenberg_marquardt)
from solver.model import Model, ModelData
from solver.registry import Registry
from solver.scoretest import stance_cluster_of_image


def angle_error_groups(data: ModelData, step_rad) -> list[tuple[int, np.ndarray]]:
    """[(joint column, group of each image (M,))] for every joint whose readings are quantised (step > 0): images
    share a group while the joint holds one command, in capture order (image ids); without commands, images of
    one stance with the same reading."""
    step_rad = np.asarray(step_rad, dtype=float)
    order = np.argsort(data.image_id, kind="stable")
    cluster = stance_cluster_of_image(data)
    out = []
    for c in np.flatnonzero(step_rad > 0):
        if data.commanded is not None:
            held = data.commanded[order, c]
            new = np.r_[True, held[1:] != held[:-1]]
            group = np.empty(data.n_images, dtype=np.int64)
            group[order] = np.cumsum(new) - 1
        else:
            key = np.column_stack([cluster, np.round(data.theta[:, c] / step_rad[c])])
            group = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
        out.append((int(c), group))
    return out


class GLSProblem:
    """The GLS normal equations at any parameter vector, for `levenberg_marquardt` (solver.identify)."""

    def __init__(self, data: ModelData, registry: Registry, x0: np.ndarray, step_rad, sigma_px: float):
        from solver.effects import EFFECTS

        self.equations = NormalEquations(data, registry, x0)
        self.registry, self.sigma2 = registry, float(sigma_px) ** 2
        data = self.equations.model.data  # sorted as the model's rows are
        self.data = data
        offsets = tuple(name for name, e in EFFECTS.items() if e.reading_offsets)
        full = Registry(tuple(dict.fromkeys(registry.effects + offsets)), setup=registry.setup)
        J_full = Model(data, full).evaluate(full.from_dict(registry.as_dict(x0)))[1]  # (N, 2, P_full)
        column_of_joint = {data.column(p.joint): full.index[p.name] for p in full.parameters
                           if EFFECTS[p.effect].reading_offsets}
        rows, cols, vals, q2 = [], [], [], []
        coordinate = np.arange(2 * data.n_rows).reshape(-1, 2)
        k = 0
        step_rad = np.asarray(step_rad, dtype=float)
        for c, group in angle_error_groups(data, step_rad):
            if c not in column_of_joint:
                continue
            a = J_full[:, :, column_of_joint[c]]  # d r / d c_j = -d r / d theta_j: the sign drops out of a a^T
            g_row = group[data.image_of_row]
            used = np.any(a != 0, axis=1)
            ids, g_row = np.unique(g_row[used], return_inverse=True)
            rows.append(coordinate[used].reshape(-1))
            cols.append(np.repeat(k + g_row, 2))
            vals.append(a[used].reshape(-1))
            q2.append(np.full(len(ids), step_rad[c] ** 2 / 12.0))
            k += len(ids)
        self.n_groups = k
        if k:
            self.A = csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(2 * data.n_rows, k))
            inner = diags(self.sigma2 / np.concatenate(q2)) + (self.A.T @ self.A)
            self.inner = splu(csc_matrix(inner))

    def _project(self, M: np.ndarray) -> np.ndarray:
        """A (sigma^2 Q^-1 + A^T A)^-1 A^T M: the part of M that the angle errors explain."""
        if not self.n_groups:
            return np.zeros_like(M)
        return self.A @ self.inner.solve(np.asarray(self.A.T @ M))

    def whitened_residual(self, r: np.ndarray) -> np.ndarray:
        """Sigma^-1 r (r: (2N,) residual coordinates)."""
        return (r - self._project(r)) / self.sigma2

    def __call__(self, free: np.ndarray) -> Normal:
        r, J = self.equations.dense(free)
        Js = J * self.equations.scales
        u = self.whitened_residual(r)
        SJ = (Js - self._project(Js)) / self.sigma2
        A = Js.T @ SJ
        data = self.data
        starts = 2 * np.searchsorted(data.image_of_row, np.arange(data.n_images))
        scores = lambda: np.add.reduceat(Js * u[:, None], starts, axis=0)  # noqa: E731 (per image)
        return Normal(0.5 * (A + A.T), Js.T @ u, 0.5 * float(r @ u), r.reshape(-1, 2), scores)


def identify_gls(data: ModelData, registry: Registry, x0: np.ndarray, step_rad, sigma_px: float, *,
                 max_iterations: int = 50) -> IdentificationResult:
    """Fit by GLS from `x0` (the ordinary fit's values). Standard deviations: the delete-one-cluster jackknife of the
    GLS estimator, clusters the stances (joined where a held command spans them), so that what the noise model
    lacks (detection biases, a load that pulls joints to one side of their cells) shows in them rather than
    hides; the sandwich, with about as many clusters as parameters (50 stances, 21-29 parameters), is too small
    (realistic mock seed 1: sandwich 0.034 deg, jackknife 0.043 deg, error 0.071 deg)."""

    start = time.perf_counter()
    problem = GLSProblem(data, registry, x0, step_rad, sigma_px)
    scales = problem.equations.scales
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        free, final, status, message, n_jac, n_fun = levenberg_marquardt(problem, registry.pack(x0), scales,
                                                                         max_iterations=max_iterations)
    values = registry.unpack(free, x0)
    d = problem.data
    cond, sv, Vt = identifiability(final.A)
    usable = sv > UNIDENTIFIABLE_RATIO * sv[0]
    inv_sv = np.where(usable, 1.0 / np.where(usable, sv, 1.0), 0.0)
    bread = (Vt.T * inv_sv ** 2) @ Vt  # (J^T Sigma^-1 J)^+ in scaled units
    covariance = _jackknife_covariance(problem, free, _blocks(d, problem)) * np.outer(scales, scales)
    covariance_model = bread * np.outer(scales, scales)
    std_free = np.sqrt(np.diag(covariance))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(std_free, std_free)
    residuals = final.residuals
    rms = np.sqrt(np.mean(residuals ** 2, axis=0))
    weak = [_direction(sv[k] / sv[0], float(inv_sv[k]), Vt[k], registry.free_names) for k in np.argsort(sv)[:3]]
    warnings = [f"weakly determined combination (relative singular value {w.singular_value:.1e}): {w.describe()}"
                for w in weak if w.singular_value < WEAK_RATIO]
    return IdentificationResult(
        success=bool(status > 0 and np.all(np.isfinite(values))), status=int(status), message=message,
        registry=registry, values=values, std=np.abs(registry.expand) @ std_free,
        std_iid=np.abs(registry.expand) @ np.sqrt(np.diag(covariance_model)), covariance=covariance,
        correlation=correlation, condition_number=float(cond), weak_directions=weak,
        residuals_px=residuals, weights=np.ones(len(residuals)), rms_px=(float(rms[0]), float(rms[1])),
        iterations=int(n_jac), function_evaluations=int(n_fun), solve_time_s=time.perf_counter() - start,
        model=problem.equations.model, warnings=warnings)


def _blocks(data: ModelData, problem: GLSProblem) -> np.ndarray:
    """(M,) the sandwich's clusters: stances, joined where an angle error group spans two of them."""
    cluster = stance_cluster_of_image(data)
    parent = list(range(int(cluster.max()) + 1))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if problem.n_groups:
        A = problem.A.tocsc()
        image_of_coordinate = np.repeat(data.image_of_row, 2)
        for g in range(problem.n_groups):
            members = np.unique(cluster[image_of_coordinate[A.indices[A.indptr[g]:A.indptr[g + 1]]]])
            for m in members[1:]:
                parent[root(int(m))] = root(int(members[0]))
    roots = np.array([root(int(c)) for c in cluster])
    return np.unique(roots, return_inverse=True)[1].reshape(-1)


def _jackknife_covariance(problem: GLSProblem, free: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """(C-1)/C sum_c (d_c - mean)(d_c - mean)^T, d_c the one-step change of the fit without cluster c
    (A - A_c)^-1 g_c, in scaled units."""
    r, J = problem.equations.dense(free)
    Js = J * problem.equations.scales
    SJ = (Js - problem._project(Js)) / problem.sigma2
    u = problem.whitened_residual(r)
    of_coordinate = cluster[np.repeat(problem.data.image_of_row, 2)]
    n_clusters, p = int(cluster.max()) + 1, Js.shape[1]
    A_c = np.zeros((n_clusters, p, p))
    g_c = np.zeros((n_clusters, p))
    for c in range(n_clusters):
        rows = of_coordinate == c
        A_c[c] = Js[rows].T @ SJ[rows]
        g_c[c] = Js[rows].T @ u[rows]
    A = A_c.sum(axis=0)
    deltas = np.array([np.linalg.lstsq(A - A_c[c], g_c[c], rcond=None)[0] for c in range(n_clusters)])
    centred = deltas - deltas.mean(axis=0)
    return (n_clusters - 1) / n_clusters * centred.T @ centred
