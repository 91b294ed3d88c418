"""Quantised joint readings: the step a joint's encoder reports in, found in the data.

One function answers it for everything that needs it (the choice of angles in solver.adapter, the noise floor in
solver.noisefloor): `reading_resolution`.
"""

from __future__ import annotations

import math

import numpy as np


def _float_gcd(values, tolerance: float) -> float:
    """Greatest common divisor of positive floats, to `tolerance` (Euclid with a tolerant remainder)."""
    step = min(values)
    for d in values:
        a, b = max(d, step), min(d, step)
        while b > tolerance:
            a, b = b, math.fmod(a, b)
            if abs(b - a) < tolerance:  # a remainder next to the divisor: it divides
                b = 0.0
        step = a
    return float(step)


def reading_resolution(theta: np.ndarray, use: np.ndarray | None = None, *, tolerance_rad: float = 1e-7,
                       smallest_rad: float = 1e-5, min_values: int = 8) -> np.ndarray:
    """(J,) quantisation step of each joint's readings in rad (0: not quantised, or not known).

    theta : (M, J) readings; use : optional (M, J) bool, the readings to look at (e.g. those of still joints:
    readings taken while moving may be interpolated).
    Encoders report multiples of their resolution (the mock and the NAO: about 0.1 deg): the step is the greatest
    common divisor of the differences between distinct readings, found on the joints with at least `min_values`
    distinct readings (fewer could share a larger divisor by chance: a joint visited at 0 and +-0.3 deg only would
    claim 0.3 deg) and shared by all joints (one kind of encoder: the median of those); a joint with fewer readings
    is taken to have that step if its readings lie on the grid.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    diffs = []
    for j, column in enumerate(theta.T):
        values = column if use is None else column[np.asarray(use)[:, j]]
        d = np.diff(np.unique(values))
        diffs.append(d[d > tolerance_rad])
    steps = [_float_gcd(d, tolerance_rad) for d in diffs if len(d) + 1 >= min_values]
    steps = [x for x in steps if x >= smallest_rad]
    out = np.zeros(theta.shape[1])
    if not steps:
        return out
    step = float(np.median(steps))
    for j, d in enumerate(diffs):
        ratio = d / step
        if len(d) == 0 or np.all(np.abs(ratio - np.round(ratio)) < tolerance_rad / step * 10):
            out[j] = step
    return out
