"""`naocal calibrate --backend mock` on the ideal and the realistic mock: what the agent achieves on each.

    python benchmarks/mock_realism_runs.py [--seeds 1 2 3] [--mock ideal realistic] [--out DIR]

For each mock and seed, one whole calibration (default paper plan, as the README's main command): whether it
finished, captures saved, the commands the mock refused (its own check on the true body: a refusal is a command
that would have collided), robot time, the fit's RMS, the worst joint-offset standard deviation the fit claims, the
worst joint-offset error against the mock's hidden truth, and the wall-clock and CPU seconds it took. The
realistic mock's corner fault model is applied as `naocal calibrate --mock realistic` applies it. Prints a
markdown table (docs/MOCK.md quotes it).
"""

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.calibrate import calibrate  # noqa: E402
from naocal.agent.measure import opencv_detector  # noqa: E402
from naocal.agent.states import AgentSettings  # noqa: E402
from naocal.backends.mock import MockBackend  # noqa: E402
from naocal.solver.joints import LEG_JOINTS  # noqa: E402


def run(mock_kind: str, seed: int, out: Path) -> dict:
    mock = MockBackend(seed, realism=mock_kind)
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        result, ctx = calibrate(mock, out, AgentSettings(seed=0, progress_bar=False),
                                detector=mock.faulty(opencv_detector), truth=mock.truth_dict())
    finally:
        mock.close()
    row = {"mock": mock_kind, "seed": seed, "ok": result.ok, "reason": result.reason,
           "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
           "refused": sum(not record.accepted for record in mock.command_log)}  # the mock's own collision check
    if ctx.measurement:
        row.update(saved=ctx.measurement["n_saved"], planned=ctx.measurement["n_planned"],
                   robot_s=ctx.measurement["robot_time_s"])
    fit = ctx.identification
    if fit is not None:
        alpha = mock.truth.alpha_rad
        errors = [abs(fit.value(f"joint_offset.{j}") + alpha[j]) for j in LEG_JOINTS]  # the parameter is c = -alpha
        stds = [float(fit.std[fit.registry.index[f"joint_offset.{j}"]]) for j in LEG_JOINTS]
        row.update(rms_px=max(fit.rms_px), worst_error_deg=math.degrees(max(errors)),
                   worst_std_deg=math.degrees(max(stds)),
                   worst_z=max(e / s for e, s in zip(errors, stds) if s > 0))
        row["largest_offset_deg"] = math.degrees(max(abs(alpha[j]) for j in LEG_JOINTS))
        for camera, truth in mock.truth.camera_rotations().items():  # worst of roll, pitch, yaw per camera
            if f"camera.{camera}.pitch" in fit.registry.index:
                row[f"{camera}_camera_error_deg"] = math.degrees(max(
                    abs(fit.value(f"camera.{camera}.{a}") - truth[a]) for a in ("roll", "pitch", "yaw")))
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--mock", nargs="+", default=["ideal", "realistic"], choices=("ideal", "realistic"))
    parser.add_argument("--out", type=Path, help="keep the runs here (default: a temporary directory)")
    args = parser.parse_args()
    base = args.out or Path(tempfile.mkdtemp(prefix="naocal_realism_"))
    print("| mock | seed | done | saved | refused by the mock | robot time s | RMS px | worst std deg | "
          "worst error deg | error / std | largest offset deg | bottom camera error deg | top camera error deg | wall s | "
          "CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for kind in args.mock:
        for seed in args.seeds:
            r = run(kind, seed, base / f"{kind}-{seed}")
            cells = [kind, seed, "yes" if r["ok"] else f"no: {r['reason']}",
                     f"{r.get('saved', 0)}/{r.get('planned', 0)}", r["refused"],
                     f"{r.get('robot_s', float('nan')):.1f}",
                     f"{r.get('rms_px', float('nan')):.3f}", f"{r.get('worst_std_deg', float('nan')):.4f}",
                     f"{r.get('worst_error_deg', float('nan')):.4f}", f"{r.get('worst_z', float('nan')):.1f}",
                     f"{r.get('largest_offset_deg', float('nan')):.1f}",
                     f"{r.get('bottom_camera_error_deg', float('nan')):.4f}",
                     f"{r.get('top_camera_error_deg', float('nan')):.4f}", f"{r['wall_s']:.0f}", f"{r['cpu_s']:.0f}"]
            print("| " + " | ".join(str(c) for c in cells) + " |", flush=True)
    print(f"runs kept in {base}")


if __name__ == "__main__":
    main()
