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


# Readings often arrive as float32 (LoLA sends float32 radians): each is off its grid by up to half a float32 ulp,
# 6e-8 of its size, and Euclid's remainders multiply that by the number of steps a gap spans. So the step is found
# in two passes: a coarse GCD tolerant to COARSE_TOLERANCE_RAD, then a least-squares step over every gap, accepted
# only if every gap is a whole number of steps to the readings' own precision.
COARSE_TOLERANCE_RAD = 2e-5
FLOAT32_RELATIVE = 2.0 ** -23  # two half-ulps: the worst rounding of a difference of two float32 readings


def _grid_step(gaps: np.ndarray, tolerance: float, smallest: float) -> float:
    """The step every gap is a whole multiple of, to `tolerance` (0.0 if none of at least `smallest`)."""
    coarse = _float_gcd(gaps, COARSE_TOLERANCE_RAD)
    if coarse < smallest:
        return 0.0
    n = np.round(gaps / coarse)
    step = float(n @ gaps / (n @ n))
    return step if np.all(np.abs(gaps - n * step) <= tolerance) else 0.0


def reading_resolution(theta: np.ndarray, use: np.ndarray | None = None, *, tolerance_rad: float = 1e-7,
                       smallest_rad: float = 1e-4, min_values: int = 8) -> np.ndarray:
    """(J,) quantisation step of each joint's readings in rad (0: not quantised, or not known).

    theta : (M, J) readings; use : optional (M, J) bool, the readings to look at (e.g. those of still joints:
    readings taken while moving may be interpolated).
    Encoders report multiples of their resolution (the NAO: 2 pi / 4096, about 0.088 deg; the mock 0.1 deg): the
    step is the greatest common divisor of the differences between distinct readings, found on the joints with at
    least `min_values` distinct readings (fewer could share a larger divisor by chance: a joint visited at 0 and
    +-0.3 deg only would claim 0.3 deg) and shared by all joints (one kind of encoder: the median of those); a
    joint with fewer readings is taken to have that step if its readings lie on the grid. A difference may be off
    a whole number of steps by `tolerance_rad` plus the rounding of float32 readings.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    tolerance = tolerance_rad + FLOAT32_RELATIVE * float(np.max(np.abs(theta), initial=0.0))
    diffs = []
    for j, column in enumerate(theta.T):
        values = column if use is None else column[np.asarray(use)[:, j]]
        d = np.diff(np.unique(values))
        diffs.append(d[d > tolerance])
    steps = [_grid_step(d, tolerance, smallest_rad) for d in diffs if len(d) + 1 >= min_values]
    steps = [x for x in steps if x >= smallest_rad]
    out = np.zeros(theta.shape[1])
    if not steps:
        return out
    step = float(np.median(steps))
    for j, d in enumerate(diffs):
        if len(d) == 0 or np.all(np.abs(d - np.round(d / step) * step) <= 10 * tolerance):
            out[j] = step
    return out
