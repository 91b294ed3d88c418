"""Grouped cross-validation: fit on some stances, predict the stances the fit did not see.

A model that only explains the noise of the data it was fitted to (too many parameters) predicts unseen stances
worse; one that captures a real effect predicts them better. Whole stances (target, stance) are held out, with all
their head postures, because images of one stance share its joint errors: holding out single images would let
the fit see the held-out stance through its siblings.
"""

from __future__ import annotations

import numpy as np

from naocal.solver.errors import NaocalError, SolveError
from naocal.solver.identify import identify
from naocal.solver.model import Model, ModelData
from naocal.solver.registry import Registry


def stance_folds(data: ModelData, n_folds: int = 5, seed: int = 0) -> list[np.ndarray]:
    """Image indices (into `data`) of each fold; every stance (target, stance) lies in exactly one fold.

    Stances are shuffled with `seed` and dealt round-robin per target, so every fold holds stances of every target
    (the NAO: of both legs).
    With fewer stances than folds, every stance is its own fold (leave-one-stance-out).
    """
    keys = [(str(t), int(s)) for t, s in zip(data.target, data.stance)]
    groups = list(dict.fromkeys(keys))
    if len(groups) < 2:
        raise NaocalError("cross-validation needs at least two stances")
    n_folds = min(int(n_folds), len(groups))
    if n_folds < 2:
        raise NaocalError("cross-validation needs at least two folds")
    rng = np.random.default_rng(seed)
    fold_of_group, position = {}, 0
    for target in sorted({g[0] for g in groups}):
        target_groups = [g for g in groups if g[0] == target]
        for k in rng.permutation(len(target_groups)):
            fold_of_group[target_groups[k]] = position % n_folds
            position += 1
    fold = np.array([fold_of_group[k] for k in keys])
    return [np.flatnonzero(fold == f) for f in range(n_folds)]


def grouped_cv_residuals(data: ModelData, registry: Registry, n_folds: int = 5,
                         seed: int = 0) -> tuple[ModelData, np.ndarray]:
    """Held-out residuals: every stance predicted by the model fitted to the other folds.

    Returns (data sorted by target, residuals (N, 2) px in that data's row order).
    """
    data = data.sorted_by_target(registry.setup.targets)
    residuals = np.full((data.n_rows, 2), np.nan)
    for k, held_out in enumerate(stance_folds(data, n_folds, seed)):
        train = np.setdiff1d(np.arange(data.n_images), held_out)
        try:
            fit = identify(data.subset(train), registry)
        except SolveError as err:
            raise SolveError(f"cross-validation fold {k + 1}: {err}") from None
        if not fit.success:
            raise SolveError(f"cross-validation fold {k + 1}: the solve did not converge ({fit.message})")
        test = data.subset(held_out)
        predicted = Model(test, fit.registry)
        rows = data.rows_of_images(held_out)  # the same rows, in the same order, as `predicted.data`
        residuals[rows] = predicted.residuals(fit.values)
    return data, residuals


def grouped_cv_rms(data: ModelData, registry: Registry, n_folds: int = 5, seed: int = 0) -> tuple[float, float]:
    """RMS (x, y) in px of the held-out residuals of `grouped_cv_residuals`."""
    _, residuals = grouped_cv_residuals(data, registry, n_folds, seed)
    rms = np.sqrt(np.mean(residuals ** 2, axis=0))
    return float(rms[0]), float(rms[1])
