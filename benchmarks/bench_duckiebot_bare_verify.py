"""`naocal verify LOG` with no calibration anywhere (an empty calibrations directory): how long it takes to say it
cannot judge a log without boards, and that a log with boards is still judged by its own camera.

Two logs of the independent generator (tests/indep_drive_log.py: OpenCV + numpy, nothing of naocal's): the
variant log's SMALL log (about 270 frames at 15 fps, boards in view while turning) and the same base log with no
boards (Variation(board_angles_rad=()), 412 frames, markers only). Each is verified in a child process of the
checkout given (default this one; another, e.g. main's worktree, measures before/after): exit code, the child's CPU
seconds (user + system) and wall seconds, the verdict's or error's first line. Logs are cached outside git
(NAOCAL_BENCH_CACHE, default /tmp/naocal-bench-duckiebot-bare-verify; about 45 s CPU to render one).
Run: `python benchmarks/bench_duckiebot_bare_verify.py [--checkout DIR] [--only boards|no-boards]`.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from indep_drive_log import Variation, make_log  # noqa: E402

from bench_duckiebot_log_variants import SMALL  # noqa: E402

LOGS = {"no-boards": Variation(board_angles_rad=()), "boards": SMALL}


def cached_log(name: str) -> Path:
    cache = Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot-bare-verify"))
    path = cache / name
    if not (path / "log.json").exists():
        make_log(path, LOGS[name])
    return path


def run_verify(checkout: Path, log: Path) -> tuple[int, float, float, str]:
    """(exit code, child CPU s, wall s, first line of its output) of `naocal verify LOG` from `checkout`."""
    with tempfile.TemporaryDirectory() as empty:
        env = {**os.environ, "NAOCAL_DUCKIETOWN_CALIBRATIONS": empty}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "naocal", "verify", str(log)], cwd=checkout, env=env,
                              capture_output=True, text=True, timeout=3600)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = (done.stdout + done.stderr).strip().splitlines()
    verdict = next((line for line in lines if line.startswith(("verdict", "naocal verify: error"))), lines[-1:])
    return done.returncode, cpu, wall, str(verdict)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkout", type=Path, default=ROOT, help="the naocal checkout to run (default: this one)")
    parser.add_argument("--only", choices=sorted(LOGS), action="append")
    args = parser.parse_args()
    for name in args.only or sorted(LOGS, reverse=True):
        log = cached_log(name)
        frames = sum(1 for _ in open(log / "frames.csv")) - 1
        code, cpu, wall, line = run_verify(args.checkout, log)
        print(f"{name:10s} {frames:4d} frames: exit {code}, {cpu:6.1f} s CPU, {wall:6.1f} s wall: {line[:160]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
