"""Identification: Levenberg-Marquardt over the registry's free parameters, with uncertainty and identifiability.

`identify(data, registry)` is a pure function of the data; it never writes anything. The result says whether it
can be trusted (`success`), how well it fits, how precisely each parameter is known and which combinations of
parameters the data cannot tell apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from naocal.solver.errors import SolveError
from naocal.solver.model import Model, ModelData
from naocal.solver.registry import Registry
from naocal.solver.scoretest import stance_cluster_of_image

# A direction whose singular value (of the column-scaled Jacobian) is below this fraction of the largest is
# treated as unidentifiable: the data cannot fix that combination of parameters.
UNIDENTIFIABLE_RATIO = 1e-6
# Below this ratio a direction is identifiable in principle but weak: reported, not fatal.
WEAK_RATIO = 1e-3
# Robust loss: images whose mean weight falls below this are reported as down-weighted.
DOWNWEIGHT_REPORT = 0.5
# Why a solve stopped, for both solvers: scipy.optimize.least_squares's status codes and naocal's LM's, one meaning
# each (its `status`; `success` is status > 0).
TERMINATION_MESSAGES = {
    -1: "improper input parameters",
    0: "no convergence: the iteration limit was reached",
    1: "gradient below gtol",
    2: "cost reduction below ftol",
    3: "step below xtol",
    4: "cost reduction below ftol and step below xtol",
}


@dataclass
class WeakDirection:
    """A combination of parameters the data determine poorly: sum(coefficients[name] * value / scale)."""

    singular_value: float  # relative to the largest singular value of the column-scaled Jacobian
    std_along: float  # standard deviation along this unit direction (in scaled units)
    coefficients: dict[str, float]

    def describe(self, top=4) -> str:
        terms = sorted(self.coefficients.items(), key=lambda kv: -abs(kv[1]))[:top]
        return " ".join(f"{c:+.2f} {n}" for n, c in terms)


@dataclass
class IdentificationResult:
    success: bool
    status: int
    message: str
    registry: Registry
    values: np.ndarray  # full parameter vector
    std: np.ndarray  # full vector of standard deviations, stance-clustered sandwich (tied copy their source; fixed 0)
    std_iid: np.ndarray  # the classic s^2 (J^T J)^-1 standard deviations, for comparison
    covariance: np.ndarray  # of the free parameters (cluster-robust)
    correlation: np.ndarray  # of the free parameters
    condition_number: float  # of the column-scaled Jacobian
    weak_directions: list[WeakDirection]
    residuals_px: np.ndarray  # (N, 2) predicted - detected, rows of `model.data`
    weights: np.ndarray  # (N,) robust-loss weight of each vertex (1 without a robust loss)
    rms_px: tuple[float, float]
    iterations: int  # Jacobian evaluations
    function_evaluations: int
    solve_time_s: float
    model: Model
    downweighted_images: list[int] = field(default_factory=list)  # dataset image ids
    warnings: list[str] = field(default_factory=list)
    reading_step_rad: np.ndarray | None = None  # (J,) the readings' encoder step the std accounts for (None: none)
    quantisation_share: float = float("nan")  # how much of the full quantisation error the residuals show (0-1)

    @property
    def sigma_px(self) -> float:
        """Fitted noise level s = sqrt(RSS / (n - p)) over both pixel coordinates."""
        dof = max(self.residuals_px.size - len(self.registry.free_names), 1)
        return float(np.sqrt(np.sum(self.residuals_px ** 2) / dof))

    def value(self, name: str) -> float:
        return float(self.values[self.registry.index[name]])

    def parameters_dict(self) -> dict:
        return {
            name: {"value": float(v), "std": float(s), "unit": self.registry.unit(name)}
            for name, v, s in zip(self.registry.names, self.values, self.std)
        }


def identifiability(As: np.ndarray):
    """Singular values of the column-scaled Jacobian from its normal matrix As = Js^T Js (Js = J * scales):
    condition number, singular values (largest first) and right singular vectors (rows of Vt).

    From the small normal matrix: exact enough here (we only compare against 1e-6 of the largest) and the tall
    Jacobian is never held whole (NormalEquations)."""
    eigenvalues, vectors = np.linalg.eigh(As)
    order = np.argsort(eigenvalues)[::-1]
    sv = np.sqrt(np.clip(eigenvalues[order], 0.0, None))
    Vt = vectors[:, order].T
    if sv[0] == 0 or sv[-1] <= sv[0] * 1e-300:
        return np.inf, sv, Vt
    return float(sv[0] / sv[-1]), sv, Vt


def weak_direction(sv_rel, std_along, vector, names) -> WeakDirection:
    coefficients = {n: float(c) for n, c in zip(names, vector) if abs(c) > 0.05}
    return WeakDirection(float(sv_rel), float(std_along), coefficients)


# An image needs at least this many vertices to determine its board's pose by itself (4 points, 8 equations).
MIN_VERTICES_PER_IMAGE = 4


def data_warnings(data: ModelData) -> list[str]:
    """Problems of the data that do not stop the solve but that the user must know about."""
    warnings = []
    counts = np.bincount(data.image_of_row, minlength=data.n_images)
    thin = data.image_id[counts < MIN_VERTICES_PER_IMAGE]
    if len(thin):
        listed = ", ".join(str(int(i)) for i in thin[:10]) + (" ..." if len(thin) > 10 else "")
        warnings.append(f"{len(thin)} of {data.n_images} images have fewer than {MIN_VERTICES_PER_IMAGE} vertices "
                        f"(images {listed}): each alone cannot fix its board's pose, so a bad detection in them "
                        "cannot be told from a model error")
    return warnings


def check_identifiable(As: np.ndarray, names, advice=None):
    """Raise SolveError naming the parameters that the data cannot determine at all (As: the scaled normal matrix
    of the free parameters `names`). advice([WeakDirection]) -> '' or what to do about those directions (a kind
    that knows which parameter to fix), said instead of the general advice."""
    names = list(names)
    cond, sv, Vt = identifiability(As)
    bad = np.flatnonzero(sv < UNIDENTIFIABLE_RATIO * sv[0]) if sv[0] > 0 else np.arange(len(sv))
    if len(bad):
        involved = sorted({names[i] for k in bad for i in np.flatnonzero(np.abs(Vt[k]) > 0.05)})
        directions = [weak_direction(sv[k] / max(sv[0], 1e-300), np.inf, Vt[k], names) for k in bad]
        combos = "; ".join(d.describe() for d in directions[:3])
        raise SolveError(
            f"the data cannot determine {len(bad)} parameter combination(s) ({combos}); involved: "
            f"{', '.join(involved)}. "
            + ((advice(directions) if advice else "") or "Measure more varied poses, or fix these parameters (--fix).")
        )


def gauges(As: np.ndarray, order, fixable) -> dict[int, tuple[list[int], float]]:
    """The parameters a kind's parametrisation makes redundant by construction: {i: ([j, ...], relative residual)},
    each i within UNIDENTIFIABLE_RATIO of the span of the parameters `order` kept before it (j: those it leans on
    most).

    The one identifiability policy (docs/ARM.md, "Identifiability"): a direction whose relative singular value is
    below UNIDENTIFIABLE_RATIO is not determined by the data. A kind may name some of its parameters gauges
    (`fixable[i]`): parameters that other parameters of it absorb whatever the data (an arm's sensor frames, which
    may be anywhere, absorb a turn of the whole arm about its first axis, so its first joint's offset); taken in the
    kind's `order`, such a parameter within the threshold of the span of those kept before it is fixed at its start
    value and reported with its partners (the prediction does not change). Whatever is still undetermined after
    that stops the fit (check_identifiable): a joint offset fixed at 0 because the data were too poor would be a
    wrong calibration, written to a robot. The test is the relative residual of the parameter's scaled Jacobian
    column after projection onto the columns kept before it (the pivots of a Cholesky factorisation of As in that
    order); the Jacobian itself is never formed (NormalEquations).
    """
    d = np.sqrt(np.clip(np.diag(As), 0.0, None))
    C = As / np.outer(np.where(d > 0, d, 1.0), np.where(d > 0, d, 1.0))  # unit columns
    kept, out = [], {}
    for i in order:
        if d[i] == 0.0:
            if fixable[i]:
                out[i] = ([], 0.0)
            continue
        if kept:
            coef = np.linalg.lstsq(C[np.ix_(kept, kept)], C[kept, i], rcond=None)[0]
            residual2 = float(C[i, i] - C[kept, i] @ coef)
        else:
            coef, residual2 = np.zeros(0), 1.0
        if fixable[i] and residual2 < UNIDENTIFIABLE_RATIO ** 2:
            out[i] = ([kept[j] for j in np.argsort(-np.abs(coef))[:3] if abs(coef[j]) > 1e-3],
                      float(np.sqrt(max(residual2, 0.0))))
            continue
        kept.append(i)
    return out


# Outliers, for every kind (solver.fit for the NAO's corners, kinds.arm.identify for the arm's detections,
# kinds.duckiebot.fit for its marker corners; one loop: `trimmed`): a measurement whose residual exceeds
# OUTLIER_SCALES robust (MAD) scales is a mis-detection (2-D Gaussian: 4e-6 of good ones, 3-D: 1.4e-5); only the
# worst of its group (image, pose) each round, since a bad one drags its group's fit and so its neighbours; at most
# MAX_TRIM_ROUNDS rounds, refitting after each. Then the set-aside measurements the final fit explains (within the
# same threshold) are taken back and the data refitted, until the kept set is the one the final fit accepts: an
# early round judged them while the true outliers still dragged the fit (dual arm, seed 1, 0.1 px: 7 good corners
# of ~1100 were listed as mis-detected, 0.04-0.4 px at the final fit). As Hartley & Zisserman's robust estimation
# finishes (Multiple View Geometry, 2nd ed., Algorithm 4.6: re-estimate from all the correspondences the final
# model classes as inliers, iterate until their number is stable) and COLMAP's IterativeGlobalRefinement (complete
# the tracks, adjust, filter, repeat while observations change). Hysteresis: a measurement taken back once and set
# aside again stays aside, so nothing oscillates; at most MAX_READMIT_ROUNDS re-admissions.
OUTLIER_SCALES = 5.0
MAX_TRIM_ROUNDS = 10
MAX_READMIT_ROUNDS = 3
MAD_TO_SIGMA = 1.4826  # 1 / Phi^-1(3/4): the median absolute deviation of a Gaussian, in standard deviations


def worst_of_group_beyond(size: np.ndarray, group: np.ndarray, threshold: float) -> np.ndarray:
    """Indices of the rows that are the largest `size` of their `group` and beyond `threshold` (the trimming's
    one round)."""
    group = np.asarray(group, dtype=np.int64)
    worst = np.full(int(group.max(initial=-1)) + 1, -1)
    order = np.argsort(size)
    worst[group[order]] = order
    return np.array([i for i in worst if i >= 0 and size[i] > threshold], dtype=int)


def trimmed(result, refit, judge, group, kept, *, rounds: int = MAX_TRIM_ROUNDS):
    """(result, kept, trimming rounds used): the outlier trimming of every kind (the rule above), from `result`, the
    fit of the rows `kept` (bool, one per row of all the data).

    refit(kept, result) : the fit of the rows `kept`, started from `result`'s values.
    judge(result, kept) : (size of EVERY row under `result`, threshold): the rows set aside are judged by the fit of
        the kept ones (on the kept rows' robust scale), as the kept rows are.
    group : (rows,) the group of each row (image, pose, frame): the worst of a group beyond the threshold per round.
    rounds : trimming rounds before the re-admission (the budget `used` counts); after each re-admission the trimming
        runs again (MAX_TRIM_ROUNDS rounds of its own), for the rows the refit now leaves beyond the threshold.
    """
    kept, group = np.array(kept, dtype=bool), np.asarray(group)
    readmitted = np.zeros_like(kept)
    used = 0
    for readmission in range(MAX_READMIT_ROUNDS + 1):
        size, threshold = judge(result, kept)
        for _ in range(rounds - used if readmission == 0 else MAX_TRIM_ROUNDS):
            rows = np.flatnonzero(kept)
            bad = rows[worst_of_group_beyond(size[rows], group[rows], threshold)]
            if not len(bad):
                break
            kept[bad] = False
            result = refit(kept, result)
            used += readmission == 0
            size, threshold = judge(result, kept)
        back = ~kept & ~readmitted & (size <= threshold)
        if readmission == MAX_READMIT_ROUNDS or not back.any():
            break
        kept |= back
        readmitted |= back
        result = refit(kept, result)
    return result, kept, used


# Vertex rows per chunk of NormalEquations: a chunk's arrays are a few per vertex (its factored Jacobian's F is
# rows x 2 x 6 doubles; a dense chunk Jacobian, for scipy's solvers and GLS, rows x 2 x P: 5.5 MB at 16384 rows and
# 21 parameters), so memory stays linear in the data with a small constant and the chunk's arrays stay near the
# caches; the paper's 3456 vertices are one chunk (benchmarks/bench_scale.py measured the choice).
CHUNK_ROWS = 16384


@dataclass
class Normal:
    """What one pass over the data gives at one free vector, in scaled variables (xs = x / scales): the normal matrix
    A = Js^T Js, the gradient g = Js^T r, the cost 0.5 r^T r, the residuals (N, 2) and each image's score
    Js_m^T r_m (M, P_free) for the cluster-robust covariance."""

    A: np.ndarray
    g: np.ndarray
    cost: float
    residuals: np.ndarray
    scores: object  # (M, P_free) array, or a function computing it (one chunk: only the final pass needs them)

    @property
    def image_scores(self) -> np.ndarray:
        if callable(self.scores):
            self.scores = self.scores()
        return self.scores


class NormalEquations:
    """The model's normal equations accumulated over chunks of images: the dense (2N x P) Jacobian is never held
    for more than `chunk_rows` vertices at a time, so memory grows with the data by a small constant (the data, the
    residuals) and the parameter count stays the only square term. A pass does not form it at all: each image's
    J_m = F_m T_m (Model.factored), so A = sum_m T_m^T (F_m^T F_m) T_m and g = sum_m T_m^T F_m^T r_m.

    model : the Model over all the data (its data sorted by target; chunks are runs of its images, in order).
    """

    def __init__(self, data: ModelData, registry: Registry, base: np.ndarray, *, chunk_rows: int = CHUNK_ROWS):
        self.model = model = Model(data, registry)
        self.registry, self.base = registry, np.asarray(base, dtype=float)
        data = model.data
        counts = np.bincount(data.image_of_row, minlength=data.n_images)
        first = np.searchsorted(data.image_of_row, np.arange(data.n_images + 1))  # each image's first row
        cuts = [0]
        for m, row in enumerate(first[:-1]):
            if m > cuts[-1] and row - first[cuts[-1]] + counts[m] > chunk_rows:
                cuts.append(m)
        cuts.append(data.n_images)
        self.image_ranges = list(zip(cuts[:-1], cuts[1:]))
        self.parts = [model] if len(self.image_ranges) == 1 else [
            Model(data.subset(np.arange(a, b)), registry) for a, b in self.image_ranges]
        self.scales = registry.scales[registry.free_index]
        P = len(registry)
        self._identity_expand = registry.expand.shape == (P, P) and np.array_equal(registry.expand, np.eye(P))
        self._rows_of_images = [_ImageRows(part.data) for part in self.parts]

    def __call__(self, free: np.ndarray, *, weights: np.ndarray | None = None, jacobian: bool = True) -> Normal:
        """One pass at the free vector `free`. `weights` (N,) per vertex (a robust loss's): g, cost and the scores
        are of the weighted residuals sqrt(w) r, A stays J^T J (the covariance's bread); the residuals are returned
        unweighted. Without `jacobian` only the residuals and cost."""
        values = self.registry.unpack(free, self.base)
        p = len(self.scales)
        A, g, rss = np.zeros((p, p)), np.zeros(p), 0.0
        residuals = np.empty((self.model.data.n_rows, 2))
        image_scores = np.zeros((self.model.data.n_images, p))
        row = 0
        for (first_image, last_image), part, rows in zip(self.image_ranges, self.parts, self._rows_of_images):
            n = part.data.n_rows
            if jacobian:  # J = F @ T per image (Model.factored): sum the images' T^T (F^T F) T, never J itself
                r, F, T = part.factored(values)
            else:
                r = part.evaluate(values, jacobian=False)[0]
            residuals[row:row + n] = r
            if weights is not None:
                r = r * np.sqrt(weights[row:row + n])[:, None]
            rss += float(r.reshape(-1) @ r.reshape(-1))
            if jacobian:
                Ts = (T if self._identity_expand else T @ self.registry.expand) * self.scales  # (M, C, P_free)
                gram, projected = rows.gram(F, r)  # F_m^T F_m (M, C, C), F_m^T r_m (M, C)
                flat = Ts.reshape(-1, p)
                A += flat.T @ (gram @ Ts).reshape(-1, p)
                g += flat.T @ projected.reshape(-1)
                image_scores[first_image:last_image] = np.einsum("mcp,mc->mp", Ts, projected)
            row += n
        return Normal(0.5 * (A + A.T), g, 0.5 * rss, residuals, image_scores)

    def residuals(self, free: np.ndarray) -> np.ndarray:
        return self(free, jacobian=False).residuals

    def dense(self, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(r (2N,), J_free (2N, P_free)) at once: for scipy's solvers (robust losses, MINPACK), which need the whole
        Jacobian; memory 16 P bytes per vertex."""
        values = self.registry.unpack(free, self.base)
        rs, Js = [], []
        for part in self.parts:
            r, J = part.evaluate(values)
            J = J.reshape(r.size, -1)
            rs.append(r.reshape(-1))
            Js.append(J if self._identity_expand else J @ self.registry.expand)
        return np.concatenate(rs), np.concatenate(Js)


class _ImageRows:
    """Sums over each image's rows of a Model's data (rows grouped by image, in image order)."""

    def __init__(self, data: ModelData):
        counts = np.bincount(data.image_of_row, minlength=data.n_images)
        self.n_images, self.n_rows = data.n_images, data.n_rows
        self.per_image = int(counts[0]) if data.n_images and np.all(counts == counts[0]) else None  # None: varies
        self.filled = np.flatnonzero(counts)  # images with rows
        self.starts = np.searchsorted(data.image_of_row, self.filled)

    def gram(self, F: np.ndarray, r: np.ndarray):
        """(F_m^T F_m (M, C, C), F_m^T r_m (M, C)) of every image m, for F (N, 2, C) and r (N, 2)."""
        C = F.shape[2]
        if self.per_image:  # every image the same number of rows: one batched product
            Fm = F.reshape(self.n_images, -1, C)
            Ft = np.swapaxes(Fm, 1, 2)
            return Ft @ Fm, (Ft @ r.reshape(self.n_images, -1, 1))[..., 0]
        gram, projected = np.zeros((self.n_images, C, C)), np.zeros((self.n_images, C))
        if len(self.filled):
            gram[self.filled] = np.add.reduceat(np.einsum("nki,nkj->nij", F, F), self.starts, axis=0)
            projected[self.filled] = np.add.reduceat(np.einsum("nki,nk->ni", F, r), self.starts, axis=0)
        return gram, projected


def normal_equations(model: Model, registry: Registry, values: np.ndarray, *, chunk_rows: int = CHUNK_ROWS):
    """(A, g, rss, n) at the full vector `values`: the free parameters' normal matrix and gradient in UNSCALED units
    (J^T J, J^T r), the residual sum of squares and the number of residual coordinates; chunked (NormalEquations)."""
    equations = NormalEquations(model.data, registry, values, chunk_rows=chunk_rows)
    normal = equations(registry.pack(values))
    inverse_scales = 1.0 / equations.scales
    return (normal.A * np.outer(inverse_scales, inverse_scales), normal.g * inverse_scales, 2.0 * normal.cost,
            2 * model.data.n_rows)


def parameter_covariance(As, rss, image_scores, sv, Vt, scales, cluster_of_image, n, dof, prior_information=None):
    """Covariance of the free parameters: cluster-robust (sandwich), and the classic s^2 (J^T J)^-1.

    The 24 vertices of one image share its errors (a board that flexes, a detection bias), and the images of one
    stance share the leg's (encoder quantisation, play, whatever the model lacks about that posture), so the
    classic estimate, which treats every pixel as independent, is too optimistic; the sandwich
    (J^T J)^-1 (sum_c g_c g_c^T) (J^T J)^-1 with g_c = J_c^T r_c the score of cluster c is not. Clusters:
    `cluster_of_image` (M,) (solver.scoretest.stance_cluster_of_image); `image_scores` (M, P) the scaled scores of
    each image (Normal.image_scores). Both results are in the unscaled parameter units. Unidentifiable directions
    (singular value below UNIDENTIFIABLE_RATIO) are left out. With a prior (Prior), As includes its information
    `prior_information` (scaled), which the sandwich's meat gets as it is: a prior is no cluster of the data, and
    where the data say nothing the posterior is the prior.
    """
    usable = sv > UNIDENTIFIABLE_RATIO * sv[0]
    inv_sv2 = np.where(usable, 1.0 / np.where(usable, sv, 1.0) ** 2, 0.0)
    bread = (Vt.T * inv_sv2) @ Vt  # (Js^T Js)^+ in scaled units
    s2 = rss / dof
    if prior_information is None:
        iid = bread * s2
    else:  # the residuals' variance scales the data's information only: where the data say nothing, the prior
        iid = bread @ ((As - prior_information) * s2 + prior_information) @ bread
    covariance_iid = iid * np.outer(scales, scales)
    scores = np.zeros((int(np.max(cluster_of_image, initial=-1)) + 1, As.shape[1]))
    np.add.at(scores, np.asarray(cluster_of_image, dtype=int), image_scores)
    n_clusters, p = len(scores), As.shape[1]
    small_sample = n_clusters / max(n_clusters - 1, 1) * (n - 1) / max(n - p, 1)
    meat = scores.T @ scores * small_sample
    if prior_information is not None:
        meat = meat + prior_information
    clustered = bread @ meat @ bread
    covariance = _at_least(clustered, iid) * np.outer(scales, scales)
    return covariance, covariance_iid


def _at_least(clustered: np.ndarray, iid: np.ndarray) -> np.ndarray:
    """The clustered covariance, raised in every direction where it is below the classic one.

    With few clusters for many parameters (32 stances for 21 parameters) the sandwich is biased low along the
    weakly determined directions: on data whose only error is independent pixel noise, where the classic estimate
    is right, it claimed 0.006 deg for a right-leg offset whose error was 0.021 deg (3.6 std). Errors shared within
    a stance can only add to the pixel noise, so along every direction the larger of the two is kept (the
    generalised eigenvalues of the pair raised to at least 1).
    """
    a, W = np.linalg.eigh((iid + iid.T) / 2)
    keep = a > 1e-12 * max(a.max(initial=0.0), 1e-300)
    if not np.any(keep):
        return clustered
    S = W[:, keep] * np.sqrt(a[keep])  # iid = S S^T
    S_inv = (W[:, keep] / np.sqrt(a[keep])).T
    lam, U = np.linalg.eigh(S_inv @ ((clustered + clustered.T) / 2) @ S_inv.T)
    raised = S @ (U * np.maximum(lam, 1.0)) @ U.T @ S.T
    # what lies outside the classic estimate's span (nothing, for a sandwich with the same bread) is kept
    outside = clustered - S @ (S_inv @ clustered @ S_inv.T) @ S.T
    return raised + outside


def quantisation_covariance(model, values, registry, J_free, sv, Vt, scales, step_rad, *, with_share=False):
    """Covariance of the free parameters that quantised joint readings cause (errors in the variables).

    A reading quantised to a step s leaves the angle off by an error of variance s^2 / 12 (uniform in the step).
    The images that share a reading of a joint within a cluster of one stance (solver.scoretest) share that error:
    it moves their residuals by a = d r / d theta_j = -d r / d c_j (the joint-offset columns) and the fit by
    -(J^T J)^-1 J^T a, so each group adds (s^2 / 12) (J^T J)^-1 J^T a a^T J (J^T J)^-1. The fit absorbs this error
    into the parameters, so neither the residuals nor the sandwich can see it. Joints without an offset
    parameter in the full model are left out.
    Whether the angles carry that error is the data's to say: a servo that stands exactly at its command, with the
    command as theta, leaves none. The error moves whole boards, so the rigid part of the residuals measures it:
    its excess over the detector noise (estimated from the non-rigid part) divided by what the full error would
    leave there scales the term (between 0 and 1).
    """
    from naocal.solver.noisefloor import RigidSplit
    from naocal.solver.effects import EFFECTS
    from naocal.solver.model import Model

    data = model.data
    offsets = tuple(name for name, e in EFFECTS.items() if e.reading_offsets)
    full = Registry(tuple(dict.fromkeys(registry.effects + offsets)), setup=registry.setup)
    J = Model(data, full).evaluate(full.from_dict(registry.as_dict(values)))[1]  # (N, 2, P_full)
    usable = sv > UNIDENTIFIABLE_RATIO * sv[0]
    inv_sv2 = np.where(usable, 1.0 / np.where(usable, sv, 1.0) ** 2, 0.0)
    bread = (Vt.T * inv_sv2) @ Vt  # (Js^T Js)^+, scaled units
    Js = (J_free * scales).reshape(data.n_rows, 2, -1)  # J_free: tall (2N, P_free)
    cluster = stance_cluster_of_image(data)
    meat = np.zeros((Js.shape[2], Js.shape[2]))
    left_px2 = 0.0  # the residual sum of squares the full quantisation error would leave after the fit
    for p in full.parameters:
        if not EFFECTS[p.effect].reading_offsets:
            continue
        c = data.column(p.joint)
        if step_rad[c] <= 0:
            continue
        a = J[:, :, full.index[p.name]]  # (N, 2): d r / d c_j = -d r / d theta_j (the sign drops out)
        g = np.einsum("ni,nip->np", a, Js)  # per row: J_s^T a
        _, group = np.unique(np.column_stack([cluster, np.round(data.theta[:, c] / step_rad[c])]), axis=0,
                             return_inverse=True)
        b = np.zeros((int(group.max()) + 1, Js.shape[2]))
        np.add.at(b, group.reshape(-1)[data.image_of_row], g)
        meat += step_rad[c] ** 2 / 12.0 * (b.T @ b)
        a_sq = np.zeros(len(b))
        np.add.at(a_sq, group.reshape(-1)[data.image_of_row], np.sum(a ** 2, axis=1))
        left_px2 += step_rad[c] ** 2 / 12.0 * float(np.sum(a_sq) - np.einsum("gp,pq,gq->", b, bread, b))
    rigid, nonrigid = RigidSplit(model, values)(model.residuals(values))
    n_images, p = data.n_images, Js.shape[2]
    detector_px2 = float(np.sum(nonrigid ** 2)) / max(2 * data.n_rows - 6 * n_images, 1)
    excess_px2 = float(np.sum(rigid ** 2)) - detector_px2 * max(6 * n_images - p, 0)
    share = float(np.clip(excess_px2 / left_px2, 0.0, 1.0)) if left_px2 > 0 else 1.0
    covariance = share * (bread @ meat @ bread) * np.outer(scales, scales)
    return (covariance, share) if with_share else covariance


def levenberg_marquardt(normal_at, x0, scales, *, max_iterations=100, ftol=1e-10, xtol=1e-10, gtol=1e-10):
    """Levenberg-Marquardt with Nielsen's damping update, on the normal equations in scaled variables.

    `normal_at(x)` returns a Normal (A = Js^T Js, g = Js^T r, cost = 0.5 r^T r, Js = J * scales) at x: the
    variables are scaled by `scales` (x = scales * xs) so that parameters in m, rad and px are conditioned alike,
    and only the P x P normal equations are needed, never the tall Jacobian (NormalEquations accumulates them
    over chunks of images). Returns (x, Normal at x, status, message, n_jacobians, n_functions); status as
    scipy.optimize.least_squares's (TERMINATION_MESSAGES).
    """
    x = np.array(x0, dtype=float)
    at = normal_at(x)
    n_fun = n_jac = 1
    mu = 1e-6 * float(np.max(np.diag(at.A))) if at.A.size else 0.0
    nu = 2.0
    identity = np.eye(len(x))
    for _ in range(max_iterations):
        A, g, cost = at.A, at.g, at.cost
        if np.max(np.abs(g), initial=0.0) <= gtol:
            return x, at, 1, TERMINATION_MESSAGES[1], n_jac, n_fun
        try:
            step_s = -np.linalg.solve(A + mu * identity, g)
        except np.linalg.LinAlgError:
            mu, nu = mu * nu, nu * 2.0
            continue
        xs = x / scales
        if np.linalg.norm(step_s) <= xtol * (np.linalg.norm(xs) + xtol):
            return x, at, 3, TERMINATION_MESSAGES[3], n_jac, n_fun
        predicted = 0.5 * float(step_s @ (mu * step_s - g))  # cost reduction the linear model promises
        if predicted <= ftol * cost:  # the linear model promises (almost) nothing more
            return x, at, 2, TERMINATION_MESSAGES[2], n_jac, n_fun
        x_new = x + step_s * scales
        trial = normal_at(x_new)
        n_fun += 1
        rho = (cost - trial.cost) / predicted if predicted > 0 else -1.0
        if rho > 0:
            reduction = cost - trial.cost
            x, at = x_new, trial
            n_jac += 1
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if reduction <= ftol * trial.cost:
                return x, at, 2, TERMINATION_MESSAGES[2], n_jac, n_fun
        else:
            mu, nu = mu * nu, nu * 2.0
    return x, at, 0, TERMINATION_MESSAGES[0], n_jac, n_fun


ROBUST_WEIGHT = {  # rho'(z) of scipy.optimize.least_squares's robust losses, z = (r / scale)^2
    "soft_l1": lambda z: 1 / np.sqrt(1 + z),
    "huber": lambda z: np.where(z <= 1, 1.0, 1 / np.sqrt(np.maximum(z, 1.0))),
    "cauchy": lambda z: 1 / (1 + z),
}
LOSSES = ("linear",) + tuple(ROBUST_WEIGHT)
ROBUST_RHO = {  # (rho, rho', rho'') of the same losses, as scipy.optimize.least_squares's callable `loss` returns
    "soft_l1": lambda z: (2.0 * (np.sqrt(1 + z) - 1), 1 / np.sqrt(1 + z), -0.5 / (1 + z) ** 1.5),
    "huber": lambda z: (np.where(z <= 1, z, 2 * np.sqrt(np.maximum(z, 1.0)) - 1), ROBUST_WEIGHT["huber"](z),
                        np.where(z <= 1, 0.0, -0.5 / np.maximum(z, 1.0) ** 1.5)),
    "cauchy": lambda z: (np.log1p(z), 1 / (1 + z), -1 / (1 + z) ** 2),
}


@dataclass
class Prior:
    """Gaussian pseudo-observations (soft bounds) on some free parameters: one whitened row (free[index] - mean) / std
    each, appended to the data's residuals with its exact Jacobian (1 / std). In the normal equations (scaled
    variables) it adds (scales / std)^2 to A's diagonal, scales (free - mean) / std^2 to g and half its squares to
    the cost. A robust loss never bends it (it is a Gaussian, not a measurement that may be wrong)."""

    index: np.ndarray  # positions in the free vector
    mean: np.ndarray
    std: np.ndarray

    def __len__(self):
        return len(self.index)

    def residuals(self, free) -> np.ndarray:
        return (np.asarray(free)[self.index] - self.mean) / self.std

    def jacobian(self, n_free: int) -> np.ndarray:
        J = np.zeros((len(self.index), n_free))
        J[np.arange(len(self.index)), self.index] = 1.0 / self.std
        return J

    def information(self, scales) -> np.ndarray:
        """What it adds to the scaled normal matrix (P_free, P_free)."""
        P = np.zeros((len(scales), len(scales)))
        P[self.index, self.index] = (scales[self.index] / self.std) ** 2
        return P

    def added(self, normal: "Normal", free, scales) -> "Normal":
        """`normal` (the data's) with the prior's rows: the residuals and scores stay the data's."""
        r = self.residuals(free)
        g = normal.g.copy()
        g[self.index] += scales[self.index] / self.std * r
        return Normal(normal.A + self.information(scales), g, normal.cost + 0.5 * float(r @ r), normal.residuals,
                      normal.scores)


@dataclass
class Spread:
    """How precisely a solution is known: the cluster-robust and the classic covariance of the free parameters
    (unscaled units), the scaled Jacobian's singular values and vectors, and its weakest directions."""

    covariance: np.ndarray
    covariance_iid: np.ndarray
    condition_number: float
    sv: np.ndarray
    Vt: np.ndarray
    weak_directions: list

    def warnings(self) -> list[str]:
        return [f"weakly determined combination (relative singular value {d.singular_value:.1e}): {d.describe()}"
                for d in self.weak_directions if d.singular_value < WEAK_RATIO]


@dataclass
class Solution:
    """What `solve` found: the free values, the normal equations there (with a robust loss: of the weighted
    residuals), why it stopped, and each residual row's robust weight (1 without a robust loss)."""

    free: np.ndarray
    final: Normal
    scales: np.ndarray
    status: int
    message: str
    n_jac: int
    n_fun: int
    success: bool
    weights: np.ndarray
    n_measured: int  # residual components that are measurements (the degrees of freedom count these)
    prior: Prior | None = None  # the pseudo-observations the fit included (their rows count as measurements too)

    def spread(self, cluster_of_group, names) -> Spread:
        """The covariance with the errors shared within a cluster (`cluster_of_group` (M,): the cluster of each
        row of Normal.image_scores: an image's stance for the NAO, an observation's pose for the arm)."""
        n_prior = 0 if self.prior is None else len(self.prior)
        dof = max(self.n_measured + n_prior - len(self.scales), 1)
        rss = 2.0 * self.final.cost  # weighted with a robust loss; the prior's rows included
        cond, sv, Vt = identifiability(self.final.A)
        covariance, covariance_iid = parameter_covariance(
            self.final.A, rss, self.final.image_scores, sv, Vt, self.scales, cluster_of_group, self.n_measured, dof,
            None if not n_prior else self.prior.information(self.scales))
        s = np.sqrt(rss / dof)
        weak = [weak_direction(sv[k] / sv[0], float(s / sv[k]) if sv[k] > 0 else np.inf, Vt[k], names)
                for k in np.argsort(sv)[:3]]
        return Spread(covariance, covariance_iid, cond, sv, Vt, weak)


def last_pass_cached(equations):
    """`equations` (free values -> normal equations) remembering its last pass: LM and the checks ask at one x
    twice, and a pass over every chunk is the fit's whole cost."""
    cache = {}

    def normal_at(free):
        key = free.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = equations(free)
        return cache[key]

    return normal_at


def solve(equations, normal_at, free0, *, loss: str = "linear", loss_scale: float = 1.0, solver: str = "lm",
          max_iterations: int = 100, measured: np.ndarray | None = None, prior: Prior | None = None) -> Solution:
    """The one solve of every robot kind: Levenberg-Marquardt on the normal equations (`levenberg_marquardt`), or,
    for a robust loss or 'minpack', scipy.optimize.least_squares on the whole Jacobian.

    equations : the problem (NormalEquations, or an arm's kinds.arm.identify.ArmEquations): `scales`,
        `equations(free, weights=)` -> Normal and `equations.dense(free)` -> (r over the measured components, J).
    normal_at : `equations` at a free vector, cached (LM and the checks ask at one x twice).
    loss, loss_scale : 'linear' or a robust loss of ROBUST_WEIGHT; the residual size (in the residuals' units) where
        it bends. The weights of each residual row are the mean of rho' over its measured components.
    measured : (N, C) bool, which components of Normal.residuals are measurements (default: all).
    prior : Gaussian pseudo-observations on free parameters (Prior), added to every pass; never robust-weighted.
    """
    scales = equations.scales
    if prior is not None and not len(prior):
        prior = None
    if prior is not None:
        data_normal_at = normal_at

        def normal_at(free):
            return prior.added(data_normal_at(free), free, scales)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        try:
            if loss == "linear" and solver == "lm":
                free, final, status, message, n_jac, n_fun = levenberg_marquardt(
                    normal_at, free0, scales, max_iterations=max_iterations)
                success = status > 0
            else:
                dense_cache = {}

                def dense(f):
                    key = f.tobytes()
                    if key not in dense_cache:
                        dense_cache.clear()
                        r, J = equations.dense(f)
                        if prior is not None:  # its rows last
                            r, J = np.concatenate([r, prior.residuals(f)]), np.vstack([J, prior.jacobian(len(f))])
                        dense_cache[key] = r, J
                    return dense_cache[key]

                method = "lm" if loss == "linear" else "trf"
                sol = least_squares(
                    lambda f: dense(f)[0], free0, jac=lambda f: dense(f)[1], method=method,
                    x_scale=scales, loss=loss if prior is None or loss == "linear" else _robust_but_last(loss, len(prior)),
                    f_scale=loss_scale,
                    max_nfev=max_iterations * (len(scales) + 1), xtol=1e-10, ftol=1e-10, gtol=1e-10,
                )
                dense_cache.clear()
                free, status = sol.x, int(sol.status)
                message = TERMINATION_MESSAGES.get(status, str(sol.message))
                n_jac, n_fun, success = int(sol.njev or 0), int(sol.nfev), bool(sol.success)
                final = normal_at(free)
        except FloatingPointError as err:
            raise SolveError(f"the model could not be evaluated during the solve ({err}): is a board behind the "
                             "camera, or are the start values wildly wrong?") from None
    residuals = final.residuals
    mask = np.ones(residuals.shape, dtype=bool) if measured is None else measured
    weights = np.ones(len(residuals))
    if loss != "linear":
        rho1 = ROBUST_WEIGHT[loss]((residuals / loss_scale) ** 2)
        weights = np.sum(rho1 * mask, axis=1) / np.maximum(mask.sum(axis=1), 1)
        final = equations(free, weights=weights)  # the covariance's scores of the weighted residuals
        if prior is not None:
            final = prior.added(final, free, scales)
        final.residuals = residuals
    return Solution(free, final, scales, int(status), message, int(n_jac), int(n_fun),
                    bool(success) and bool(np.all(np.isfinite(free))), weights, int(mask.sum()), prior)


def _robust_but_last(loss: str, k: int):
    """scipy.optimize.least_squares's callable loss: `loss` on every residual but the last k (a Prior's rows),
    which stay quadratic."""

    def rho(z):
        out = np.empty((3, z.size))
        out[:, :-k] = np.array(ROBUST_RHO[loss](z[:-k]))
        out[0, -k:], out[1, -k:], out[2, -k:] = z[-k:], 1.0, 0.0
        return out

    return rho


def identify(data: ModelData, registry: Registry, *, x0: np.ndarray | None = None, loss: str = "linear",
             loss_scale_px: float = 1.0, max_iterations: int = 100, check: bool = True,
             solver: str = "lm", chunk_rows: int = CHUNK_ROWS, reading_step_rad=None) -> IdentificationResult:
    """Fit the registry's free parameters to the detected vertices.

    Parameters
    ----------
    x0 : full parameter vector to start from (default: zero, the nominal robot).
    loss : 'linear' (plain least squares) or a robust loss of scipy.optimize.least_squares ('soft_l1', 'huber',
        'cauchy'), solved by its trust-region method; images it down-weights are reported.
    loss_scale_px : residual size at which the robust loss starts to down-weight, px.
    solver : 'lm' (naocal's Levenberg-Marquardt on the normal equations, the fast default, memory linear in the
        data) or 'minpack' (scipy.optimize.least_squares(method='lm')); both minimise the same sum of squares.
        The robust losses and 'minpack' hold the whole Jacobian (16 P bytes per vertex).
    chunk_rows : vertices per chunk of the normal equations (NormalEquations).
    reading_step_rad : (J,) encoder step of each joint's readings (0: exact); the standard deviations then include
        the error the step leaves in the angles (`quantisation_covariance`).
    """
    start = time.perf_counter()
    warnings = []
    base = registry.zeros() if x0 is None else np.asarray(x0, dtype=float)

    def make_problem(registry):
        """The chunked normal equations, and a cache of the last pass (LM and the checks ask at one x twice)."""
        equations = NormalEquations(data, registry, base, chunk_rows=chunk_rows)
        return equations, last_pass_cached(equations)

    equations, normal_at = make_problem(registry)
    model = equations.model
    if check:
        warnings.extend(data_warnings(model.data))
        empty = [n for n, a in zip(registry.free_names, np.diag(normal_at(registry.pack(base)).A)) if a == 0]
        if empty:
            warnings.append(f"no data for {', '.join(empty)}: these parameters are fixed at their start values")
            registry = registry.with_fixed(empty)
            equations, normal_at = make_problem(registry)
    if not len(registry.free_names):
        raise SolveError("no free parameters to identify")

    free0 = registry.pack(base)
    if check:
        check_identifiable(normal_at(free0).A, registry.free_names)
    solution = solve(equations, normal_at, free0, loss=loss, loss_scale=loss_scale_px, solver=solver,
                     max_iterations=max_iterations)
    free, final, weights = solution.free, solution.final, solution.weights
    scales = equations.scales
    values = registry.unpack(free, base)
    residuals = final.residuals
    spread = solution.spread(stance_cluster_of_image(model.data), registry.free_names)
    covariance, sv, Vt = spread.covariance, spread.sv, spread.Vt
    share = float("nan")
    if reading_step_rad is not None and np.any(np.asarray(reading_step_rad) > 0):
        J_free = equations.dense(free)[1]  # the only tall Jacobian of the linear fit; only when steps are asked
        added, share = quantisation_covariance(model, values, registry, J_free, sv, Vt, scales,
                                               np.asarray(reading_step_rad, dtype=float), with_share=True)
        covariance = covariance + added
    std_free = np.sqrt(np.diag(covariance))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(std_free, std_free)
    std = np.abs(registry.expand) @ std_free
    std_iid = np.abs(registry.expand) @ np.sqrt(np.diag(spread.covariance_iid))
    warnings.extend(spread.warnings())
    cond, weak = spread.condition_number, spread.weak_directions
    status, message, n_jac, n_fun, success = (solution.status, solution.message, solution.n_jac, solution.n_fun,
                                              solution.success)

    downweighted = []
    if loss != "linear":
        per_image = np.bincount(model.data.image_of_row, weights=weights, minlength=model.data.n_images)
        counts = np.bincount(model.data.image_of_row, minlength=model.data.n_images)
        mean_w = per_image / np.maximum(counts, 1)
        downweighted = [int(model.data.image_id[m]) for m in np.flatnonzero(mean_w < DOWNWEIGHT_REPORT)]

    rms = np.sqrt(np.mean(residuals ** 2, axis=0))
    success = bool(success) and bool(np.all(np.isfinite(values)))
    return IdentificationResult(
        success=success, status=int(status), message=message, registry=registry, values=values,
        std=std, std_iid=std_iid, covariance=covariance, correlation=correlation, condition_number=cond, weak_directions=weak,
        residuals_px=residuals, weights=weights, rms_px=(float(rms[0]), float(rms[1])),
        iterations=int(n_jac), function_evaluations=int(n_fun), solve_time_s=time.perf_counter() - start,
        model=model, downweighted_images=downweighted, warnings=warnings,
        reading_step_rad=None if reading_step_rad is None else np.asarray(reading_step_rad, dtype=float),
        quantisation_share=share,
    )
