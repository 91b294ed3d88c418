"""Ranking every candidate effect: naocal's score test against refitting every candidate, same data, same run.

Dataset: the paper's size, 24 stances per leg x 3 head postures = 144 images, 3456 vertices, 0.1 px noise, with
hidden elasticity (0.02-0.05 rad/(N m)) and joint velocities on a third of the images (so time_lag is testable).
naocal: `rank_candidates` (one evaluation of the model extended by all 7 candidates at zero, projection off the
fitted Jacobian, clustered jackknife score tests).
Straightforward: for every candidate, refit the extended model with scipy.optimize.least_squares (method='lm',
finite-difference Jacobian, started from the base fit) and take the RMS it reaches.

    python benchmarks/bench_diagnose.py [--repeats 20]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.solver.diagnostics import rank_candidates  # noqa: E402
from naocal.solver.identify import identify  # noqa: E402
from naocal.solver.joints import LEG_JOINTS  # noqa: E402
from naocal.solver.model import Model  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402
from naocal.sim.synthetic import random_truth, synthesize  # noqa: E402


def refit_every_candidate(result, candidates):
    """{effect: RMS over both coordinates after refitting the model with it}, finite differences throughout."""
    out = {}
    for effect in candidates:
        registry = result.registry.extended((effect,))
        model = Model(result.model.data, registry)
        x0 = registry.from_dict(result.registry.as_dict(result.values))
        scales = registry.scales

        def fun(x):
            return model.residuals(x).ravel()

        sol = least_squares(fun, x0, method="lm", x_scale=scales, diff_step=1e-7)
        out[effect] = float(np.sqrt(np.mean(sol.fun ** 2)))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    truth = random_truth(rng)
    truth.update({f"elasticity.{j}": rng.uniform(0.02, 0.05) for j in LEG_JOINTS})
    velocity = np.zeros((144, 14))
    velocity[::3] = rng.uniform(-0.4, 0.4, (48, 14))
    data = synthesize(rng, truth, effects=("elasticity",), velocity=velocity, pixel_noise_px=0.1)
    result = identify(data, Registry())
    print(f"dataset: {data.n_rows} vertices in {data.n_images} images; base fit RMS "
          f"{result.rms_px[0]:.3f} / {result.rms_px[1]:.3f} px (hidden elasticity)")

    rank_candidates(result)  # warm-up
    times, cpu = [], []
    for _ in range(args.repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        ranking = rank_candidates(result)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    fast = statistics.median(times)

    start = time.perf_counter()
    # the effects (the model's assumptions are candidates too: untie_shared_motors is only tested on a tied model,
    # rigid_board has no model to refit)
    refit = refit_every_candidate(result, [c.effect for c in ranking if c.testable and not c.assumption])
    slow = time.perf_counter() - start

    print(f"\n{'candidate':18s} {'predicted RMS':>14s} {'refit RMS':>10s} {'p-value':>9s} {'uniqueness':>10s}")
    for c in ranking:
        print(f"{c.effect:18s} {c.predicted_rms_px:11.3f} px {refit.get(c.effect, float('nan')):7.3f} px "
              f"{c.p_value:9.1e} {c.uniqueness:10.3f}")
    order_fast = [c.effect for c in ranking if c.effect in refit]
    order_slow = sorted(refit, key=refit.get)
    print(f"\nbest candidate: score test {order_fast[0]}, refitting {order_slow[0]}")
    print(f"naocal rank_candidates ({len(ranking)} candidates): median {fast * 1e3:.1f} ms wall, "
          f"{statistics.median(cpu) * 1e3:.1f} ms CPU over {args.repeats} runs (target < 1000 ms)")
    print(f"straightforward (refit each, finite differences): {slow:.2f} s")
    print(f"speed-up: {slow / fast:.0f}x")


if __name__ == "__main__":
    main()
