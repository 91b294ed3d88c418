"""diagnose on cameras whose filed intrinsics are off (issue 24, `naocal simulate --robot dualarm --camera-error`):
once the model refines the intrinsics, a camera judging an arm fitted from the other sensors is judged with its own
intrinsics refitted from its data (as verify --refit intrinsics does), not at the filed ones it was found off; and
a candidate's own parameters are never refitted for the judged sensor only (the comparison without it would lack
that freedom)."""

import numpy as np
import pytest

from naocal.kinds.arm.diagnose import Test as Candidate, physical_checks
from naocal.kinds.arm.identify import fit, initialise_sensors


@pytest.fixture(scope="module")
def camera_error():
    """The dual-arm robot, its cameras' true intrinsics off the filed ones by a checkerboard's error (60 poses, no
    outliers)."""
    from naocal.kinds.arm.sim import CAMERA_FILING_ERROR, simulate_dualarm

    return simulate_dualarm(None, seed=1, n_poses=60, outlier_fraction=0.0, camera_error=dict(CAMERA_FILING_ERROR),
                            write=False)


def judged(sim, effects, label, cameras_only=False):
    from naocal.kinds.arm.sim import dualarm_model

    obs = sim["observations"]
    if cameras_only:
        obs = obs.subset(obs.sensor < 2)
    model = dualarm_model(effects, sensors=sim["sensors"][:2] if cameras_only else sim["sensors"])
    fitted = fit(model, obs, initialise_sensors(model, obs))
    candidate = Candidate(label, 1, 0.0, 0.0, 1.0, fitted.rms(), {}, significant=True)
    physical_checks(fitted, [candidate], sessions=0)
    return fitted, candidate


def test_the_loop_s_two_rounds_judge_the_cameras_with_their_own_intrinsics(camera_error):
    """Round 1, the model without intrinsics: the candidate intrinsics, fitted from the cameras, makes the tracker
    better; where the cameras judge (the arm fitted from the tracker alone) their intrinsics stay as filed with and
    without it, so that it gains nothing there by its own freedom. Round 2, the intrinsics in the model: each
    camera left out is judged with its own intrinsics refitted (main held them at the filed ones it was found off:
    its RMS was its own camera error, about 1 px against 0.3 px of noise, with and without any candidate)."""
    fitted, candidate = judged(camera_error, ("joint_offsets", "link_lengths", "tool", "points"), "intrinsics")
    by_kind = {c.kind: c for c in candidate.checks}
    tracker = by_kind["sensor"]
    assert tracker.with_effect["tracker"] < 0.5 * tracker.without["tracker"] and candidate.physical
    reverse = by_kind["reverse"]  # the arm from the tracker alone: the intrinsics change nothing of it
    for name in reverse.without:
        assert reverse.with_effect[name] == pytest.approx(reverse.without[name], rel=0.02), name

    fitted, candidate = judged(camera_error, ("joint_offsets", "link_lengths", "tool", "points", "intrinsics"),
                               "elasticity", cameras_only=True)
    assert max(fitted.rms().values()) < 1.2 * 0.3  # the intrinsics in the model: the pixels at their noise
    cameras = [c for c in candidate.checks if c.kind == "camera"]
    assert len(cameras) == 2 and all("its frame and intrinsics refitted" in c.how for c in cameras)
    for check in cameras:
        for name, rms in check.without.items():
            assert rms < 1.5 * 0.3, (name, rms)
