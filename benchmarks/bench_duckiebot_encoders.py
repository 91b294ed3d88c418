"""encoders.csv as evidence in `naocal diagnose LOG` end to end: logs of the independent generator
(tests/indep_drive_log.py: OpenCV + numpy, nothing of naocal's; the variant benchmark's SMALL log with encoders,
about 270 frames) with and without a hidden slip in turns (Truth.turn_slip: the body turns that share less than its
wheels, whose encoders count the turn as commanded) and with wheels of another radius than log.json's. For each:
diagnose's named effect, the fitted baseline, the encoders' ratio per phase and their evidence, CPU seconds.
Logs are cached outside git (NAOCAL_BENCH_CACHE, default /tmp/naocal-bench-duckiebot-encoders; about 45 s CPU to
render one). Run: `python benchmarks/bench_duckiebot_encoders.py [--only NAME ...]`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from indep_drive_log import default_truth, make_log  # noqa: E402

from bench_duckiebot_log_variants import SMALL  # noqa: E402

LOG = dataclasses.replace(SMALL, encoders=True)
HIDDEN = {"clean": {}, "turn slip 0.15": {"turn_slip": 0.15}, "turn slip 0.05": {"turn_slip": 0.05},
          "radius 34.5 mm": {"radius_m": 0.0345}}


def cached_log(name: str) -> Path:
    cache = Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot-encoders"))
    path = cache / name.replace(" ", "_")
    if not (path / "log.json").exists():
        make_log(path, LOG, dataclasses.replace(default_truth(LOG.seed), **HIDDEN[name]))
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", choices=sorted(HIDDEN), action="append")
    args = parser.parse_args()
    for name in args.only or HIDDEN:
        log = cached_log(name)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run([sys.executable, "-m", "naocal", "diagnose", str(log), "--json"], cwd=ROOT,
                              capture_output=True, text=True, timeout=3600)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
        if done.returncode:
            print(f"{name:16s} exit {done.returncode}: {done.stderr.strip()[:200]}")
            continue
        d = json.loads(done.stdout)
        enc = d["encoders"]
        phases = ", ".join(f"{p} {v['both']:.3f} (+-{v['tolerance']:.3f})" for p, v in enc["phases"].items())
        print(f"{name:16s} named {d['named']}; baseline {d['parameters']['baseline_m']['value'] * 1e3:.1f} mm; "
              f"encoder / model: {phases}; {cpu:.0f} s CPU\n{'':17s}evidence: {enc['verdict']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
