"""Do the Duckiebot joint fit's stds cover the truth? The realistic mock's missions (bench_duckiebot_mock.py's cache,
NAOCAL_BENCH_CACHE: each run's `log/`), refitted as the mission fits them (kinds.duckiebot.identify: detection, the
lens fit, the joint fit with the mission's wheel effects and Duckietown's PWM driver), each parameter's signed
z = (estimate - truth) / std against the mock's hidden truth (mock.truth_document), for two stds:
- "without": the cluster-robust std with the lens's covariance carried in (add_lens_covariance), the detector's
  size-dependent corner error not considered;
- "with": plus that error as a considered nuisance (identify.add_corner_covariance, CORNER_WINDOW_STD_PX2).
The estimates are the same for both (a considered nuisance moves only the covariance). Printed per seed: z without
-> with for gain, trim, baseline, dead zone and the camera's pose, the trim's std and its parts (statistical, lens,
corner error); then over all values the RMS z and the largest |z|. Reads the cache, writes nothing.

Run: `NAOCAL_BENCH_CACHE=DIR python benchmarks/bench_duckiebot_stds.py [--seeds 1 2 3 4 5]`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_duckiebot_mock import cache_dir  # noqa: E402
from naocal.kinds.duckiebot.drive_log import read_drive_log  # noqa: E402
from naocal.kinds.duckiebot.fit import CORNER_WINDOW, LENS, PWM_DRIVER, STATISTICAL  # noqa: E402
from naocal.kinds.duckiebot.identify import calibrate, detect_log, fit_intrinsics  # noqa: E402
from naocal.kinds.duckiebot.mission import FIT_EFFECTS  # noqa: E402
from naocal.kinds.duckiebot.mock import DuckiebotMock, truth_document  # noqa: E402

SHOWN = ("gain", "trim", "baseline_m", "dead_zone", "camera.x_m", "camera.y_m", "camera.z_m", "camera.roll_rad",
         "camera.pitch_rad", "camera.yaw_rad")


def refit(seed: int, realism: str = "realistic"):
    """(the joint fit of the cached mission `seed`'s log, its truth {name: value}, CPU s of the lens and joint fit)."""
    log = read_drive_log(cache_dir() / f"{realism}_seed{seed}" / "log")
    detections = detect_log(log)
    cpu = time.process_time()
    lens, fits = fit_intrinsics(log, detections)
    cal = calibrate(log, detections, lens, fits, effects=FIT_EFFECTS + (PWM_DRIVER,))
    cpu = time.process_time() - cpu
    robot = DuckiebotMock(seed, realism)
    try:
        truth = truth_document(robot.truth, seed, realism)["parameters"]
    finally:
        robot.close()
    return cal.drive_fit, {n: v["value"] for n, v in truth.items()}, cpu


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    print("| seed | z without -> with the corner error considered: " + ", ".join(SHOWN) +
          " | trim std without -> with (statistical, lens, corner error) | largest z with | CPU s |")
    print("|---|---|---|---|---|")
    every = {"without": [], "with": []}
    for seed in args.seeds:
        fit, truth, cpu = refit(seed)
        parts = fit.std_parts()
        without = np.sqrt(fit.std ** 2 - parts[CORNER_WINDOW] ** 2)
        z = {}
        for n in SHOWN:
            i = fit.names.index(n)
            error = fit.x[i] - truth[n]
            z[n] = (error / without[i], error / fit.std[i])
            every["without"].append(z[n][0])
            every["with"].append(z[n][1])
        t = fit.names.index("trim")
        worst = max(SHOWN, key=lambda n: abs(z[n][1]))
        print(f"| {seed} | " + ", ".join(f"{n} {a:+.1f} -> {b:+.1f}" for n, (a, b) in z.items()) +
              f" | {without[t]:.5f} -> {fit.std[t]:.5f} ({parts[STATISTICAL][t]:.5f}, {parts[LENS][t]:.5f}, "
              f"{parts[CORNER_WINDOW][t]:.5f}) | {abs(z[worst][1]):.2f} ({worst}) | {cpu:.0f} |", flush=True)
        print("|  | std ratio with / without: " + ", ".join(
            f"{n} {fit.std[fit.names.index(n)] / without[fit.names.index(n)]:.2f}" for n in SHOWN) + " | | | |")
    for name, values in every.items():
        values = np.abs(values)
        print(f"{name} the corner error considered: RMS z {np.sqrt(np.mean(values ** 2)):.2f}, largest |z| "
              f"{values.max():.2f}, |z| > 3: {int(np.sum(values > 3))} of {len(values)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
