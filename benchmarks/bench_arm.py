"""Arm identification time and memory: naocal's fit against a straightforward implementation, same data, same run.

Data: the Franka Panda (pybullet_data's URDF), joint offsets and link lengths hidden (0.01-0.5 deg, 0.1-2 mm), a
tracker seeing 3 reflectors (0.1 mm noise) and a camera 4 markers (0.2 px) at each of 100 / 1000 / 10000 random
stances; the measurements are naocal's own model at the truth plus noise (kinds/arm/model.py).

naocal: kinds.arm.identify.fit (its identifiability check, Levenberg-Marquardt with the analytic Jacobian,
standard deviations and weak directions). Straightforward: scipy.optimize.least_squares(method='lm') on the same
whitened residuals and the same free parameters with a finite-difference Jacobian ('2-point'), nothing else.
Memory: tracemalloc's peak (numpy reports its arrays to it) in a second run of each.

    python benchmarks/bench_arm.py [--poses 100,1000,10000] [--repeats 3]
"""

import argparse
import math
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.arm.model import ArmModel, Observations, Sensor, exp_so3  # noqa: E402
from naocal.kinds.arm.dataset import arm_chain, resolve_robot  # noqa: E402
from naocal.kinds.arm.identify import fit, initialise_sensors, whitened  # noqa: E402

CAMERA = {"width_px": 1280, "height_px": 1024, "fx_px": 1400.0, "fy_px": 1400.0, "cx_px": 639.5, "cy_px": 511.5,
          "distortion": [0.0] * 5}
POINTS = {"t1": (0.1, 0.0, 0.05), "t2": (-0.05, 0.087, 0.05), "t3": (-0.05, -0.087, 0.05),
          "m1": (0.03, 0.03, 0.06), "m2": (-0.03, 0.03, 0.06), "m3": (0.03, -0.03, 0.06), "m4": (-0.03, -0.03, 0.07)}


def dataset(n_poses, seed=0):
    """(model with R0 reset, observations, true parameter values) of the panda."""
    urdf, base, tip = resolve_robot("franka_panda", None)
    chain, names, load = arm_chain(urdf, base, tip, urdf)
    rng = np.random.default_rng(seed)
    sensors = [Sensor("tracker", "points", noise=1e-4), Sensor("camera", "camera", dict(CAMERA), 0.2)]
    model = ArmModel(chain, POINTS, sensors, ("joint_offsets", "link_lengths"), load=load, link_names=names)
    lo = np.array([-2.5, -1.5, -2.5, -2.8, -2.5, 0.3, -2.5])
    hi = np.array([2.5, 1.5, 2.5, -0.4, 2.5, 3.4, 2.5])
    theta = rng.uniform(lo, hi, (n_poses, 7))
    rows = [(i, 0, p) for i in range(n_poses) for p in range(3)] + [(i, 1, p) for i in range(n_poses)
                                                                    for p in range(3, 7)]
    rows = np.array(rows)
    obs = Observations(theta[rows[:, 0]], rows[:, 0], rows[:, 1], rows[:, 2], np.zeros((len(rows), 3)))
    x = np.zeros(len(model.names))
    for i, p in enumerate(model.parameters):
        if p.effect == "joint_offsets":
            x[i] = math.radians(rng.uniform(0.01, 0.5)) * rng.choice((-1, 1))
        elif p.effect == "link_lengths":
            x[i] = rng.uniform(1e-4, 2e-3) * rng.choice((-1, 1))
        elif p.effect == "sensors" and p.axis < 3:  # a sensor's translation
            x[i] = ((1.5, -2.0, 0.3), (2.5, 0.1, -0.4))[p.index][p.axis]
    model.R0[0] = exp_so3(np.array([0.4, -0.3, 1.2]))
    model.R0[1] = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])  # looks back at the arm
    pred = model.predict(x, obs)
    noise = np.where(obs.sensor[:, None] == 0, 1e-4, 0.2) * rng.normal(size=pred.shape)
    noise[obs.sensor == 1, 2] = 0.0
    obs.measured = pred + noise
    keep = (obs.sensor == 0) | ((pred[:, 0] > 0) & (pred[:, 0] < 1280) & (pred[:, 1] > 0) & (pred[:, 1] < 1024))
    obs = obs.subset(keep)
    model.R0[:] = np.eye(3)
    return model, obs, dict(zip(model.names, x))


def run_naocal(model, obs):
    return fit(model, obs, initialise_sensors(model, obs))


def run_straightforward(model, obs, x0, free, sigma):
    idx = np.flatnonzero(free)

    def fun(z):
        x = x0.copy()
        x[idx] = z
        return whitened(model, obs, x, sigma)

    result = least_squares(fun, x0[idx], jac="2-point", method="lm", x_scale=model.scales[idx], xtol=1e-12,
                           ftol=1e-12, gtol=1e-12)
    x = x0.copy()
    x[idx] = result.x
    return x, result


def peak_mib(call):
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1] / 2 ** 20
    finally:
        tracemalloc.stop()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", default="100,1000,10000")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"{'poses':>6} {'obs':>7} {'naocal s':>9} {'FD s':>8} {'ratio':>6} {'naocal MiB':>11} {'FD MiB':>8} "
          f"{'ratio':>6}  max |difference| of the results, worst error vs truth")
    for n in [int(v) for v in args.poses.split(",")]:
        model, obs, truth = dataset(n)
        times_n, times_f = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            result = run_naocal(model, obs)
            times_n.append(time.perf_counter() - start)
            model.R0[:] = np.eye(3)
        # the straightforward fit starts where naocal's does (its sensor frames) with naocal's free parameters
        x0 = initialise_sensors(model, obs)
        for _ in range(args.repeats):
            start = time.perf_counter()
            x_f, res_f = run_straightforward(model, obs, x0, result.free, result.sigma)
            times_f.append(time.perf_counter() - start)
        model.R0[:] = np.eye(3)
        mem_n = peak_mib(lambda: run_naocal(model, obs))
        model.R0[:] = np.eye(3)
        x0 = initialise_sensors(model, obs)
        mem_f = peak_mib(lambda: run_straightforward(model, obs, x0, result.free, result.sigma))
        arm = [i for i, p in enumerate(model.parameters) if p.effect != "sensors" and result.free[i]]
        diff = float(np.max(np.abs(result.x[arm] - x_f[arm]) / model.scales[arm]))
        worst = max(abs(result.x[i] - truth[model.names[i]]) / (1e-4 if model.parameters[i].unit == "m"
                                                                else math.radians(0.01)) for i in arm)
        tn, tf = statistics.median(times_n), statistics.median(times_f)
        print(f"{n:>6} {len(obs):>7} {tn:>9.3f} {tf:>8.3f} {tf / tn:>6.1f} {mem_n:>11.1f} {mem_f:>8.1f} "
              f"{mem_f / mem_n:>6.2f}  {diff:.1e} (scaled), {worst:.2f} of the tolerance (0.1 mm, 0.01 deg); "
              f"FD {res_f.nfev} evaluations", flush=True)


if __name__ == "__main__":
    main()
