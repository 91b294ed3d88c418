"""The arm's priors on the near-flat directions of issue 24 (kinds/arm/scenarios.py, on the panda; tests/test_arm_priors.py runs them too):
(a) a joint offset against a turn of the marker body (per-marker points, a camera, the last joint barely turning),
(b) link lengths from poses that barely move the wrist, (c) a tracker's one reflector with a free position, the
wrist barely moving; 8 seeds each (other errors, poses and noise).

Per scenario: with the priors (the default), how many fits converge to plausible values (kinds.arm.identify.ran_off
finds nothing) and the largest |z| = (identified - true) / std over every free physical parameter (do the
posterior stds cover the truth, prior-held ones included?), and the largest error in plausible sizes; without
(--no-priors), how many stop with the run-off message and the largest value in plausible sizes. The truth is taken
in the fit's gauges (`gauge_truth`: the first joint's offset and the base's height, which the sensor frames absorb,
held at 0; docs/ARM.md, identifiability).

    python benchmarks/bench_arm_priors.py [--seeds 8]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.arm.identify import fit, initialise_sensors, prior_sizes, ran_off  # noqa: E402
from naocal.kinds.arm.scenarios import scenario  # noqa: E402  (the scenarios' one home, shared with the tests)

CASES = {"a": "joint offset vs marker-body turn (camera, points)", "b": "link lengths, wrist barely moving (tracker)",
         "c": "free reflector, wrist barely moving (tracker)"}


def gauge_truth(case, seed, model, truth, fitted):
    """The truth as the fit's gauges see it: the noise-free data fitted (no priors) from the truth with the gauges
    `fitted` fixed held where the fit holds them (0)."""
    _, clean, _, _ = scenario(case, seed, noise=False)
    gauges = tuple(fitted.fixed_reasons)
    x0 = initialise_sensors(model, clean, start={n: v for n, v in truth.items() if n in model.names and n not in gauges})
    return fit(model, clean, x0, fixed=gauges, auto_fix=False, robust=False, priors=False).x


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args(argv)
    print("| scenario | priors: plausible | max abs z | max abs error / plausible size | no priors: stopped | "
          "max abs value / plausible size | CPU s per fit |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    worst = 0.0
    for case, label in CASES.items():
        plausible = stopped = 0
        z_max = error_max = runaway = 0.0
        cpu = []
        for seed in range(args.seeds):
            model, obs, truth, _ = scenario(case, seed)
            size = prior_sizes(model)
            start = time.process_time()
            with_priors = fit(model, obs, initialise_sensors(model, obs))
            cpu.append(time.process_time() - start)
            true = gauge_truth(case, seed, model, truth, with_priors)
            plausible += with_priors.success and ran_off(with_priors) is None
            judged = with_priors.free & (size > 0)
            z = (with_priors.x - true)[judged] / with_priors.std[judged]
            z_max = max(z_max, float(np.max(np.abs(z))))
            error_max = max(error_max, float(np.max(np.abs(with_priors.x - true)[judged] / size[judged])))
            alone = fit(model, obs, initialise_sensors(model, obs), priors=False)
            stopped += ran_off(alone) is not None
            free = alone.free & (size > 0)
            runaway = max(runaway, float(np.max(np.abs(alone.x[free]) / size[free])))
        worst = max(worst, z_max)
        print(f"| ({case}) {label} | {plausible}/{args.seeds} | {z_max:.2f} | {error_max:.2f} | "
              f"{stopped}/{args.seeds} | {runaway:.0f} | {np.median(cpu):.2f} |", flush=True)
    print(f"worst |z| with the priors: {worst:.2f} ({'within' if worst < 3.5 else 'BEYOND'} 3.5)")
    return 0 if worst < 3.5 else 1


if __name__ == "__main__":
    sys.exit(main())
