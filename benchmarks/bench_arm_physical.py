"""Where diagnose's physical check should call a held-out RMS "worse" (kinds.arm.diagnose.HELDOUT_TOLERANCE).

The simulated dual-arm robot (kinds/arm/sim.py simulate_dualarm: two torso cameras, a tracker, markers and the
reflector glued 1-2 mm off, tool mounts off, 2 % wrong detections). Each significant candidate is judged on data its
fit did not see (kinds.arm.diagnose.physical_checks: the tracker with the arm fitted from the cameras, the cameras
with the arm fitted from the tracker, each camera with the arm fitted from the other, blocks of poses held out); a
check is "worse" when a held-out RMS grows by more than the tolerance. Two kinds of candidate, by construction:

- physical (the robot has it): the model lacks one effect the simulation hid, `link_lengths` (0.02-0.2 mm: small,
  where a tight tolerance refutes by chance) or `tool` (1-3 mm, 0.2-0.6 deg); refuting one is a FALSE ALARM;
- fooled (the robot has none; it would absorb a sensor-model error): cam_left's focal length 1 % off what the model is
  told, the model complete, candidates `elasticity` and `link_poses`; passing one is a MISS.

Each check's ratio (with / without, the largest over its sensors) is computed once; the sweep counts, for each
tolerance, the false alarms and misses over the seeds; then, at the tolerance diagnose uses with its chance bounds, how
many of each kind are confirmed, not confirmed and refuted (a physical one refuted: a false alarm; a fooled one
confirmed: a false confirmation).

    python benchmarks/bench_arm_physical.py [--seeds 1 2 3 4] [--poses 200]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.arm.sim import dualarm_model, simulate_dualarm  # noqa: E402
from naocal.kinds.arm.model import Sensor  # noqa: E402
from naocal.kinds.arm.diagnose import HELDOUT_TOLERANCE, Test, physical_checks  # noqa: E402
from naocal.kinds.arm.identify import fit, initialise_sensors  # noqa: E402

FULL = ("joint_offsets", "link_lengths", "tool", "points")
FOCAL_ERROR = 0.01
# (case, model effects, candidates, physical?, cam_left's focal length error)
CASES = [("link lengths missing", ("joint_offsets", "tool", "points"), ("link_lengths",), True, 0.0),
         ("tool missing", ("joint_offsets", "link_lengths", "points"), ("tool",), True, 0.0),
         ("cam_left focal 1 % off", FULL, ("elasticity", "link_poses"), False, FOCAL_ERROR)]
TOLERANCES = (0.0, 0.005, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2)


def focal_off(sensors, error):
    return [Sensor(s.name, s.kind, {**s.intrinsics, "fx_px": s.intrinsics["fx_px"] * (1 + error),
                                    "fy_px": s.intrinsics["fy_px"] * (1 + error)}, s.noise, link=s.link)
            if s.name == "cam_left" and error else s for s in sensors]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--poses", type=int, default=200)
    args = parser.parse_args()
    t0, c0 = time.time(), time.process_time()
    judged = []  # (case, seed, candidate, physical?, {check kind: ratio})
    for seed in args.seeds:
        sim = simulate_dualarm(None, seed=seed, n_poses=args.poses, write=False)
        obs = sim["observations"]
        for case, effects, labels, physical, focal in CASES:
            model = dualarm_model(effects, sensors=focal_off(sim["sensors"], focal))
            fitted = fit(model, obs, initialise_sensors(model, obs))
            candidates = [Test(label, 1, 0.0, 0.0, 1.0, fitted.rms(), {}, significant=True) for label in labels]
            physical_checks(fitted, candidates)
            for c in candidates:
                ratios = {}
                for check in c.checks:
                    ratio = max(check.with_effect[s] / check.without[s] for s in check.with_effect)
                    ratios[check.kind] = max(ratio, ratios.get(check.kind, 0.0))
                standing = ("refuted", "not confirmed", "confirmed")[(c.physical is not False) + bool(c.confirmed)]
                judged.append((case, seed, c.label, physical, ratios, standing))
                print(f"seed {seed} {case:24s} {c.label:13s} {'physical' if physical else 'fooled  '} " + "  ".join(
                    f"{kind} {ratio:.3f}" for kind, ratio in ratios.items()) + f"  -> {standing}", flush=True)
    print(f"\n{len(judged)} candidates judged ({sum(j[3] for j in judged)} physical, "
          f"{sum(not j[3] for j in judged)} fooled); {time.time() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU")
    kinds = ("sensor", "reverse", "camera", "session")
    print("\n| tolerance | false alarms (physical refuted) | misses (fooled passed) | false alarms by check: "
          + ", ".join(kinds) + " | misses if only that check |")
    print("|---:|---:|---:|---|---|")
    for tol in TOLERANCES:
        worse = [{k for k, r in ratios.items() if r > 1 + tol} for *_, ratios, _ in judged]
        alarms = sum(1 for j, w in zip(judged, worse) if j[3] and w)
        misses = sum(1 for j, w in zip(judged, worse) if not j[3] and not w)
        by_kind = ", ".join(str(sum(1 for j, w in zip(judged, worse) if j[3] and k in w)) for k in kinds)
        alone = ", ".join(str(sum(1 for j, w in zip(judged, worse) if not j[3] and k not in w)) for k in kinds)
        mark = " (now)" if tol == HELDOUT_TOLERANCE else ""
        print(f"| {tol:.1%}{mark} | {alarms} | {misses} | {by_kind} | {alone} |")
    print("\nWith the chance bounds (diagnose's verdict: worse beyond the tolerance and chance; confirmed: the deciding "
          "check better beyond chance):")
    for physical in (True, False):
        counts = {w: sum(1 for j in judged if j[3] == physical and j[5] == w)
                  for w in ("confirmed", "not confirmed", "refuted")}
        print(f"  {'physical' if physical else 'fooled'}: " + ", ".join(f"{w} {n}" for w, n in counts.items()))


if __name__ == "__main__":
    main()
