"""The mission's loop on the Duckiebot (issue 23): `naocal diagnose` on drive logs with one hidden effect each.

For each seed and case, `kinds.duckiebot.simulate.run_simulate` renders a drive log of hidden robot SEED (the OpenCV
renderer, render.joint_program) with the case's hidden effect, and `kinds.duckiebot.diagnose.diagnose_log` fits the
base model (Duckietown's kinematics, no wheel effect, corners rectified with plumb_bob), names the missing effect
(score tests; the lens by its held-out error) and refits with it. Cases: clean (nothing hidden: nothing must be
named), dead_zone=0.08, slip=0.5 (s/m), wide_lens (a 150-degree Kannala-Brandt lens plumb_bob cannot follow).

Columns: what is named first and its statistic (T^2 of the clustered score test, or the lens's held-out ratio), the
corner RMS before and after adding it, the clean log's RMS of the same robot (what the base model leaves with
nothing hidden: the floor the refit must reach), after / clean, and the corners' expected noise (identify.py's
noise model). A row is ok when the hidden effect is named first and its refit could be made. Where the base
model's joint fit cannot be made (a wrong lens can leave it undetermined) RMS before is 'no fit' and the reason is
noted; where the refit cannot be made, after is nan and its reason noted.

Logs are cached outside git (NAOCAL_BENCH_CACHE, default /tmp/naocal-bench-duckiebot-diagnose): about 15 s CPU to
render each. Run: `python benchmarks/bench_duckiebot_diagnose.py [--seeds 1 2 3]`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import naocal.tools.cli  # noqa: E402,F401  (one BLAS thread, as the command line)
from naocal.kinds.duckiebot.drive_diagnostics import diagnose_log  # noqa: E402
from naocal.kinds.duckiebot.simulate import run_simulate  # noqa: E402
from naocal.solver.errors import NaocalError  # noqa: E402

CASES = {"clean": "", "dead_zone": "dead_zone=0.08", "slip": "slip=0.5", "wide_lens": "wide_lens"}
EXPECTED = {"clean": None, "dead_zone": "dead_zone", "slip": "slip", "wide_lens": "lens=fisheye"}


def cache_dir() -> Path:
    return Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot-diagnose"))


def log_of(seed: int, case: str) -> Path:
    path = cache_dir() / f"{case}_seed{seed}"
    if not (path / "truth.json").exists():
        path.mkdir(parents=True, exist_ok=True)
        for stale in path.rglob("*"):  # an interrupted render: start over
            if stale.is_file():
                stale.unlink()
        run_simulate(argparse.Namespace(seed=seed, out=str(path), hidden_effects=CASES[case]))
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    args = parser.parse_args(argv)
    print(f"{'seed':>4} {'hidden':10s} {'named first':14s} {'statistic':>12s} {'RMS before':>11s} {'after':>7s} "
          f"{'clean':>7s} {'a/clean':>7s} {'noise':>7s} {'ok':>3s} {'CPU s':>6s}")
    failures = 0
    for seed in args.seeds:
        clean_rms = None
        for case in args.cases:
            path = log_of(seed, case)
            t0 = time.process_time()
            try:
                d = diagnose_log(path)
            except NaocalError as err:  # the base fit refused the log: said, counted as a failure
                failures += 1
                print(f"{seed:4d} {case:10s} refused: {err}", flush=True)
                continue
            cpu = time.process_time() - t0
            named = d.named
            if named is None:
                statistic = "-"
            elif named.startswith("lens="):
                statistic = f"ratio {d.lens_verdict.ratio:.1f}"
            else:
                statistic = f"T2 {next(t.statistic for t in d.tests if t.effect == named):.0f}"
            if case == "clean":
                clean_rms = d.rms_px
            after = d.after.get("rms_px", float("nan")) if d.after else float("nan")
            # named as hidden, and (something named) the refit with it made
            ok = named == EXPECTED[case] and (named is None or np.isfinite(after))
            failures += not ok
            clean = f"{clean_rms:7.3f}" if clean_rms is not None else "      -"
            after_text = f"{after:7.3f}" if named is not None else f"{'-':>7s}"
            ratio = f"{after / clean_rms:7.2f}" if clean_rms and np.isfinite(after) else f"{'-':>7s}"
            before = f"{d.rms_px:11.3f}" if d.fit is not None else f"{'no fit':>11s}"
            noise = f"{d.floor_px:7.3f}" if d.fit is not None else f"{'-':>7s}"
            notes = ([f"base fit: {d.fit_error[:60]}..."] if d.fit_error else []) + (
                [f"refit: {d.after['error']}"] if d.after and "error" in d.after else [])
            print(f"{seed:4d} {case:10s} {str(named):14s} {statistic:>12s} {before} {after_text} {clean} "
                  f"{ratio} {noise} {'yes' if ok else 'NO':>3s} {cpu:6.1f}" + "".join("  " + n for n in notes),
                  flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
