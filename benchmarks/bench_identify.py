"""Identification speed: naocal's solve against a straightforward implementation, same data, same run.

Dataset: the paper's size, 24 stances per leg x 3 head postures = 144 images, 3456 vertices, 0.1 px noise.
Straightforward: the 21-parameter model evaluated by a Python loop over images (per-image forward kinematics
and projection), finite-difference Jacobian, scipy.optimize.least_squares(method='lm').

    python benchmarks/bench_identify.py [--repeats 15] [--busy]

BLAS threads: as the environment says (numpy's default: one per core); `naocal` itself uses one
(OPENBLAS_NUM_THREADS=1, see tools/cli.py). `--busy` keeps the other core busy with a spinning process while the
naocal solves are timed, as NAOqi does on a robot: compare `python benchmarks/bench_identify.py --busy` with
`OPENBLAS_NUM_THREADS=1 python benchmarks/bench_identify.py --busy`.
"""

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.solver.identify import identify  # noqa: E402
from naocal.solver.kinematics import camera_fk, leg_fk  # noqa: E402
from naocal.solver.joints import HEAD_COLUMNS, LEG_COLUMNS, LEG_JOINTS  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402
from naocal.sim.synthetic import random_truth, synthesize  # noqa: E402
from naocal.solver.transforms import rot_x, rot_y, rot_z  # noqa: E402


def straightforward_residuals(x, data):
    """The paper's model, one image at a time (x: the 12 joint offsets c, camera roll, pitch, yaw, the boards)."""
    alpha = -x[:12]  # q_true = theta - c
    roll, pitch, yaw = x[12:15]
    R_off = rot_y(pitch) @ rot_x(roll) @ rot_z(yaw)
    out = []
    intr = data.intrinsics
    for m in range(data.n_images):
        leg = data.leg[m]
        rows = data.image_of_row == m
        q_leg = data.theta[m, LEG_COLUMNS[leg]] + (alpha[:6] if leg == "L" else alpha[6:])
        T_sole = leg_fk(q_leg[None], leg)[0]
        T_cam = camera_fk(data.theta[m, HEAD_COLUMNS][None])[0]
        R_cam = T_cam[:3, :3] @ R_off
        rz, bx, by = x[15:18] if leg == "L" else x[18:21]
        for p, uv in zip(data.p_mount[rows], data.uv_px[rows]):
            q = rot_z(rz) @ (p + np.array([bx, by, 0.0]))
            p_torso = T_sole[:3, :3] @ q + T_sole[:3, 3]
            pc = R_cam.T @ (p_torso - T_cam[:3, 3])
            out.append(intr["cx_px"] - intr["fx_px"] * pc[1] / pc[0] - uv[0])
            out.append(intr["cy_px"] - intr["fy_px"] * pc[2] / pc[0] - uv[1])
    return np.array(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--straightforward-repeats", type=int, default=3)
    parser.add_argument("--busy", action="store_true", help="a spinning process on the other core while timing")
    args = parser.parse_args()
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset (one per core)')}"
          + ("; the other core kept busy" if args.busy else ""))

    rng = np.random.default_rng(0)
    truth = random_truth(rng)
    data = synthesize(rng, truth, pixel_noise_px=0.1)
    registry = Registry()
    print(f"dataset: {data.n_images} images, {data.n_rows} vertices, {len(registry)} parameters")

    identify(data, registry)  # warm-up (imports, caches)
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if args.busy else None
    try:
        fast = [identify(data, registry).solve_time_s for _ in range(args.repeats)]
        result = identify(data, registry)
        minpack = [identify(data, registry, solver="minpack").solve_time_s for _ in range(args.repeats)]
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()

    slow, slow_x = [], None
    for _ in range(args.straightforward_repeats):
        start = time.perf_counter()
        sol = least_squares(straightforward_residuals, np.zeros(21), args=(data,), method="lm", jac="2-point",
                            x_scale=registry.scales)
        slow.append(time.perf_counter() - start)
        slow_x = sol.x
    agreement = np.max(np.abs(slow_x - result.values) / result.std)

    fast_ms, minpack_ms, slow_ms = (statistics.median(v) * 1e3 for v in (fast, minpack, slow))
    print(f"naocal identify (analytic Jacobian, naocal LM): median {fast_ms:8.2f} ms  (min {min(fast) * 1e3:.2f},"
          f" {result.iterations} iterations)")
    print(f"naocal model + scipy MINPACK LM:                median {minpack_ms:8.2f} ms")
    print(f"straightforward (loop, finite differences, LM): median {slow_ms:8.2f} ms")
    print(f"speed-up: {slow_ms / fast_ms:.0f}x (naocal LM), {slow_ms / minpack_ms:.0f}x (naocal model + MINPACK)")
    print(f"solutions agree to {agreement:.2g} standard deviations; RMS {result.rms_px[0]:.3f}, "
          f"{result.rms_px[1]:.3f} px")

    # The extended model's costliest term: elasticity makes the joint angles implicit (Newton per evaluation).
    elastic_registry = Registry(("elasticity",))
    truth.update({f"elasticity.{j}": 0.03 for j in LEG_JOINTS})
    elastic = synthesize(np.random.default_rng(1), truth, effects=("elasticity",), pixel_noise_px=0.1)
    identify(elastic, elastic_registry)
    times = [identify(elastic, elastic_registry).solve_time_s for _ in range(args.repeats)]
    print(f"naocal identify with elasticity ({len(elastic_registry)} parameters): median "
          f"{statistics.median(times) * 1e3:8.2f} ms")


if __name__ == "__main__":
    main()
