"""Where the dual-arm cameras' residual comes from: the simulated robot (kinds/arm/sim.py, simulate_dualarm) with each
of its errors switched off in turn, fitted from the cameras alone, and each fit's camera RMS against the noise.

A fit at the simulation's noise leaves a residual RMS per axis of noise * sqrt((n - p) / n) (n residual components,
p free parameters: what the fit absorbs of the noise), unless the simulation does something the fit does not
model. Two fits per row: "fitted effects" as tests/test_arm_dual.py's filing-error test fitted them before
(joint_offsets, tool, points, intrinsics: no link lengths, no print scale) and "every hidden effect" (those and
link_lengths, marker_scale). Each fit is also made on the same robot measured without noise and outliers (its
sensors still stated at the noise): what is left there is the model's misfit alone, ~0 when the fit models every
error the robot has (the two projections, the markers' gluing and print, PyBullet's kinematics against naocal's).

The rows: "all": the simulation as tests/test_arm_dual.py runs it (the cameras filed off their true intrinsics by
CAMERA_FILING_ERROR, each sheet printed 1 + N(0, 0.3 %), joint offsets, link lengths, tool mounts, markers glued
off, 2 % outlier corners); then each of those made exact in turn (simulate_dualarm's `hidden`, camera_error,
print_scale_error, outlier_fraction; the other draws stay the seed's). Outliers are set aside by the fit's robust
rounds (identify.fit); "set aside" counts them against the corners the simulation drew wrong (its `mistaken`).

    python benchmarks/bench_dual_arm_residual.py [--seeds 5] [--poses 60] [--noise-px 0.1]
"""

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # as bench_dual_arm.py
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.arm.identify import fit, initialise_sensors  # noqa: E402
from naocal.kinds.arm.sim import CAMERA_FILING_ERROR, DUAL_HIDDEN, PRINT_SCALE_ERROR, dualarm_model, \
    simulate_dualarm  # noqa: E402

FITS = {"fitted effects": ("joint_offsets", "tool", "points", "intrinsics"),
        "every hidden effect": ("joint_offsets", "link_lengths", "tool", "points", "marker_scale", "intrinsics")}
OUTLIERS = 0.02


def cases():
    """(label, simulate_dualarm keyword arguments): everything, then each error made exact in turn."""
    every = {"hidden": DUAL_HIDDEN, "camera_error": CAMERA_FILING_ERROR, "print_scale_error": PRINT_SCALE_ERROR,
             "outlier_fraction": OUTLIERS}
    yield "all", every
    yield "no outliers", dict(every, outlier_fraction=0.0)
    yield "lens exact (filed = true)", dict(every, camera_error=None)
    yield "printed exactly", dict(every, print_scale_error=0.0)
    for effect, words in (("points", "markers glued exactly"), ("tool", "tool mounts exact"),
                          ("link_lengths", "link lengths exact"), ("joint_offsets", "joint offsets exact")):
        yield words, dict(every, hidden=tuple(h for h in DUAL_HIDDEN if h != effect))


def camera_fit(sim, effects, noise_px):
    """(camera RMS per axis, its expected value noise * sqrt((n - p) / n), detections set aside, corners drawn
    wrong (the simulation's truth))."""
    cameras = [replace(s, noise=noise_px) for s in sim["sensors"] if s.kind == "camera"]
    rows = np.flatnonzero(sim["observations"].sensor < len(cameras))
    obs = sim["observations"].subset(rows)
    model = dualarm_model(effects, sensors=cameras)
    result = fit(model, obs, initialise_sensors(model, obs))
    n = int(model.component_mask(result.obs).sum())
    p = int(result.free.sum())
    return max(result.rms().values()), noise_px * np.sqrt((n - p) / n), len(result.outliers), \
        int(sim["mistaken"][rows].sum())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[5])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--noise-px", type=float, default=0.1)
    args = parser.parse_args(argv)
    print(f"dual-arm cameras' RMS per axis (px), {args.poses} stances, noise {args.noise_px} px per axis; "
          f"'no noise': the same robot measured without noise and outliers (the model's misfit alone)")
    print(f"{'seed':>4s} {'simulation':>26s} {'fit':>20s} {'RMS':>7s} {'expected':>8s} {'no noise':>8s} "
          f"{'set aside':>13s} {'CPU s':>6s}")
    for seed in args.seeds:
        for label, kwargs in cases():
            cpu = time.process_time()
            sims = [simulate_dualarm(None, seed=seed, n_poses=args.poses, noise_m=1e-5, noise_px=noise, write=False,
                                     **dict(kwargs, outlier_fraction=fraction))
                    for noise, fraction in ((args.noise_px, kwargs["outlier_fraction"]), (1e-9, 0.0))]
            for name, effects in FITS.items():
                rms, expected, aside, wrong = camera_fit(sims[0], effects, args.noise_px)
                misfit = camera_fit(sims[1], effects, args.noise_px)[0]
                drawn = f"{aside} / {wrong}"
                print(f"{seed:4d} {label:>26s} {name:>20s} {rms:7.4f} {expected:8.4f} {misfit:8.4f} {drawn:>13s} "
                      f"{time.process_time() - cpu:6.1f}", flush=True)
                cpu = time.process_time()
    return 0


if __name__ == "__main__":
    sys.exit(main())
