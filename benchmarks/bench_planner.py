"""Stance planning: how many D-optimal stances reach the precision of the paper's random plan, and the robot time
that saves - predicted by the design, and measured on the mock.

    python benchmarks/bench_planner.py [--seeds 5] [--mock-seeds 1]

Part 1 (design, per plan seed): a pool of 150 feasible stances per leg; the paper plan is the first 24 per leg
(random), the optimal plan the greedy D-optimal prefix that matches it in both the D-criterion and the worst
joint-offset standard deviation (agent.design, generalised least squares with 0.1 deg encoder quantisation).
Part 2 (mock): both plans calibrate the same mock; robot time of the measurement phase, the standard deviations the
fit reports, and the errors against the mock's hidden truth.
"""

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.planner import PlanSettings, make_plan  # noqa: E402
from naocal.solver.joints import LEG_JOINTS  # noqa: E402


def design_part(seeds):
    print("design (predicted by agent.design; 3 head postures per stance)")
    print(f"{'seed':>4} {'paper':>6} {'optimal':>8} {'ratio':>6} {'paper worst std':>16} {'optimal worst std':>18} "
          f"{'paper time':>11} {'optimal time':>13} {'plan s':>7}")
    rows = []
    for seed in seeds:
        t0 = time.perf_counter()
        optimal = make_plan(seed, PlanSettings(kind="optimal", probe=False))
        seconds = time.perf_counter() - t0
        design = optimal.stats["design"]
        paper = make_plan(seed, PlanSettings(kind="paper", probe=False))
        paper_worst = np.degrees(max(paper.stats["predicted_std"][f"joint_offset.{j}"] for j in LEG_JOINTS))
        row = (seed, design["paper_stances"], design["selected_stances"],
               design["paper_stances"] / design["selected_stances"], paper_worst,
               optimal.stats["predicted_worst_joint_offset_std_deg"], paper.stats["estimated_robot_time_s"],
               optimal.stats["estimated_robot_time_s"], seconds)
        rows.append(row)
        print(f"{row[0]:4d} {row[1]:6d} {row[2]:8d} {row[3]:6.2f} {row[4]:13.4f} deg {row[5]:15.4f} deg "
              f"{row[6]:9.1f} s {row[7]:11.1f} s {row[8]:7.1f}")
    r = np.array([row[1:] for row in rows], dtype=float)
    print(f"mean: paper {r[:, 0].mean():.0f} stances, optimal {r[:, 1].mean():.1f} stances "
          f"(ratio {r[:, 2].mean():.2f}); estimated robot time {r[:, 5].mean():.0f} s -> {r[:, 6].mean():.0f} s "
          f"(saves {100 * (1 - r[:, 6].mean() / r[:, 5].mean()):.0f} %)")
    print("(the paper plan of each seed here is drawn from the optimal run's pool; the 'paper' column of the "
          "time estimate is the agent's own paper plan for that seed)")


def mock_part(seeds):
    from naocal.agent.calibrate import calibrate
    from naocal.agent.summary import truth_errors
    from naocal.agent.states import AgentSettings
    from naocal.backends.mock import MockBackend

    print("\nmock (measured): the same robot calibrated with each plan")
    print(f"{'mock seed':>9} {'plan':>8} {'stances':>8} {'images':>7} {'robot s':>8} {'wall s':>7} "
          f"{'worst std':>10} {'worst error':>12} {'RMS error':>10}")
    for seed in seeds:
        results = {}
        for kind in ("paper", "optimal"):
            out = Path(tempfile.mkdtemp(prefix=f"naocal_bench_{kind}_"))
            mock = MockBackend(seed)
            try:
                t0 = time.perf_counter()
                result, ctx = calibrate(mock, out, AgentSettings(seed=0, plan=PlanSettings(kind=kind),
                                                                 progress_bar=False, save_images=False))
                wall = time.perf_counter() - t0
                truth = mock.truth_dict()
            finally:
                mock.close()
            if not result.ok:
                print(f"{seed:9d} {kind:>8} failed: {result.reason}")
                continue
            res = ctx.identification
            errors = np.array(list(truth_errors(res, truth)["joint_offset_deg"].values()))
            std = max(np.degrees(res.std[res.registry.index[f"joint_offset.{j}"]]) for j in LEG_JOINTS)
            stances = sum(ctx.plan.stats["n_stances"].values())
            results[kind] = ctx.measurement["robot_time_s"]
            print(f"{seed:9d} {kind:>8} {stances:8d} {ctx.plan.n_images():7d} {ctx.measurement['robot_time_s']:8.1f} "
                  f"{wall:7.1f} {std:7.4f} deg {np.abs(errors).max():9.4f} deg {np.sqrt(np.mean(errors ** 2)):7.4f} deg")
            shutil.rmtree(out, ignore_errors=True)
        if len(results) == 2:
            print(f"{'':9s} robot time optimal / paper: {results['optimal'] / results['paper']:.2f} "
                  f"(the paper's robot: 590 s)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="plan seeds for the design part")
    parser.add_argument("--mock-seeds", type=int, default=1, help="mock seeds for the measured part (0: skip)")
    args = parser.parse_args()
    design_part(range(args.seeds))
    if args.mock_seeds:
        mock_part(range(args.mock_seeds))


if __name__ == "__main__":
    main()
