"""Does `naocal verify` find a small drift on the default (realistic) mock? Issue 21's benchmark.

For each calibration run (`naocal calibrate --backend mock --seed N --out RUN`, the realistic mock, the default),
the run's own offsets.json is changed in ONE leg joint offset and the run's dataset verified under it: the verdict
must be drifted (exit 1) and name the joint; the unchanged file must be still good (exit 0). The change required is
max(0.1 deg, 3 x the joint's own std from the offsets file), tried with both signs; the smallest change found is
searched among a few sizes (+ sign). HipYawPitch is one motor (one offset for L and R): both entries change.

    python benchmarks/bench_verify_drift.py RUN [RUN ...] [--markdown]

Runs are made once and reused (about 50 s CPU each); CPU time (process_time) is printed beside wall time.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.rundir import find_dataset  # noqa: E402
from naocal.solver.dataset import read_dataset  # noqa: E402
from naocal.solver.joints import LEG_JOINTS  # noqa: E402
from naocal.solver.offsets import read_offsets  # noqa: E402
from naocal.solver.verify import verify_dataset  # noqa: E402
from naocal.kinds.nao.verify import EXIT_DRIFTED, EXIT_GOOD  # noqa: E402

SEARCH_DEG = (0.03, 0.05, 0.07, 0.1)
MIN_CHANGE_DEG = 0.1
STDS = 3.0


def changed_offsets(doc: dict, joint: str, change_deg: float, folder: Path):
    """The offsets file `doc` with `joint`'s offset (both of a shared motor's entries) changed, written and read back
    as verify reads it."""
    doc = copy.deepcopy(doc)
    joints = [j for j in LEG_JOINTS if j.endswith("HipYawPitch")] if joint.endswith("HipYawPitch") else [joint]
    for j in joints:
        doc["model"]["parameters"][f"joint_offset.{j}"]["value"] += math.radians(change_deg)
        doc["body"]["joint_offsets_rad"][j] += math.radians(change_deg)
    path = folder / f"{joint}{change_deg:+g}.json"
    path.write_text(json.dumps(doc))
    return read_offsets(path)


def outcome(dataset, offsets, joint: str | None) -> dict:
    result = verify_dataset(dataset, offsets, pixel_noise_px=dataset.meta.get("pixel_noise_px"))
    code = EXIT_GOOD if result.good else EXIT_DRIFTED
    motor = {f"joint {j}" for j in LEG_JOINTS if joint and (j == joint or (joint.endswith("HipYawPitch")
                                                                            and j.endswith("HipYawPitch")))}
    named = bool(result.suspects) and result.suspects[0] in motor
    return {"code": code, "ratio": result.ratio, "named": named, "found": code == EXIT_DRIFTED and named,
            "suspects": result.suspects[:3], "verdict": result.verdict}


def bench_run(run: Path, folder: Path) -> list[dict]:
    dataset = read_dataset(find_dataset(run))
    doc = json.loads((run / "offsets.json").read_text())
    seed = doc.get("source", {}).get("mock_seed")
    unchanged = outcome(dataset, read_offsets(run / "offsets.json"), None)
    rows = []
    for joint in LEG_JOINTS:
        std_deg = math.degrees(doc["model"]["parameters"][f"joint_offset.{joint}"]["std"])
        required = max(MIN_CHANGE_DEG, STDS * std_deg)
        at_required = {sign: outcome(dataset, changed_offsets(doc, joint, sign * required, folder), joint)
                       for sign in (+1, -1)}
        smallest = None
        for size in sorted(set(SEARCH_DEG) | {round(required, 4)}):
            got = outcome(dataset, changed_offsets(doc, joint, size, folder), joint)
            if got["found"]:
                smallest = (size, got)
                break
        rows.append({"seed": seed, "joint": joint, "std_deg": std_deg, "required_deg": required,
                     "at_required": at_required, "smallest": smallest, "unchanged": unchanged})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args(argv)
    cpu, wall = time.process_time(), time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in args.runs:
            rows += bench_run(run, Path(tmp))
    print("| seed | joint | std (deg) | required: max(0.1, 3 std) | + / - at required (exit, named) | smallest found "
          "(deg) | its ratio | unchanged: exit, ratio |")
    print("|---|---|---|---|---|---|---|---|")
    failures = 0
    for r in rows:
        plus, minus = r["at_required"][1], r["at_required"][-1]
        ok = plus["found"] and minus["found"] and r["unchanged"]["code"] == EXIT_GOOD
        failures += not ok
        small = f"{r['smallest'][0]:.2f}" if r["smallest"] else "none"
        small_ratio = f"{r['smallest'][1]['ratio']:.2f}" if r["smallest"] else "-"
        mark = lambda o: f"{o['code']}{', named' if o['named'] else ', NOT named: ' + ' '.join(o['suspects'])}"  # noqa
        print(f"| {r['seed']} | {r['joint']} | {r['std_deg']:.4f} | {r['required_deg']:.3f} | {mark(plus)} / "
              f"{mark(minus)} | {small} | {small_ratio} | {r['unchanged']['code']}, {r['unchanged']['ratio']:.2f} |")
    print(f"\n{len(rows)} changes, {failures} missed or false alarms; "
          f"{time.process_time() - cpu:.0f} s CPU, {time.perf_counter() - wall:.0f} s wall")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
