"""The diagnose -> add -> diagnose loop with naocal's defaults on data naocal did not write (tests/loop_cases.py,
an independent generator: its own kinematics, gravity torques, camera, encoder and dataset writer)."""

import math

import numpy as np
import pytest

from solver.quantisation import reading_resolution

STEP_RAD = 2 * math.pi / 4096


def test_the_encoder_step_is_found_in_float32_readings():
    """LoLA sends float32 radians: each reading is off the 12-bit grid by up to half a float32 ulp, and gaps of
    many steps multiply that in Euclid's remainders (the exact GCD found the step in 16 of 200 such tables)."""
    rng = np.random.default_rng(0)
    for _ in range(50):
        theta = (np.round(rng.uniform(-2, 2, (96, 14)) / STEP_RAD) * STEP_RAD).astype(np.float32).astype(float)
        np.testing.assert_allclose(reading_resolution(theta), STEP_RAD, rtol=1e-6)
        unquantised = rng.uniform(-2, 2, (96, 14))
        assert not np.any(reading_resolution(unquantised))
        assert not np.any(reading_resolution(unquantised.astype(np.float32).astype(float)))
