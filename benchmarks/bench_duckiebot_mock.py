"""The Duckiebot calibrated end to end on the realistic PyBullet mock (kinds/duckiebot/mock.py) by its mission
(kinds/duckiebot/mission.py), seeds 1-5, each beside the seed paper's k iteration on the same hidden robot
(benchmarks/bench_duckiebot.py's `paper_method`, on the OpenCV renderer, from the mission's own plumb_bob lens).

Measured under each result, on the hidden robot (the truth: DuckiebotTruth.kinematics_at(0.3), what Duckietown's
inverse kinematics needs to drive it 0.3 m/s straight, the PWM floor averaged; truth.json's `kinematics`):
- deviation: the mock itself (PyBullet, PWM quantisation, the motors' start, lag, slip) placed anew, commanded
  0.3 m/s straight through Duckietown's inverse kinematics with the result until 2 m from its start: its signed
  lateral offset there (left +), beside the same drive compensated with the TRUE parameters; then over 9 speeds
  within +-2 % of 0.3 m/s (each floors the two wheels' PWM differently): the mean (the calibration's own drift:
  the PWM floor's luck averages out) / the largest; the bound the PWM floor allows at 0.3 m/s
  (kinematics.pwm_drift_bound_m: the wheels one PWM step apart); the result's deviation on the exact forward
  kinematics (no PWM: bench_duckiebot.straight_drive);
- speed: its mean speed over the last 1.5 m against 0.3 m/s;
- trim error: |trim - true trim| (in the log's k);
- intrinsics: kinds.duckiebot.intrinsics.camera_difference_px of the chosen lens against the true camera, over the
  whole image, beside its std from the fit (LensFit.whole_image_std_px);
- homography: bench_duckiebot.homography_error_m (floor 0.15-0.6 m ahead, |y| <= 0.15 m);
- robot time: the mock's clock at the end of the identification (calibration) and at the end of the mission;
- z: the largest |error / std| over the joint fit's gain and trim (the motors' slope), dead_zone, baseline and the
  camera's six pose parameters, against truth.json's `parameters`; each one's signed z on the row below.
CPU and wall time of the whole mission (rendering, detection, the fits). Runs are kept in NAOCAL_BENCH_CACHE
(default /tmp/naocal-bench-duckiebot-mock); `--fresh` runs again.

Run: `python benchmarks/bench_duckiebot_mock.py [--seeds 1 2 3 4 5] [--mock realistic|ideal]`.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_duckiebot import homography_error_m, paper_method, straight_drive  # noqa: E402
from naocal.kinds.duckiebot.calibration_files import ground_homography  # noqa: E402
from naocal.kinds.duckiebot.intrinsics import LensCamera, camera_difference_px  # noqa: E402
from naocal.kinds.duckiebot.kinematics import inverse_kinematics, pwm_drift_bound_m  # noqa: E402
from naocal.kinds.duckiebot.mission import MissionSettings, run_mission  # noqa: E402
from naocal.kinds.duckiebot.mock import LOG_K, DuckiebotMock, truth_document  # noqa: E402
from naocal.kinds.duckiebot.robot import Kinematics, duckiebot  # noqa: E402

SPEED_MPS, PATH_M = 0.3, 2.0
SWEEP = SPEED_MPS * np.linspace(0.98, 1.02, 9)  # within the 2 % of 0.3 m/s: about 3 PWM steps


def cache_dir() -> Path:
    return Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot-mock"))


def drive_on_mock(seed: int, realism: str, kin: Kinematics, speed_mps: float = SPEED_MPS) -> tuple[float, float]:
    """(signed lateral deviation m (left +) at PATH_M from the start, mean speed m/s over the last 1.5 m) of the mock
    robot `seed` commanded `speed_mps` straight through Duckietown's inverse kinematics with `kin`."""
    robot = DuckiebotMock(seed, realism, supersample=1)
    try:
        left, right = inverse_kinematics(speed_mps, 0.0, kin)
        robot.command(float(left), float(right))
        start, marks = robot.pose(), []
        while np.linalg.norm(robot.pose()[:2] - start[:2]) < PATH_M and robot.now() < 60.0:
            robot.advance(0.01)
            marks.append((robot.now(), np.linalg.norm(robot.pose()[:2] - start[:2])))
        robot.command(0.0, 0.0)
        end = robot.pose()
        t, d = np.array(marks).T
        i = np.searchsorted(d, 0.5)
        speed = (d[-1] - d[i]) / (t[-1] - t[i])
        c, s = np.cos(start[2]), np.sin(start[2])
        return float(-s * (end[0] - start[0]) + c * (end[1] - start[1])), float(speed)
    finally:
        robot.close()


def sweep(seed: int, realism: str, kin: Kinematics) -> np.ndarray:
    """The signed 2 m deviations at SWEEP speeds: the PWM floor's luck changes from one to the next (a step is
    0.5 % of the duty), the calibration's own drift does not: their mean is the calibration's."""
    return np.array([drive_on_mock(seed, realism, kin, v)[0] for v in SWEEP])


def cm_sweep(deviations) -> str:
    return f"{100 * np.mean(deviations):+.1f} / {100 * np.max(np.abs(deviations)):.1f}"


def run_seed(seed: int, realism: str, fresh: bool):
    out = cache_dir() / f"{realism}_seed{seed}"
    if fresh and out.exists():
        shutil.rmtree(out)
    if out.exists():  # an earlier run: resume finishes it (replaying the log), or replays a finished one
        pass
    robot = DuckiebotMock(seed, realism, state_path=out / "mock_state.json")
    cpu, wall = time.process_time(), time.perf_counter()
    try:
        result, ctx = run_mission(robot, out, MissionSettings(), robot_id=f"mock{seed}",
                                  source=f"benchmarks/bench_duckiebot_mock.py seed {seed}")
    finally:
        robot.close()
    identified_at = next((s for s in result.history if s.state == "identification"), None)
    robot_calibration_s = sum(s.robot_s for s in result.history[:result.history.index(identified_at) + 1]) \
        if identified_at else float("nan")
    return robot, result, ctx, time.process_time() - cpu, time.perf_counter() - wall, robot_calibration_s


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--mock", choices=("realistic", "ideal"), default="realistic")
    parser.add_argument("--fresh", action="store_true", help="run the missions again (not from the cache)")
    args = parser.parse_args(argv)
    print("| seed | method | final | trim error (std) | 2 m on the mock at 0.3 m/s: result (truth) | over 0.3 m/s +-2 %: "
          "result mean / max (truth's) | PWM floor's bound | exact kinematics | speed error | intrinsics RMS | "
          "homography RMS | robot time calib. / all | z (max) | CPU s / wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        robot, result, ctx, cpu, wall, robot_cal_s = run_seed(seed, args.mock, args.fresh)
        truth = robot.truth
        true_kin = truth.kinematics_at(SPEED_MPS)  # what drives it 0.3 m/s straight (the PWM floor averaged)
        floor_dev, _ = drive_on_mock(seed, args.mock, true_kin)
        floor_sweep = sweep(seed, args.mock, true_kin)
        duty = float(np.mean(inverse_kinematics(SPEED_MPS, 0.0, true_kin)))
        bound = pwm_drift_bound_m(duty, truth.duty_offset(), truth.baseline_m, PATH_M) if truth.pwm_driver else 0.0
        cal = ctx.calibration
        if cal is None:
            print(f"| {seed} | naocal mission | {result.final}: {result.reason[:120]} | | ({100 * floor_dev:+.1f} cm) | "
                  f"({cm_sweep(floor_sweep)} cm) | {100 * bound:.1f} cm | | | | | {robot.now():.0f} s | | "
                  f"{cpu:.0f} / {wall:.0f} |")
            continue
        kin, fit = cal.kinematics, cal.drive_fit
        trim_error = abs(kin.trim - true_kin.trim)
        dev, speed = drive_on_mock(seed, args.mock, kin)
        result_sweep = sweep(seed, args.mock, kin)
        exact_dev, _ = straight_drive(kin, true_kin)
        true_lens = LensCamera.from_intrinsics(truth.camera)
        intrinsics_px = camera_difference_px(cal.lens.camera, true_lens, (640, 480))
        files = cal.duckietown()
        hidden = truth.hidden_robot()
        h_error = homography_error_m(files.homography, files.camera.K, files.camera.distortion, hidden)
        document = truth_document(truth, seed, args.mock)
        values = {n: v["value"] for n, v in document["parameters"].items() if n in fit.names}
        z = {n: (fit.value(n) - v) / fit.stdev(n) for n, v in values.items()}
        worst = max(z, key=lambda n: abs(z[n]))
        validation = ctx.validation or {}
        print(f"| {seed} | naocal mission ({cal.lens.camera.model}, {len(fit.sightings.frame)} corners) | "
              f"{result.final} | {trim_error:.4f} ({fit.stdev('trim'):.4f}) | {dev * 100:+.1f} cm "
              f"({floor_dev * 100:+.1f} cm) | {cm_sweep(result_sweep)} cm ({cm_sweep(floor_sweep)} cm) | "
              f"{100 * bound:.1f} cm | {exact_dev * 100:.1f} cm | {abs(speed / SPEED_MPS - 1) * 100:.2f} % | "
              f"{intrinsics_px:.2f} px ({cal.lens.whole_image_std_px:.2f}) | {h_error * 1000:.1f} mm | "
              f"{robot_cal_s:.0f} s / {robot.now():.0f} s | "
              f"{abs(z[worst]):.1f} ({worst}) | {cpu:.0f} / {wall:.0f} |")
        print(f"|  | (z per parameter: {', '.join(f'{n} {v:+.1f}' for n, v in z.items())}) | | | | | | | | | | | | |")
        if validation:
            print(f"|  | (the mission's validation: {100 * validation['deviation_m']:+.1f} cm at "
                  f"{validation.get('measured_at_m', validation['driven_m']):.2f} m, PWM bound "
                  f"{100 * validation.get('pwm_bound_m', float('nan')):.1f} cm) | | | | | | | | | | | | |")
        cpu0 = time.process_time()
        lens = cal.lens_fits["plumb_bob"].camera
        kappa, rounds, measured = paper_method(seed, lens, np.random.default_rng(seed + 2000), robot=hidden)
        paper_cpu = time.process_time() - cpu0
        trim = (kappa - 1.0) / (kappa + 1.0)
        paper = Kinematics(gain=1.0, trim=trim, k=LOG_K, baseline_m=duckiebot("DB21").baseline_m)
        p_trim_error = abs(trim - true_kin.trim / true_kin.gain) * true_kin.gain
        p_dev, p_speed = drive_on_mock(seed, args.mock, paper)
        p_exact, _ = straight_drive(paper, true_kin)
        H = ground_homography(duckiebot("DB21").T_base_camera, lens.K)
        p_h = homography_error_m(H, lens.K, lens.distortion[:5], hidden)
        print(f"| {seed} | paper's k iteration ({rounds} drives, {measured} measured; renderer) | - | "
              f"{p_trim_error:.4f} | {p_dev * 100:+.1f} cm | | | {p_exact * 100:.1f} cm | "
              f"{abs(p_speed / SPEED_MPS - 1) * 100:.1f} % | (same camera) | {p_h * 1000:.1f} mm (nominal mount) | "
              f"- | - | {paper_cpu:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
