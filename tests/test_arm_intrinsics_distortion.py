"""An arm camera's whole plumb_bob distortion refined with the arm (issue 24: a real robot's cameras need more of
the lens than k1): k2, p1, p2 off the filed ones are recovered from a small synthetic camera dataset."""

import numpy as np

from naocal.kinds.arm.identify import fit, initialise_sensors
from naocal.kinds.arm.scenarios import CAMERA, true_errors
from naocal.solver.effects.intrinsics import ARM_PRIOR
from tests.test_arm import synthetic

EFFECTS = ("joint_offsets", "link_lengths", "points", "intrinsics")
# The camera's true lens off what dataset.json files, about 2 plausible sizes each (ARM_PRIOR: k2 0.005, p 0.0005)
LENS = {"intrinsics.camera.k2": -0.01, "intrinsics.camera.p1": 0.001, "intrinsics.camera.p2": -0.0008}


def radial_px(values, r):
    """f (k1 r^3 + k2 r^5 + k3 r^7): how far the radial corrections move a point at radius r off its filed place."""
    k1, k2, k3 = (values.get(f"intrinsics.camera.{k}", 0.0) for k in ("k1", "k2", "k3"))
    return CAMERA["fx_px"] * r ** 3 * (k1 + r ** 2 * (k2 + r ** 2 * k3))


def test_a_camera_s_k2_p1_p2_off_the_filed_ones_are_recovered_with_the_arm():
    """The camera's markers fill its image (r up to 0.55), 40 stances, 0.05 px: the tangential p1, p2 are found
    within 3.5 stds, a third of their prior's; of the radial terms the data tell their sum (the image's radial
    displacement, to a tenth of the truth's 0.7 px at the corner) and each term within 3.5 stds, the priors
    splitting k1, k2, k3 (their std: about the prior's)."""
    model, obs, _, _ = synthetic(EFFECTS, dict(true_errors(), **LENS), n_poses=40, seed=7, noise_px=0.05)
    x0 = initialise_sensors(model, obs)
    result = fit(model, obs, x0, robust=False)
    assert result.rms()["camera"] < 0.05  # px, its noise
    found = dict(zip(model.names, result.x))
    std = dict(zip(model.names, result.std))
    for name in ("intrinsics.camera.k1", "intrinsics.camera.k2", "intrinsics.camera.k3", *LENS):
        assert abs(found[name] - LENS.get(name, 0.0)) < 3.5 * std[name], (name, found[name], std[name])
    for name in ("intrinsics.camera.p1", "intrinsics.camera.p2"):  # the data's, not the prior's
        assert std[name] < ARM_PRIOR[name[-2:]] / 3, (name, std[name])
    r = np.linspace(0.0, 0.55, 12)
    assert np.abs(radial_px(found, r) - radial_px(LENS, r)).max() < 0.1  # px; the truth's reaches 0.7 px
