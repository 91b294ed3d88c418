"""Drive logs as other recorders write them (issue 23's "logs recorded elsewhere"), one variation at a time.

Each variant is a log of the independent generator (tests/indep_drive_log.py: OpenCV + numpy, nothing of naocal's)
differing from the base (tests/test_duckiebot_indep_log.py's SMALL log, about 270 frames) in one way a ROS bag
export or another lab's generator may: the clock (Unix epoch 1.78e9), the camera starting before or after the first
wheel row, commands at exactly the frames' times, every wheel row written twice, PNG frames, encoders.csv (with and
without ticks_per_revolution, counters near int32's wrap), boards of 6 x 4 and 8 x 6 inner corners with other
squares, markers of 5 and 8 cm, robot models DB21M / DB19 / a lab's own, CRLF, a UTF-8 BOM, a trailing blank line,
extra log.json keys. For each: `naocal identify LOG --out CAL.json` (trim against the generator's truth, within
0.001; gain within 1 %: test_duckiebot_indep_log.py's criteria), `naocal diagnose LOG` (a clean log: no effect
named), `naocal offsets export CAL.json --format duckietown` (the three files).

Variants whose files alone differ link the base log's frames (same scene and motion); when such a log reads exactly
as the base log (every array and field naocal reads), diagnose is not run again: its input is the same. Logs are
cached outside git (NAOCAL_BENCH_CACHE, default /tmp/naocal-bench-duckiebot-log-variants; about 55 s CPU to render one).
Run: `python benchmarks/bench_duckiebot_log_variants.py [--only NAME ...] [--no-diagnose] [--render]`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from indep_drive_log import Variation, default_truth, make_log  # noqa: E402

SMALL = Variation(turn_rate_radps=0.6, line_speed_mps=0.15, line_distance_m=0.4, n_markers=6)
# name: (changes to SMALL, whether the frames are SMALL's)
VARIANTS = {
    "base": ({}, False),
    "unix_1.78e9": ({"t0_s": 1.78e9}, False),
    "camera_first_1s": ({"camera_start_s": -1.0}, False),
    "wheels_first_1s": ({"camera_start_s": 1.0}, False),
    "rows_at_frames": ({"wheel_rows_at_frames": True}, True),  # the motion is the same: so are the frames
    "rows_twice": ({"duplicate_wheel_rows": True}, True),
    "png": ({"image_ext": ".png"}, False),
    "encoders": ({"encoders": True}, True),
    "encoders_int32_wrap": ({"encoders": True, "encoder_start_ticks": (2 ** 31 - 60, -2 ** 31 + 60)}, True),
    "encoders_no_ticks_per_rev": ({"encoders": True, "ticks_per_revolution": None}, True),
    "board_6x4_40mm": ({"board_inner_corners": (6, 4), "board_square_m": 0.04, "board_centre_m": 0.15}, False),
    "board_8x6_25mm": ({"board_inner_corners": (8, 6), "board_square_m": 0.025}, False),
    "marker_50mm": ({"marker_size_m": 0.05}, False),
    "marker_80mm": ({"marker_size_m": 0.08}, False),
    "model_DB21M": ({"model": "DB21M"}, True),
    "model_DB21J": ({"model": "DB21J"}, True),
    "model_DB19": ({"model": "DB19"}, True),
    "model_unknown": ({"model": "DB99-lab"}, True),
    "crlf": ({"newline": "\r\n"}, True),
    "bom": ({"bom": True}, True),
    "trailing_blank_line": ({"trailing_blank_line": True}, True),
    "extra_keys": ({"extra_meta": {"recorded_by": "rosbag2csv 0.3", "robot": {"hostname": "autobot01"},
                                   "camera": {"fps": 15}}}, True),
}


def naocal(*argv):
    return subprocess.run([sys.executable, "-m", "naocal", *map(str, argv)], cwd=ROOT, capture_output=True,
                          text=True, timeout=1800)


def as_read(log):
    """What naocal reads of a log (every array and description field), to compare logs by."""
    from naocal.kinds.duckiebot.drive_log import read_drive_log

    d = read_drive_log(log, check_images=False)
    return [d.model, d.wheels, d.marker_size_m, d.board_inner_corners, d.board_square_m, d.frame_files] + \
        [a.tolist() for a in (d.wheel_t_s, d.left_duty, d.right_duty, d.frame_t_s)]


def last_line(text):
    lines = text.strip().splitlines()
    return lines[-1][:110] if lines else ""


def run(name, cache: Path, diagnose: bool, render: bool = False):
    changes, linked = VARIANTS[name]
    linked = linked and not render
    var = dataclasses.replace(SMALL, **changes)
    base_dir = cache / "base" / "LOG"
    log = cache / name / "LOG"
    if not (log / "log.json").exists():
        shutil.rmtree(cache / name, ignore_errors=True)
        make_log(log, var, frames_from=base_dir if linked else None)
    truth = default_truth(var.seed)  # what make_log hid
    cal = cache / name / "CAL.json"
    cal.unlink(missing_ok=True)
    row = {"variant": name}
    identify = naocal("identify", log, "--out", cal)
    row["identify"] = identify.returncode
    if identify.returncode == 0:
        kin = json.loads(cal.read_text())["kinematics"]
        row["trim_err"] = kin["trim"] - truth.trim
        row["gain_err_pct"] = 100 * (kin["gain"] / truth.gain - 1)
        row["baseline_err_mm"] = 1000 * (kin["baseline_m"] - truth.baseline_m)
        out = cache / name / "DT"
        shutil.rmtree(out, ignore_errors=True)
        export = naocal("offsets", "export", cal, "--format", "duckietown", "--out", out)
        files = [out / f / "indep.yaml" for f in ("kinematics", "camera_intrinsic", "camera_extrinsic")]
        row["export"] = f"exit {export.returncode}, {sum(f.is_file() for f in files)}/3 files"
    else:
        row["error"] = last_line(identify.stderr)
    if linked and as_read(log) == as_read(base_dir):
        row["diagnose_says"] = "not run: the log reads exactly as the base log (diagnose's input is the same)"
    elif diagnose:
        diag = naocal("diagnose", log)
        row["diagnose"] = diag.returncode
        row["diagnose_says"] = next((ln[:110] for ln in diag.stdout.splitlines() if ln.startswith("VERDICT")),
                                    last_line(diag.stderr))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=list(VARIANTS))
    parser.add_argument("--no-diagnose", action="store_true")
    parser.add_argument("--render", action="store_true", help="render every variant's frames (link none)")
    args = parser.parse_args()
    cache = Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot-log-variants"))
    names = args.only or list(VARIANTS)
    if not args.render and any(VARIANTS[name][1] for name in names) and not (cache / "base" / "LOG" / "log.json").exists():
        names = ["base"] + [name for name in names if name != "base"]
    for name in names:
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        row = run(name, cache, not args.no_diagnose, args.render)
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        row["naocal_cpu_s"] = round(cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1)
        ok = row["identify"] == 0 and abs(row["trim_err"]) < 0.001 and abs(row["gain_err_pct"]) < 1.0
        diagnosed = row.get("diagnose_says", "").startswith(("VERDICT: no missing effect", "not run"))
        row["ok"] = ok and row.get("diagnose", 0) == 0 and (args.no_diagnose or diagnosed)
        print(json.dumps({k: round(v, 5) if isinstance(v, float) else v for k, v in row.items()}), flush=True)


if __name__ == "__main__":
    main()
