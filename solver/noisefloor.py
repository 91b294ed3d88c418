"""The noise floor: what a correct model leaves of the residuals.

Detector noise (stated by the dataset, or estimated from what no rigid board motion and no camera term can
explain) combined with the error of quantised joint readings, which moves whole boards and so hides from the
non-rigid estimate. `RigidSplit` also serves the diagnostics' rigid / non-rigid view of every image.
"""

from __future__ import annotations

import math

import numpy as np

from naocal.solver.effects import EFFECTS
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.quantisation import reading_resolution  # noqa: F401 (its home is solver.quantisation)
from naocal.solver.scoretest import orthonormal_basis, project_off


class RigidSplit:
    """Splits every image's residual into the best rigid motion of its board and a non-rigid remainder.

    The rigid part is the least-squares projection of the image's residual on the six columns of its
    board-twist Jacobian (Model.board_twist_jacobian) at the fitted values; the rest is non-rigid.
    """

    def __init__(self, model: Model, values, fitted=None):
        """fitted : (N,) bool, the rows each image's motion is fitted to (default all); the others are split by
        that motion (a corner set aside, judged by the board motion its kept neighbours show)."""
        data = model.data
        L = model.board_twist_jacobian(values)
        starts = np.searchsorted(data.image_of_row, np.arange(data.n_images + 1))
        self.slices = [slice(a, b) for a, b in zip(starts[:-1], starts[1:])]
        self.fitted = [np.arange(s.start, s.stop) if fitted is None else np.flatnonzero(fitted[s]) + s.start
                       for s in self.slices]
        self.twist_columns = L  # (N, 2, 6)
        self._pinv = []
        for rows in self.fitted:
            A = L[rows].reshape(-1, 6)
            scale = np.linalg.norm(A, axis=0)
            scale[scale == 0] = 1.0  # translations (m) and rotations (rad) differ by orders of magnitude
            self._pinv.append(np.linalg.pinv(A / scale, rcond=1e-10) / scale[:, None])

    def twists(self, residuals) -> np.ndarray:
        """(M, 6) best rigid board twist (v in m, w in rad, camera frame) explaining each image's residual."""
        return np.stack([P @ residuals[rows].reshape(-1) for P, rows in zip(self._pinv, self.fitted)])

    def __call__(self, residuals) -> tuple[np.ndarray, np.ndarray]:
        """(rigid, nonrigid), both (N, 2) px, from residuals (N, 2)."""
        rigid = np.empty_like(residuals)
        for P, rows, fitted in zip(self._pinv, self.slices, self.fitted):
            rigid[rows] = (self.twist_columns[rows].reshape(-1, 6) @ (P @ residuals[fitted].reshape(-1))).reshape(-1, 2)
        return rigid, residuals - rigid


def noise_floor_estimate(model: Model, values, residuals, n_nonrigid_parameters: int = 0,
                         split: RigidSplit | None = None) -> float:
    """Detector noise estimated from the residuals: what no rigid board motion and no camera term can explain.

    Every kinematic error (offsets, play, elasticity, link lengths, head offsets, time lag) moves each board
    rigidly, so removing each image's best rigid 6-DOF motion leaves detector noise plus intrinsics and
    distortion errors; those are removed too (fx, fy, cx, cy, k1, k2 fitted to the remainder). Then
    s = sqrt(RSS_rest / (n - 6 M - 6 - n_nonrigid_parameters)), n the number of residual coordinates.
    Without the camera step this is the plain s = sqrt(RSS_nonrigid / (n - 6 M)) of the method notes; the
    camera step keeps a wrong focal length or distortion from passing for noise.
    """
    data = model.data
    split = split or RigidSplit(model, values)
    nonrigid = split(residuals)[1]
    non_rigid = tuple(name for name, e in EFFECTS.items() if e.non_rigid)
    camera = Registry(tuple(dict.fromkeys(model.registry.effects + non_rigid)), setup=model.registry.setup)
    J = Model(data, camera).evaluate(camera.from_dict(model.registry.as_dict(values)))[1]
    columns = [split(J[:, :, camera.index[p.name]])[1].reshape(-1)
               for p in camera.parameters if EFFECTS[p.effect].non_rigid]
    Q = orthonormal_basis(np.stack(columns, axis=1))
    rest = project_off(Q, nonrigid.reshape(-1))
    counts = np.bincount(data.image_of_row, minlength=data.n_images)
    dof = int(np.sum(np.maximum(2 * counts - 6, 0))) - Q.shape[1] - n_nonrigid_parameters
    return float(np.sqrt(rest @ rest / dof)) if dof > 0 else float("nan")


def encoder_noise_px(model: Model, values, resolution_rad) -> np.ndarray:
    """(x, y) RMS pixel error that joint readings quantised to `resolution_rad` ((J,) or one step) cause.

    Quantisation leaves each reading off by a uniform error of standard deviation resolution / sqrt(12),
    independent between joints; it moves the board by d r / d theta_j per joint (the joint-offset columns).
    """
    data = model.data
    resolution = np.broadcast_to(np.asarray(resolution_rad, dtype=float), (len(data.joints),))
    if not np.any(resolution > 0):
        return np.zeros(2)
    # Only the full Jacobian is needed: ties and fixed parameters do not matter here.
    offsets = tuple(name for name, e in EFFECTS.items() if e.reading_offsets)
    registry = Registry(tuple(dict.fromkeys(model.registry.effects + offsets)), setup=model.registry.setup)
    J = Model(data, registry).evaluate(registry.from_dict(model.registry.as_dict(values)))[1]
    variance = np.zeros(2)
    for p in registry.parameters:
        if EFFECTS[p.effect].reading_offsets:
            sigma = resolution[data.column(p.joint)] / math.sqrt(12.0)
            variance += sigma ** 2 * np.mean(J[:, :, registry.index[p.name]] ** 2, axis=0)
    return np.sqrt(variance)
