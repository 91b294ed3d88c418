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
from scipy.sparse import csc_matrix, csr_matrix, diags, vstack
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from naocal.solver.identify import (CHUNK_ROWS, UNIDENTIFIABLE_RATIO, WEAK_RATIO, IdentificationResult, Normal,
                             NormalEquations, weak_direction, identifiability, levenberg_marquardt)
from naocal.solver.model import Model, ModelData
from naocal.solver.registry import Registry
from naocal.solver.scoretest import stance_cluster_of_image


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
    """The GLS normal equations at any parameter vector, for `levenberg_marquardt` (solver.identify), accumulated
    over the chunks of images of NormalEquations: with A the (2N x k) group matrix (columns a_g) and
    S = sigma^2 Q^-1 + A^T A (k x k, sparse, factorised once), Sigma^-1 = (I - A S^-1 A^T) / sigma^2, so
    J^T Sigma^-1 J = (J^T J - (A^T J)^T S^-1 (A^T J)) / sigma^2 needs per chunk only its J^T J, J^T r, A^T J and A^T r:
    memory linear in the data, the tall Jacobian never held whole."""

    def __init__(self, data: ModelData, registry: Registry, x0: np.ndarray, step_rad, sigma_px: float, *,
                 chunk_rows: int = CHUNK_ROWS):
        from naocal.solver.effects import EFFECTS

        self.equations = equations = NormalEquations(data, registry, x0, chunk_rows=chunk_rows)
        self.registry, self.sigma2 = registry, float(sigma_px) ** 2
        data = equations.model.data  # sorted as the model's rows are
        self.data = data
        offsets = tuple(name for name, e in EFFECTS.items() if e.reading_offsets)
        full = Registry(tuple(dict.fromkeys(registry.effects + offsets)), setup=registry.setup)
        full_values = full.from_dict(registry.as_dict(x0))
        column_of_joint = {data.column(p.joint): full.index[p.name] for p in full.parameters
                           if EFFECTS[p.effect].reading_offsets}
        step_rad = np.asarray(step_rad, dtype=float)
        groups = [(c, group) for c, group in angle_error_groups(data, step_rad) if c in column_of_joint]
        first_group = np.cumsum([0] + [int(group.max(initial=-1)) + 1 for _, group in groups])
        q2 = np.concatenate([np.full(int(group.max(initial=-1)) + 1, step_rad[c] ** 2 / 12.0) for c, group in groups]
                            + [np.zeros(0)])
        # each chunk's rows of A, from d r / d c_j (= -d r / d theta_j: the sign drops out of a a^T) at x0
        blocks = []
        for (first_image, last_image), part in zip(equations.image_ranges, equations.parts):
            J_full = Model(part.data, full).evaluate(full_values)[1]  # (n, 2, P_full), one chunk
            coordinate = np.arange(2 * part.data.n_rows).reshape(-1, 2)
            rows, cols, vals = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)], [np.zeros(0)]
            for (c, group), offset in zip(groups, first_group):
                a = J_full[:, :, column_of_joint[c]]
                used = np.any(a != 0, axis=1)
                rows.append(coordinate[used].reshape(-1))
                cols.append(np.repeat(offset + group[first_image:last_image][part.data.image_of_row[used]], 2))
                vals.append(a[used].reshape(-1))
            blocks.append(csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                     shape=(2 * part.data.n_rows, int(first_group[-1]))))
            del J_full
        # only the groups with entries, numbered as before (joint by joint, each joint's groups in order)
        counts = sum((np.bincount(b.indices, minlength=int(first_group[-1])) for b in blocks),
                     np.zeros(int(first_group[-1]), dtype=np.int64))
        kept = counts > 0
        number = np.cumsum(kept) - 1
        k = int(np.count_nonzero(kept))
        self.blocks = [csr_matrix((b.data, number[b.indices], b.indptr), shape=(b.shape[0], k)) for b in blocks]
        self.n_groups = k
        if k:
            inner = diags(self.sigma2 / q2[kept]) + sum(b.T @ b for b in self.blocks)
            self.inner = splu(csc_matrix(inner))
        self._whitening = (None, None, None)  # (free bytes, S^-1 A^T r, S^-1 A^T Js) of the last pass

    @property
    def A(self):
        """The whole (2N x k) group matrix (sparse; for tests and small data)."""
        return vstack(self.blocks, format="csc") if len(self.blocks) > 1 else self.blocks[0].tocsc()

    def _chunks(self, free: np.ndarray):
        """Per chunk: (its first image, its group rows, residuals r (2n,), scaled Jacobian Js (2n, P_free))."""
        equations = self.equations
        values = self.registry.unpack(free, equations.base)
        for (first_image, _), part, block in zip(equations.image_ranges, equations.parts, self.blocks):
            r, J = part.evaluate(values)
            J = J.reshape(r.size, -1)
            Js = (J if equations._identity_expand else J @ self.registry.expand) * equations.scales
            yield first_image, part, block, r.reshape(-1), Js

    def __call__(self, free: np.ndarray) -> Normal:
        p, k = len(self.equations.scales), self.n_groups
        JJ, Jr, rr = np.zeros((p, p)), np.zeros(p), 0.0
        AJ, Ar = np.zeros((k, p)), np.zeros(k)
        residuals = np.empty((self.data.n_rows, 2))
        row = 0
        for _, part, block, r, Js in self._chunks(free):
            residuals[row:row + part.data.n_rows] = r.reshape(-1, 2)
            row += part.data.n_rows
            JJ += Js.T @ Js
            Jr += Js.T @ r
            rr += float(r @ r)
            if k:
                AJ += np.asarray(block.T @ Js)
                Ar += block.T @ r
        z = self.inner.solve(Ar) if k else Ar
        W = self.inner.solve(AJ) if k else AJ
        self._whitening = (free.tobytes(), z, W)
        A = (JJ - AJ.T @ W) / self.sigma2
        g = (Jr - AJ.T @ z) / self.sigma2
        cost = 0.5 * (rr - float(Ar @ z)) / self.sigma2
        return Normal(0.5 * (A + A.T), g, cost, residuals, lambda: self._image_scores(free))

    def whitening(self, free: np.ndarray):
        """(S^-1 A^T r, S^-1 A^T Js) at `free`: Sigma^-1 r = (r - A z) / sigma^2, Sigma^-1 Js = (Js - A W) / sigma^2."""
        if self._whitening[0] != free.tobytes():
            self(free)
        return self._whitening[1], self._whitening[2]

    def _image_scores(self, free: np.ndarray) -> np.ndarray:
        """(M, P_free) each image's score Js_m^T Sigma^-1 r (a second pass over the chunks)."""
        z, _ = self.whitening(free)
        scores = np.zeros((self.data.n_images, len(self.equations.scales)))
        for first_image, part, block, r, Js in self._chunks(free):
            u = (r - block @ z) / self.sigma2 if self.n_groups else r / self.sigma2
            starts = 2 * np.searchsorted(part.data.image_of_row, np.arange(part.data.n_images))
            if len(u):
                scores[first_image:first_image + part.data.n_images] = np.add.reduceat(Js * u[:, None], starts, axis=0)
        return scores


def identify_gls(data: ModelData, registry: Registry, x0: np.ndarray, step_rad, sigma_px: float, *,
                 max_iterations: int = 50, chunk_rows: int = CHUNK_ROWS) -> IdentificationResult:
    """Fit by GLS from `x0` (the ordinary fit's values). Standard deviations: the delete-one-cluster jackknife of the
    GLS estimator, clusters the stances (joined where a held command spans them), so that what the noise model
    lacks (detection biases, a load that pulls joints to one side of their cells) shows in them rather than
    hides; the sandwich, with about as many clusters as parameters (50 stances, 21-29 parameters), is too small
    (realistic mock seed 1: sandwich 0.034 deg, jackknife 0.043 deg, error 0.071 deg); plus, for each joint
    offset, the place its servo rests in its cell, which no data show (`rest_bias_variance`). `chunk_rows`:
    vertices per chunk (solver.identify.NormalEquations)."""

    start = time.perf_counter()
    problem = GLSProblem(data, registry, x0, step_rad, sigma_px, chunk_rows=chunk_rows)
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
    covariance += np.diag(rest_bias_variance(d, registry, step_rad))
    covariance_model = bread * np.outer(scales, scales)
    std_free = np.sqrt(np.diag(covariance))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(std_free, std_free)
    residuals = final.residuals
    rms = np.sqrt(np.mean(residuals ** 2, axis=0))
    weak = [weak_direction(sv[k] / sv[0], float(inv_sv[k]), Vt[k], registry.free_names) for k in np.argsort(sv)[:3]]
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


def rest_bias_variance(data: ModelData, registry: Registry, step_rad) -> np.ndarray:
    """(P_free,) the variance of each free joint offset that no data can reduce: where a servo rests in its step.

    The fit sees where each servo stands in its cell only through how that place changes from stance to stance;
    the mean place over all stances is the offset itself. A load of one sign in every stance (on its back, the
    hip and knee pitches and HipYawPitch carry the legs' weight the same way in all 48 stances) holds the servo
    on one side of its cell: the offset absorbs the shift, and neither the jackknife nor the residuals can show it.
    Unknown within the cell, the mean place is +-step/2: variance step^2 / 12 for each offset whose joint's
    readings are quantised (the largest step of the joints a tied offset drives). Measured on the realistic mock
    (paper plan, seeds 1-4, 8 runs with two plans): HipYawPitch's error was negative in all 8, down to -4.0 std
    without this term; the same robot with the load's pull switched off: -1.4 std."""
    from naocal.solver.effects import EFFECTS

    step_rad = np.asarray(step_rad, dtype=float)
    full = np.zeros(len(registry.names))
    for i, p in enumerate(registry.parameters):
        if EFFECTS[p.effect].reading_offsets and p.joint is not None:
            full[i] = step_rad[data.column(p.joint)] ** 2 / 12.0
    # a free parameter takes the largest of the offsets it drives (HipYawPitch: one motor, one cell)
    return np.max(registry.expand * full[:, None], axis=0, initial=0.0)


def _blocks(data: ModelData, problem: GLSProblem) -> np.ndarray:
    """(M,) the sandwich's clusters: stances, joined where an angle error group spans two of them (the connected
    components of the graph of clusters and groups)."""
    cluster = stance_cluster_of_image(data)
    n_clusters, k = int(cluster.max()) + 1, problem.n_groups
    if not k:
        return np.unique(cluster, return_inverse=True)[1].reshape(-1)
    pairs = []  # (cluster, group) of every entry of A
    for (first_image, _), part, block in zip(problem.equations.image_ranges, problem.equations.parts,
                                             problem.blocks):
        coordinate_cluster = np.repeat(cluster[first_image:first_image + part.data.n_images][part.data.image_of_row], 2)
        entry_row = np.repeat(np.arange(block.shape[0]), np.diff(block.indptr))
        pairs.append(np.unique(coordinate_cluster[entry_row].astype(np.int64) * k + block.indices))  # one key a pair
    pairs = np.concatenate(pairs)
    graph = csr_matrix((np.ones(len(pairs)), (pairs // k, n_clusters + pairs % k)),
                       shape=(n_clusters + k, n_clusters + k))
    _, component = connected_components(graph, directed=False)
    return np.unique(component[cluster], return_inverse=True)[1].reshape(-1)


JACKKNIFE_BLOCK = 1024  # clusters whose left-out systems are solved together (memory: 3 x 8 P^2 bytes each)


def _jackknife_covariance(problem: GLSProblem, free: np.ndarray, cluster: np.ndarray) -> np.ndarray:
    """(C-1)/C sum_c (d_c - mean)(d_c - mean)^T, d_c the one-step change of the fit without cluster c
    (A - A_c)^-1 g_c, in scaled units; A_c and g_c accumulated chunk by chunk."""
    z, W = problem.whitening(free)
    n_clusters, p = int(cluster.max()) + 1, len(problem.equations.scales)
    A_c = np.zeros((n_clusters, p, p))
    g_c = np.zeros((n_clusters, p))
    for first_image, part, block, r, Js in problem._chunks(free):
        if problem.n_groups:
            SJ = (Js - block @ W) / problem.sigma2
            u = (r - block @ z) / problem.sigma2
        else:
            SJ, u = Js / problem.sigma2, r / problem.sigma2
        of_coordinate = np.repeat(cluster[first_image:first_image + part.data.n_images][part.data.image_of_row], 2)
        order = np.argsort(of_coordinate, kind="stable")
        present, starts = np.unique(of_coordinate[order], return_index=True)
        for c, rows in zip(present, np.split(order, starts[1:])):
            A_c[c] += Js[rows].T @ SJ[rows]
            g_c[c] += Js[rows].T @ u[rows]
    # each cluster's left-out system, solved as numpy's lstsq does (least norm; singular values below
    # eps * p of the largest dropped), JACKKNIFE_BLOCK clusters at a time: one lstsq a cluster cost 0.2 ms, mostly
    # the call
    A = A_c.sum(axis=0)
    deltas = np.empty((n_clusters, p))
    for first in range(0, n_clusters, JACKKNIFE_BLOCK):
        some = slice(first, first + JACKKNIFE_BLOCK)
        U, sv, Vt = np.linalg.svd(A - A_c[some])
        inverse = np.where(sv > np.finfo(float).eps * p * sv[:, :1], 1.0 / np.where(sv > 0, sv, 1.0), 0.0)
        deltas[some] = np.einsum("cji,cj->ci", Vt, inverse * np.einsum("ckj,ck->cj", U, g_c[some]))
    centred = deltas - deltas.mean(axis=0)
    return (n_clusters - 1) / n_clusters * centred.T @ centred
