"""Precision per robot-second on the realistic mock: worst joint-offset std and error against robot time, paper plan
against optimal plan.

    python benchmarks/bench_precision.py [--seeds 1 2 3] [--plans paper optimal] [--fractions 0.33 0.5 0.75 1]
                                         [--out DIR] [--plot docs/precision.png]

For each seed and plan, one whole `naocal calibrate --backend mock` (realistic, the corner fault model applied as
the command line applies it). Then the curve from its own captures: the first fraction f of each leg's stances
(bottom camera, still; a plan measures the legs one after the other, so a prefix of the run would hold one leg
only) fitted as the agent fits (solver.fit.identify_dataset, GLS), against the robot time those stances took (each
leg from its first capture to the end of its last kept stance, on the mock's clock). f = 1 is the whole run: every
capture, the top camera's too, and the run's whole robot time. Each row also gives the worst std the planner's
information model predicts for the bottom-camera still captures the row fitted (agent.design, the plan's own
settings) and realised / predicted. Prints a markdown table (docs/AGENT.md quotes it).
"""

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.calibrate import calibrate  # noqa: E402
from naocal.agent.design import predicted_std, stance_information  # noqa: E402
from naocal.agent.measure import opencv_detector  # noqa: E402
from naocal.agent.planner import PlanSettings  # noqa: E402
from naocal.agent.states import AgentSettings  # noqa: E402
from naocal.backends.mock import MockBackend  # noqa: E402
from naocal.solver.dataset import Dataset, read_dataset  # noqa: E402
from naocal.solver.fit import identify_dataset  # noqa: E402
from naocal.solver.joints import LEG_JOINTS, LEGS  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402


def worst(result, alpha) -> tuple[float, float]:
    """(worst |error|, worst std) of the leg joint offsets, deg (the parameter is c = -alpha)."""
    errors = [abs(result.value(f"joint_offset.{j}") + alpha[j]) for j in LEG_JOINTS]
    stds = [result.std[result.registry.index[f"joint_offset.{j}"]] for j in LEG_JOINTS]
    return math.degrees(max(errors)), math.degrees(max(stds))


def predicted_worst_std_deg(plan, images) -> float:
    """The planner's predicted worst joint-offset std (deg) for the plan's bottom-camera stills among `images`."""
    s = PlanSettings.from_dict(plan.settings)
    registry = Registry(tuple(e for e in s.design_effects.split(",") if e))
    stills = [st for st in plan.stills() if st.camera == "bottom" and st.image in set(int(i) for i in images)]
    info = stance_information(np.array([st.angles() for st in stills]), np.array([st.leg for st in stills]),
                              np.array([st.stance for st in stills]), sigma_px=s.sigma_px,
                              encoder_resolution_rad=np.radians(s.encoder_resolution_deg), intrinsics=s.intrinsics,
                              registry=registry, servo_stiffness_nm_per_rad=s.servo_stiffness_nm_per_rad)
    std = predicted_std(info.sum(axis=0), registry)
    return math.degrees(max(std[registry.index[f"joint_offset.{j}"]] for j in LEG_JOINTS))


def curve(dataset, fractions, alpha, total_robot_s, plan) -> list[dict]:
    cols = dataset.as_v2().columns
    image = np.asarray(cols["image"])
    t = np.asarray(cols["t_image_s"], dtype=float)
    still = np.ones(len(image), bool)
    if dataset.as_v2().has_velocities:
        still = np.all([np.asarray(cols["vel_" + j]) == 0 for j in dataset.joints], axis=0)
    bottom = np.asarray(cols["camera"]) == "bottom"
    target, stance = np.asarray(cols["target"]), np.asarray(cols["stance"])
    points = []
    for f in fractions:
        if f >= 1.0:
            fit = identify_dataset(dataset, gls=True)
            e, s = worst(fit.result, alpha)
            points.append({"fraction": 1.0, "robot_s": total_robot_s, "images": len(np.unique(image)),
                           "worst_error_deg": e, "worst_std_deg": s,
                           "predicted_std_deg": predicted_worst_std_deg(plan, image[bottom & still])})
            continue
        keep = np.zeros(len(image), bool)
        robot_s = 0.0
        for leg in LEGS:
            rows = bottom & still & (target == leg)
            if not rows.any():  # a leg none of whose captures were saved: no curve without it
                break
            stances = sorted(set(stance[rows]), key=lambda k: t[rows & (stance == k)].min())
            chosen = stances[:max(1, int(round(f * len(stances))))]
            sel = rows & np.isin(stance, chosen)
            keep |= sel
            robot_s += t[sel].max() - t[rows].min()
        else:
            part = Dataset(dataset.meta, {k: np.asarray(v)[keep] for k, v in cols.items()})
            fit = identify_dataset(part, gls=True)
            e, s = worst(fit.result, alpha)
            points.append({"fraction": f, "robot_s": robot_s, "images": len(np.unique(image[keep])),
                           "worst_error_deg": e, "worst_std_deg": s,
                           "predicted_std_deg": predicted_worst_std_deg(plan, image[keep])})
    return points


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--plans", nargs="+", default=["paper", "optimal"], choices=("paper", "optimal"))
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.33, 0.5, 0.75, 1.0])
    parser.add_argument("--out", type=Path, help="keep the runs here (default: a temporary directory)")
    parser.add_argument("--plot", type=Path, help="write the curve as a PNG")
    args = parser.parse_args()
    base = args.out or Path(tempfile.mkdtemp(prefix="naocal_precision_"))
    print("| plan | seed | stances per leg | images | robot s | worst std deg | predicted std deg | realised / predicted "
          "| worst error deg | run wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for plan in args.plans:
        for seed in args.seeds:
            out = base / f"{plan}-{seed}"
            mock = MockBackend(seed, realism="realistic")
            wall = time.perf_counter()
            try:
                settings = AgentSettings(seed=0, progress_bar=False, plan=PlanSettings(kind=plan))
                result, ctx = calibrate(mock, out, settings, detector=mock.faulty(opencv_detector),
                                        truth=mock.truth_dict())
                alpha = mock.truth.alpha_rad
            finally:
                mock.close()
            wall = time.perf_counter() - wall
            if not result.ok:
                print(f"| {plan} | {seed} | failed: {result.reason} | | | | | | | {wall:.0f} |", flush=True)
                continue
            n_stances = ctx.plan.stats["n_stances"]
            for p in curve(read_dataset(out / "dataset"), args.fractions, alpha, ctx.measurement["robot_time_s"],
                           ctx.plan):
                per_leg = "/".join(str(max(1, int(round(p["fraction"] * n_stances[leg])))) for leg in LEGS)
                rows.append(dict(p, plan=plan, seed=seed))
                print(f"| {plan} | {seed} | {per_leg} | {p['images']} | {p['robot_s']:.1f} | "
                      f"{p['worst_std_deg']:.3f} | {p['predicted_std_deg']:.3f} | "
                      f"{p['worst_std_deg'] / p['predicted_std_deg']:.2f} | {p['worst_error_deg']:.3f} | "
                      + (f"{wall:.0f} |" if p["fraction"] >= 1.0 else " |"), flush=True)
    print(f"runs kept in {base}")
    if args.plot and rows:
        plot(rows, args.plot)


def plot(rows, path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_std, ax_err) = plt.subplots(1, 2, figsize=(9, 3.6), sharex=True)
    colours = {"paper": "tab:blue", "optimal": "tab:orange"}
    for (plan, seed) in sorted({(r["plan"], r["seed"]) for r in rows}):
        pts = sorted((r for r in rows if r["plan"] == plan and r["seed"] == seed), key=lambda r: r["robot_s"])
        x = [r["robot_s"] for r in pts]
        label = plan if seed == min(r["seed"] for r in rows if r["plan"] == plan) else None
        colour = colours.get(plan)
        ax_std.plot(x, [r["worst_std_deg"] for r in pts], "o-", color=colour, label=label, alpha=0.8)
        ax_err.plot(x, [r["worst_error_deg"] for r in pts], "o-", color=colour, label=label, alpha=0.8)
    for ax, title in ((ax_std, "worst joint-offset std (deg)"), (ax_err, "worst joint-offset error (deg)")):
        ax.axhline(0.05 if ax is ax_std else 0.1, color="grey", lw=0.8, ls="--")
        ax.axvline(90.0, color="grey", lw=0.8, ls=":")
        ax.set_xlabel("robot time (s)")
        ax.set_title(title, fontsize=10)
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


if __name__ == "__main__":
    main()
