"""The Duckiebot's wheels and ground homography: naocal's joint fit beside the seed paper's method (issue 23), on
logs of the independent OpenCV renderer (kinds/duckiebot/render.py), hidden robots seeds 1-5.

naocal: `identify_log` on a rendered log of `render.joint_program()` (boards while turning in one-wheel steps, then
the marker line driven forward in stops with turns, and back): intrinsics by held-out lens choice, then the joint
fit.
The paper (Chaika et al. 2021, steps 3-4; /docs/DUCKIEBOT.md): the same hidden robot, facing the marker line as the
log's marker phase starts, drives forward a fixed time with the right duty = kappa x the left, reads the nearest
marker's yaw before and after (markers on the floor through the same fitted camera, at the nominal camera mount: the
paper calibrates no extrinsics), solves dtheta = r dt u c (kappa - kappa_i) / b for the ratio kappa_i that would
drive straight (c = k / gain, Duckietown's nominal wheel speed per duty), kappa += (kappa_i / kappa - 1) / 2, drives
back; done after 3 successive corrections below EPSILON or MAX_ROUNDS rounds. trim = (kappa - 1) / (kappa + 1)
(gain 1, k 27: the paper estimates no speed). Its homography: the nominal camera mount with the fitted camera.

Measured, under each result, on the hidden robot (truth: Duckietown's forward kinematics, no PWM quantisation in
this renderer):
- trim error: |trim / gain - true trim / true gain| x true gain (in the log's k, as the fit's trim): what decides
  whether the compensated robot drives straight;
- deviation: the hidden robot commanded v = 0.3 m/s, omega = 0 through Duckietown's inverse kinematics with the
  result, lateral offset after 2 m of path;
- speed error: its true speed against 0.3 m/s;
- homography ground error: floor points 0.15-0.6 m ahead (|y| <= 0.15 m, in the image) seen by the TRUE camera,
  undistorted with the result's camera_intrinsic and mapped by its homography, RMS distance to the truth.

Rendered logs are cached outside git (NAOCAL_BENCH_CACHE, default /tmp/naocal-bench-duckiebot): about 12 s CPU to
render each. Run: `python benchmarks/bench_duckiebot.py [--seeds 1 2 3 4 5]`.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.duckiebot.calibration_files import apply_homography, ground_homography  # noqa: E402
from naocal.kinds.duckiebot.detect import detect_markers  # noqa: E402
from naocal.kinds.duckiebot.fit import marker_on_floor, pose_parameters  # noqa: E402
from naocal.kinds.duckiebot.identify import identify_log  # noqa: E402
from naocal.kinds.duckiebot.intrinsics import LensCamera, camera_difference_px  # noqa: E402
from naocal.kinds.duckiebot.kinematics import forward_kinematics, integrate_pose, inverse_kinematics  # noqa: E402
from naocal.kinds.duckiebot.render import (Renderer, calibration_scene, hidden_robot, joint_program,  # noqa: E402
                                    paper_program, render_drive_log, simulate_drive)
from naocal.kinds.duckiebot.robot import Kinematics, duckiebot  # noqa: E402
from naocal.solver.camera import undistort_points  # noqa: E402
from naocal.solver.transforms import invert_transform, transform_points  # noqa: E402

LOG_K = 27.0
SPEED_MPS = 0.3
PATH_M = 2.0
EPSILON = 0.002  # the paper's "correction below epsilon" on kappa
MAX_ROUNDS = 10
DRIVE_DUTY, DRIVE_S = 0.3, 0.3  # the paper's short drive: about 8 cm
SIZE = (640, 480)


def cache_dir() -> Path:
    return Path(os.environ.get("NAOCAL_BENCH_CACHE", "/tmp/naocal-bench-duckiebot"))


def rendered_log(seed: int) -> Path:
    path = cache_dir() / f"joint_seed{seed}"
    if not (path / "log.json").exists():
        render_drive_log(path, seed=seed, steps=joint_program())
    return path


def effective_truth(kin: Kinematics) -> tuple[float, float]:
    """(gain, trim) of the hidden robot in the log's k (w = u k / (gain +- trim))."""
    return kin.gain * LOG_K / kin.k, kin.trim * LOG_K / kin.k


def straight_drive(result: Kinematics, truth: Kinematics) -> tuple[float, float]:
    """(lateral deviation m after PATH_M of path, true speed m/s) of the hidden robot commanded SPEED_MPS straight
    with the compensation `result`."""
    u_left, u_right = inverse_kinematics(SPEED_MPS, 0.0, result)
    v, omega = forward_kinematics(u_left, u_right, truth)
    end = integrate_pose(np.zeros(3), v, omega, PATH_M / float(v))
    return abs(float(end[1])), float(v)


def homography_error_m(H, K, distortion, robot) -> float:
    x, y = np.meshgrid(np.linspace(0.15, 0.6, 19), np.linspace(-0.15, 0.15, 13))
    ground = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    p_cam = transform_points(invert_transform(robot.T_base_camera), ground)
    seen = robot.camera.project(p_cam)
    inside = (seen[:, 0] >= 0) & (seen[:, 0] <= 639) & (seen[:, 1] >= 0) & (seen[:, 1] <= 479)
    rectified = undistort_points(seen[inside], {"fx_px": K[0, 0], "fy_px": K[1, 1], "cx_px": K[0, 2],
                                                "cy_px": K[1, 2], "distortion": list(distortion)})
    error = np.linalg.norm(apply_homography(H, rectified) - ground[inside, :2], axis=1)
    return float(np.sqrt(np.mean(error ** 2)))


def paper_method(seed: int, lens, rng, robot=None) -> tuple[float, int, int]:
    """(kappa, rounds driven, rounds with a marker seen before and after) of the paper's k iteration on the hidden
    robot `seed` (or `robot`, a render.HiddenRobot: e.g. the PyBullet mock's, benchmarks/bench_duckiebot_mock.py),
    rendering each frame it grabs."""
    robot = hidden_robot(seed) if robot is None else robot
    scene = calibration_scene()
    renderer = Renderer(scene, robot.camera, robot.T_base_camera)
    facing = simulate_drive(paper_program(board_steps=0, marker_drives=0), robot.kinematics).frame_poses[-1]
    nominal = duckiebot("DB21")
    mount, K = nominal.T_base_camera, lens.K
    c = LOG_K / 1.0  # the nominal wheel speed per duty (gain 1)

    def look(pose):
        image = renderer.render(pose, rng)
        out = {}
        for s in detect_markers(image):
            normalised = lens.normalised(s.corners_px)
            uv = np.column_stack([K[0, 0] * normalised[:, 0] + K[0, 2], K[1, 1] * normalised[:, 1] + K[1, 2]])
            out[s.id] = marker_on_floor(uv, np.arange(4), K, mount, scene.marker_size_m)
        return out

    kappa, pose, quiet, rounds, measured = 1.0, facing.copy(), 0, 0, 0
    while rounds < MAX_ROUNDS and quiet < 3:
        rounds += 1
        before = look(pose)
        u_left, u_right = DRIVE_DUTY, min(1.0, kappa * DRIVE_DUTY)
        v, omega = forward_kinematics(u_left, u_right, robot.kinematics)
        pose = integrate_pose(pose, v, omega, DRIVE_S)
        after = look(pose)
        common = set(before) & set(after)
        if common:
            measured += 1
            nearest = min(common, key=lambda m: np.hypot(*before[m][:2]))
            dtheta = -math.remainder(after[nearest][2] - before[nearest][2], 2 * math.pi)  # the robot turns opposite
            kappa_i = kappa - dtheta * nominal.baseline_m / (nominal.radius_m * DRIVE_S * DRIVE_DUTY * c)
            correction = (kappa_i / kappa - 1.0) / 2.0
            kappa += correction
            quiet = quiet + 1 if abs(correction) < EPSILON else 0
        v, omega = forward_kinematics(-u_left, -u_right, robot.kinematics)
        pose = integrate_pose(pose, v, omega, DRIVE_S)
    return kappa, rounds, measured


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    rows, z_max, lens_rows = [], [], []
    print("| seed | method | trim error | 2 m deviation | speed error | homography RMS | z (max over kin. + "
          "camera pose) | CPU s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        robot = hidden_robot(seed)
        gain_true, trim_true = effective_truth(robot.kinematics)
        path = rendered_log(seed)
        start, wall = time.process_time(), time.perf_counter()
        cal = identify_log(path)
        cpu, wall = time.process_time() - start, time.perf_counter() - wall
        lens_rows.append((seed, cal.lens, cal.lens_fits, LensCamera.from_intrinsics(robot.camera)))
        fit = cal.drive_fit
        truth = {"gain": gain_true, "trim": trim_true, "baseline_m": robot.kinematics.baseline_m}
        truth.update(zip(("camera.x_m", "camera.y_m", "camera.z_m", "camera.roll_rad", "camera.pitch_rad",
                          "camera.yaw_rad"), pose_parameters(robot.T_base_camera)))
        z = {n: (fit.value(n) - v) / fit.stdev(n) for n, v in truth.items()}
        worst = max(z, key=lambda n: abs(z[n]))
        z_max.append(abs(z[worst]))
        files = cal.duckietown()
        kin = cal.kinematics
        trim_error = abs(kin.trim / kin.gain - trim_true / gain_true) * gain_true
        deviation, speed = straight_drive(kin, robot.kinematics)
        h_error = homography_error_m(files.homography, files.camera.K, files.camera.distortion, robot)
        rows.append(("naocal", trim_error, deviation, speed, h_error))
        print(f"| {seed} | naocal joint fit ({cal.lens.camera.model}, {len(fit.sightings.frame)} corners, "
              f"{len(fit.outliers.frame)} set aside) | {trim_error:.4f} (std {fit.stdev('trim'):.4f}) | "
              f"{deviation * 100:.1f} cm | {abs(speed / SPEED_MPS - 1) * 100:.2f} % | {h_error * 1000:.1f} mm | "
              f"{abs(z[worst]):.1f} ({worst}) | {cpu:.1f} | {wall:.1f} |")
        start, wall = time.process_time(), time.perf_counter()
        lens = cal.lens_fits["plumb_bob"].camera
        kappa, rounds, measured = paper_method(seed, lens, np.random.default_rng(seed + 2000))
        cpu, wall = time.process_time() - start, time.perf_counter() - wall
        trim = (kappa - 1.0) / (kappa + 1.0)
        paper = Kinematics(gain=1.0, trim=trim, k=LOG_K, baseline_m=duckiebot("DB21").baseline_m)
        trim_error = abs(trim - trim_true / gain_true) * gain_true
        deviation, speed = straight_drive(paper, robot.kinematics)
        H = ground_homography(duckiebot("DB21").T_base_camera, lens.K)
        h_error = homography_error_m(H, lens.K, lens.distortion[:5], robot)
        rows.append(("paper", trim_error, deviation, speed, h_error))
        print(f"| {seed} | paper's k iteration ({rounds} drives, {measured} with a marker before and after) | "
              f"{trim_error:.4f} | {deviation * 100:.1f} cm | {abs(speed / SPEED_MPS - 1) * 100:.1f} % | "
              f"{h_error * 1000:.1f} mm (nominal mount) | - | {cpu:.1f} | {wall:.1f} |")
    for method in ("naocal", "paper"):
        r = np.array([row[1:] for row in rows if row[0] == method])
        print(f"| all | {method} (max) | {r[:, 0].max():.4f} | {r[:, 1].max() * 100:.1f} cm | "
              f"{np.abs(r[:, 2] / SPEED_MPS - 1).max() * 100:.2f} % | {r[:, 3].max() * 1000:.1f} mm | "
              f"{max(z_max):.1f} |  |  |" if method == "naocal" else
              f"| all | {method} (max) | {r[:, 0].max():.4f} | {r[:, 1].max() * 100:.1f} cm | "
              f"{np.abs(r[:, 2] / SPEED_MPS - 1).max() * 100:.1f} % | {r[:, 3].max() * 1000:.1f} mm | - |  |  |")
    print_intrinsics(lens_rows)
    return 0


def print_intrinsics(lens_rows) -> None:
    """The intrinsics of each seed's identify_log beside the truth: every lens model's training and held-out RMS,
    and the camera's RMS difference from the truth over the whole image with the std its covariance implies."""
    print()
    print("| seed, views | model | training RMS | held-out RMS | whole image vs truth | its std | fx, fy, cx, cy "
          "error (std) px |")
    print("|---|---|---|---|---|---|---|")
    for seed, chosen, fits, truth in lens_rows:
        for i, (model, fit) in enumerate(fits.items()):
            error = camera_difference_px(truth, fit.camera, SIZE)
            k = fit.camera.parameters[:4] - truth.parameters[:4]
            pixels = ", ".join(f"{e:+.2f} ({s:.2f})" for e, s in zip(k, fit.std[:4]))
            print(f"| {f'{seed}, {fit.n_views}' if i == 0 else ''} | {model}{' (chosen)' if fit is chosen else ''} | "
                  f"{fit.train_rms_px:.3f} px | {fit.held_out_rms_px:.3f} px | {error:.2f} px | "
                  f"{fit.whole_image_std_px:.2f} px | {pixels} |")


if __name__ == "__main__":
    sys.exit(main())
