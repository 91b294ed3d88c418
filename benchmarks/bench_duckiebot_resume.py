"""A Duckiebot calibration stopped mid-drive, the robot carried elsewhere by hand, and resumed as on the real robot
(kinds/duckiebot/mission.py `restart_phase`: the phase starts again where the robot stands, the drive log gets a
break, the joint fit one anchor per segment), beside the same mission uninterrupted, on the realistic mock.

For each seed: the mission up to the identification, uninterrupted; then again, stopped (KeyboardInterrupt, as
Ctrl-C: the wheels stopped) in the marker drives' second leg out (its second stretch at duty 0.45), the mock
restored from its saved world and carried CARRY (forward, left m, turn rad), resumed. Printed: the joint fit's gain
and trim (the motors' slope) and the camera's pose on the body, each run's value and std, their difference in the
combined std (z), each against the truth; the breaks and the anchors; CPU and wall time.

Run: `python benchmarks/bench_duckiebot_resume.py [--seeds 1 2] [--mock realistic|ideal] [--out DIR]`.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.agent.machine import DONE, INTERRUPTED  # noqa: E402
from naocal.kinds.duckiebot.drive_log import read_drive_log  # noqa: E402
from naocal.kinds.duckiebot.fit import CAMERA  # noqa: E402
from naocal.kinds.duckiebot.mission import (Boards, CalibrateCamera, FaceMarkers, IdentifyDrive,  # noqa: E402
                                            MarkerDrives, MissionSettings, run_mission)
from naocal.kinds.duckiebot.mock import DuckiebotMock, truth_document  # noqa: E402

CARRY = (-0.03, 0.02, 0.1)  # 3 cm back, 2 cm left, 5.7 deg counter-clockwise
STATES = (Boards, CalibrateCamera, FaceMarkers, MarkerDrives, IdentifyDrive)
UP_TO_IDENTIFICATION = {("boards", "ok"): "camera", ("camera", "ok"): "face_markers",
                        ("face_markers", "ok"): "marker_drives", ("marker_drives", "ok"): "identification",
                        ("identification", "ok"): DONE}
COMPARED = ("gain", "trim") + CAMERA
STOP_DUTY, STOP_AT = 0.45, 2  # the second leg's duty (drive_duties[1]), its second stretch


class StoppedMidDrive:
    """The mock, stopped (KeyboardInterrupt: what Ctrl-C or SIGTERM raises) when it is to drive straight at
    STOP_DUTY for the STOP_AT-th time."""

    def __init__(self, robot):
        self.robot, self.seen = robot, 0

    def __getattr__(self, name):
        return getattr(self.robot, name)

    def advance(self, duration_s, poses=None):
        if np.allclose(self.robot.duties, STOP_DUTY):
            self.seen += 1
            if self.seen >= STOP_AT:
                raise KeyboardInterrupt("stopped mid-drive (benchmark)")
        self.robot.advance(duration_s, poses)


def mission(robot, out, **kw):
    return run_mission(robot, out, MissionSettings(), states=STATES, transitions=UP_TO_IDENTIFICATION, **kw)


def run_seed(seed: int, realism: str, root: Path) -> dict:
    whole_dir, resumed_dir = root / f"seed{seed}" / "whole", root / f"seed{seed}" / "resumed"
    for d in (whole_dir, resumed_dir):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
    cpu, wall = time.process_time(), time.perf_counter()
    robot = DuckiebotMock(seed, realism)
    try:
        result, whole = mission(robot, whole_dir)
        truth = truth_document(robot.truth, seed, realism)
    finally:
        robot.close()
    assert result.final == DONE, result.reason
    state = resumed_dir / "mock_state.json"
    robot = DuckiebotMock(seed, realism, state_path=state)
    try:
        stopped, _ = mission(StoppedMidDrive(robot), resumed_dir)
    finally:
        robot.close()
    assert stopped.final == INTERRUPTED and stopped.history[-1].state == "marker_drives", stopped.reason
    robot = DuckiebotMock(seed, realism, state_path=state)  # a new process: the mock restored where it stopped
    try:
        robot.carry(*CARRY)
        result, resumed = mission(robot, resumed_dir, restart_phase=True)
    finally:
        robot.close()
    assert result.final == DONE, result.reason
    a, b = whole.calibration.drive_fit, resumed.calibration.drive_fit
    rows = {}
    for name in COMPARED:
        true = truth["parameters"][name]["value"]
        rows[name] = {"whole": a.value(name), "whole_std": a.stdev(name), "resumed": b.value(name),
                      "resumed_std": b.stdev(name), "truth": true,
                      "z_between": (b.value(name) - a.value(name)) / np.hypot(a.stdev(name), b.stdev(name))}
    log = read_drive_log(resumed_dir / "log", check_images=False)
    return {"seed": seed, "parameters": rows, "breaks_s": log.segment_t_s.tolist(), "anchors_s": b.anchors,
            "frames": {"whole": len(whole.session.log.frames), "resumed": len(log.frame_files)},
            "rms_px": {"whole": a.rms_px, "resumed": b.rms_px},
            "cpu_s": time.process_time() - cpu, "wall_s": time.perf_counter() - wall}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--mock", default="realistic", choices=("realistic", "ideal"))
    parser.add_argument("--out", type=Path, default=Path("/tmp/naocal-bench-duckiebot-resume"))
    args = parser.parse_args(argv)
    for seed in args.seeds:
        r = run_seed(seed, args.mock, args.out)
        print(f"seed {seed} ({args.mock}): breaks {r['breaks_s']}, anchors {r['anchors_s']}, frames {r['frames']}, "
              f"RMS px {r['rms_px']['whole']:.3f} / {r['rms_px']['resumed']:.3f}, {r['cpu_s']:.0f} s CPU, "
              f"{r['wall_s']:.0f} s wall")
        print(f"  {'parameter':18s} {'uninterrupted':>22s} {'resumed':>22s} {'z between':>9s} {'truth':>10s}")
        for name, p in r["parameters"].items():
            print(f"  {name:18s} {p['whole']:+.5f} +- {p['whole_std']:.5f}   {p['resumed']:+.5f} +- "
                  f"{p['resumed_std']:.5f} {p['z_between']:+9.2f} {p['truth']:+10.5f}")
        (args.out / f"seed{seed}" / "result.json").write_text(json.dumps(r, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
