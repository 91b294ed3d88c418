"""The score (Lagrange multiplier) test of adding a block of parameters to a fitted least-squares model.

Shared by the candidate ranking and the regressor scan of solver.diagnostics: an orthonormal basis of the fitted
model's Jacobian, the projection of a candidate block off it, and a significance test whose variance is clustered
(residuals are correlated within an image and within a stance, independent between stances) and
leverage-corrected (jackknife). Residuals are predicted - detected, px, flattened to (2 N,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import fdtrc  # F survival function (scipy.stats is slow to import)


# A direction of a candidate whose share of its Jacobian left after projecting off the fitted model is below this
# is numerically inside the model: not counted as a degree of freedom of the test.
RANK_TOLERANCE = 1e-9


def rms(a) -> float:
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def per_image_sum(values: np.ndarray, image_of_element: np.ndarray, n_images: int) -> np.ndarray:
    """(M, ...) sums of `values` (n, ...) over the elements of each image."""
    values = np.asarray(values, dtype=float)
    if len(image_of_element) and np.all(np.diff(image_of_element) >= 0):
        # Rows grouped by image (Model's layout): contiguous sums, much faster than np.add.at.
        starts = np.searchsorted(image_of_element, np.arange(n_images))
        present = np.bincount(image_of_element, minlength=n_images) > 0
        out = np.zeros((n_images,) + values.shape[1:])
        out[present] = np.add.reduceat(values, starts[present], axis=0)
        return out
    out = np.zeros((n_images,) + values.shape[1:])
    np.add.at(out, image_of_element, values)
    return out


def orthonormal_basis(J: np.ndarray, tolerance=1e-7) -> np.ndarray:
    """Orthonormal basis (n, rank) of the column space of J (n, p), p small.

    From the eigen-decomposition of the small Gram matrix of the column-normalised J, repeated once on the result
    (as CholeskyQR2) so the basis is orthonormal to rounding error; directions whose singular value is below
    `tolerance` times the largest are treated as absent (rank-revealing, like pivoted QR, and several times
    faster than LAPACK's QR on a tall matrix with few columns).
    """
    norms = np.linalg.norm(J, axis=0)
    if J.shape[1] == 0 or not np.any(norms > 0):
        return np.zeros((J.shape[0], 0))
    U = J[:, norms > 0] / norms[norms > 0]
    for threshold in (tolerance ** 2, 0.5):
        eigenvalues, V = np.linalg.eigh(U.T @ U)
        keep = eigenvalues > threshold * eigenvalues.max()
        U = U @ (V[:, keep] / np.sqrt(eigenvalues[keep]))
    return U


def project_off(Q: np.ndarray, A: np.ndarray) -> np.ndarray:
    """A minus its projection on the orthonormal columns Q."""
    return A - Q @ (Q.T @ A)


def stance_clusters(data) -> list[np.ndarray]:
    """Residual-coordinate indices (into the flattened (2 N,) residual) of each cluster of the significance tests.

    The 24 vertices of one image move together, and so do the images of one stance (leg, stance) taken at several
    head postures: the leg did not move between them, so its encoder quantisation, play and any unmodelled joint
    error are the same in all of them. A capture taken while the joints move (non-zero velocities, e.g. the
    agent's lag probe) joins its stance only if its leg readings are those of the stance; captures along a sweep
    each have their own angles and errors, and are clusters of their own.
    """
    element_cluster = np.repeat(stance_cluster_of_image(data)[data.image_of_row], 2)
    order = np.argsort(element_cluster, kind="stable")
    _, starts = np.unique(element_cluster[order], return_index=True)
    return np.split(order, starts[1:])


def row_ids(a: np.ndarray) -> np.ndarray:
    """(n,) np.unique(a, axis=0, return_inverse=True)[1] of an array (n, k) (integers, or finite floats): each row's
    rank among the distinct rows in lexicographic order; by np.lexsort, 5-10x faster than unique's sort of a
    structured view."""
    ids = np.zeros(len(a), dtype=np.int64)
    if len(a) == 0 or a.shape[1] == 0:
        return ids
    order = np.lexsort(a.T[::-1])  # the last key is the primary one
    rows = a[order]
    ids[order] = np.cumsum(np.r_[False, np.any(rows[1:] != rows[:-1], axis=1)])
    return ids


def stance_cluster_of_image(data) -> np.ndarray:
    """(M,) cluster number of each image, as `stance_clusters` explains: its stance, or itself along a sweep."""
    moving = np.zeros(data.n_images, bool) if data.velocity is None else np.any(data.velocity != 0, axis=1)
    # the stance's readings: every joint but the cameras' (a leg, for the NAO's sandals)
    on_cameras = {j for c in np.unique(data.camera) for j in data.robot.camera_chain(c).joint_names}
    body = [k for k, j in enumerate(data.joints) if j not in on_cameras]
    # Vectorised (a Python loop over the images took a tenth of a 100k-vertex solve): integer ids of the target,
    # the stance and the body's readings (to 1e-6 rad), combined into one key per image.
    _, target_id = np.unique(data.target, return_inverse=True)
    stance_values, stance_id = np.unique(np.asarray(data.stance), return_inverse=True)
    leg_id = row_ids(np.round(data.theta[:, body] * 1e6).astype(np.int64))
    target_id, stance_id, leg_id = (np.asarray(a, dtype=np.int64).reshape(-1) for a in (target_id, stance_id, leg_id))
    n_pairs = (int(target_id.max(initial=0)) + 1) * len(stance_values)
    pair = target_id * len(stance_values) + stance_id
    triple = pair * (int(leg_id.max(initial=0)) + 1) + leg_id
    alone = moving & ~np.isin(triple, triple[~moving])  # a sweep's image: its own cluster unless a still one shares it
    key = np.where(alone, n_pairs + triple, pair)
    return np.unique(key, return_inverse=True)[1].reshape(-1)


def image_clusters(data) -> list[np.ndarray]:
    """Residual-coordinate indices of each image: clusters for data whose stances share nothing."""
    element_image = np.repeat(data.image_of_row, 2)
    order = np.argsort(element_image, kind="stable")
    _, starts = np.unique(element_image[order], return_index=True)
    return np.split(order, starts[1:])


def effective_clusters(Z: np.ndarray, clusters: list) -> float:
    """How many clusters the block Z (n, q), orthonormal columns, really draws on: (sum w_c)^2 / sum w_c^2 with
    w_c = |Z_c|_F^2 its energy in cluster c (Satterthwaite). All G when it is spread evenly; 6 when it lives in 6
    images (a regressor seen only by a few moving captures): the clustered variance then rests on those few and
    the F reference must say so, or a handful of images yields p-values of 1e-11.
    """
    weights = np.array([float(np.sum(Z[rows] ** 2)) for rows in clusters])
    total = weights.sum()
    return float(total ** 2 / np.sum(weights ** 2)) if total > 0 else 0.0


@dataclass
class ScoreTest:
    """Score test of adding the columns of a (projected) Jacobian block to a fitted least-squares model.

    dof: rank of the block after projection. delta_rss: predicted drop of the residual sum of squares, px^2.
    step: (d,) predicted change of the block's parameters (in the units of the block's columns).
    statistic: Hotelling's T^2 of the cluster-robust test; p_value from F(dof, G - dof), G the effective number
    of clusters (`effective_clusters`).
    noise_rss: what the block would remove from pure noise on average, trace of the score's variance, px^2;
    delta_rss - noise_rss estimates, without bias, the drop it owes to a real effect.
    step_std: (d,) standard deviation of `step` from the same clustered variance (nan where not estimable).
    """

    dof: int
    delta_rss: float
    step: np.ndarray
    statistic: float
    p_value: float
    noise_rss: float = float("nan")
    step_std: np.ndarray | None = None


def _jackknife_scores(U, q, e, clusters):
    """(G, q) cluster scores Z_g^T (I - H_gg)^-1 e_g with U = [Q, Z] orthonormal, Z its last q columns.

    H is the hat matrix of the model plus the block. A cluster that pulls the fit towards itself shows a smaller
    residual than its error; dividing out its leverage (Woodbury: (I - U_g U_g^T)^-1 = I + U_g (I - U_g^T U_g)^-1
    U_g^T) undoes that: the leave-one-cluster-out (jackknife, "CR3") variance. Without it, tests of the 12-parameter
    candidates reject 2-3 times too often.
    """
    k = U.shape[1]
    C, a = np.empty((len(clusters), k, k)), np.empty((len(clusters), k))
    for g, rows in enumerate(clusters):
        Ug = U[rows]
        C[g], a[g] = Ug.T @ Ug, Ug.T @ e[rows]
    A = np.eye(k) - C
    try:
        x = np.linalg.solve(A, a[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a cluster that alone determines a direction: no variance estimate there
        x = np.stack([np.linalg.lstsq(Ag, ag, rcond=1e-12)[0] for Ag, ag in zip(A, a)])
    return a[:, -q:] + np.einsum("gij,gj->gi", C[:, -q:], x)


def score_test(J_tilde: np.ndarray, r: np.ndarray, clusters: list, Q: np.ndarray | None = None) -> ScoreTest:
    """Score test for the block `J_tilde` (n, d), already projected off the fitted model's Jacobian.

    With Z an orthonormal basis of the block, the score is g = Z^T r and the predicted drop of the residual sum
    of squares is |g|^2. Residuals are correlated within a cluster (the 24 vertices of an image, the images of a
    stance) and independent between clusters, so the variance of g is the clustered sandwich V = sum_c h_c h_c^T,
    h_c = Z_c^T e_c the score of cluster c, computed with e = r - Z g, the residual after adding the block (a
    strong real effect then does not inflate its own noise estimate), leverage-corrected when Q (the fitted
    model's orthonormal basis) is given. T^2 = (G - 1) / G g^T V^-1 g and (G - d) / (d (G - 1)) T^2 ~ F(d, G - d)
    when the effect is absent (the Hotelling form of the cluster-robust Wald test, G the effective number of
    clusters).

    Parameters
    ----------
    J_tilde : (n, d) block, n = 2 N flattened residual coordinates.
    r : (n,) residuals of the fitted model, px.
    clusters : index arrays into the n residual coordinates, one per cluster (`stance_clusters`).
    Q : (n, p) orthonormal basis of the fitted model's Jacobian, for the leverage correction.
    """
    d = J_tilde.shape[1]
    if d == 0:
        return ScoreTest(0, 0.0, np.zeros(0), 0.0, 1.0)
    norms = np.linalg.norm(J_tilde, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    Jn = J_tilde / scale
    eigenvalues, E = np.linalg.eigh(Jn.T @ Jn)
    keep = eigenvalues > RANK_TOLERANCE * max(eigenvalues.max(), 1e-300)
    if not np.any(keep):
        return ScoreTest(0, 0.0, np.zeros(d), 0.0, 1.0)
    to_z = E[:, keep] / np.sqrt(eigenvalues[keep])  # column-scaled block coordinates -> orthonormal Z coordinates
    Z = Jn @ to_z
    g = Z.T @ r
    step = -(to_z @ g) / scale  # least-squares change of the block's parameters
    q = Z.shape[1]
    G = min(len(clusters), effective_clusters(Z, clusters))
    if G <= q + 1:
        return ScoreTest(q, float(g @ g), step, float("nan"), float("nan"))
    e = r - Z @ g
    if Q is None:
        h = np.stack([Z[rows].T @ e[rows] for rows in clusters])
    else:
        h = _jackknife_scores(np.hstack([Q, Z]), q, e, clusters)
    V = G / (G - 1) * (h.T @ h)  # variance of the score g
    t2 = float(g @ np.linalg.lstsq(V, g, rcond=1e-12)[0])
    f_value = (G - q) / (q * (G - 1)) * t2
    to_step = to_z / scale[:, None]  # step = -to_step @ g
    step_std = np.sqrt(np.maximum(np.einsum("iq,qr,ir->i", to_step, V, to_step), 0.0))
    return ScoreTest(q, float(g @ g), step, t2, float(fdtrc(q, G - q, f_value)), float(np.trace(V)), step_std)
