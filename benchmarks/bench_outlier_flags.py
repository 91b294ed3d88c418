"""Precision and recall of the outlier flags against the simulations' truth: which observations the fits set aside
as mis-detections, against which ones the simulation made wrong.

- dual arm (kinds/arm/sim.py simulate_dualarm, its `mistaken` truth: 2 % of the corner detections moved 8-40 px),
  fitted from the cameras alone as benchmarks/bench_dual_arm_residual.py fits them (every hidden effect), with
  every error of the simulation ("all") and with the joint offsets exact;
- the NAO's realistic mock (`naocal simulate`'s path, seeded: backends/mock_faults.py's FaultyDetector moves 0.4 %
  of the corners, a square off or 3-20 px; the faults it drew are its truth, matched to the dataset's corners by
  image time stamp, leg and vertex), then identified as `naocal identify DATASET` does (solver.fit.identify_dataset).
  A corner of an image set aside whole is counted as flagged; the captures taken while moving, which the fit sets
  aside (no time_lag), are left out of both counts. A "square" fault moved onto a neighbour's position is a true
  outlier too.

Each row: observations flagged, true outliers, flagged and true (tp), precision tp / flagged, recall tp / true, and
the largest final residual of a good observation flagged.

    python benchmarks/bench_outlier_flags.py [--arm-seeds 1 2 3] [--poses 60] [--nao-seeds 1 2] [--nao-dir DIR]
"""

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def row(label, flagged: set, true: set, good_sizes, cpu_s):
    tp = len(flagged & true)
    precision = tp / len(flagged) if flagged else 1.0
    recall = tp / len(true) if true else 1.0
    worst = f"{max(good_sizes):.3f}" if good_sizes else "-"
    print(f"{label:>34s} {len(flagged):7d} {len(true):5d} {tp:5d} {precision:9.3f} {recall:7.3f} {worst:>12s} "
          f"{cpu_s:6.1f}", flush=True)


def arm(seeds, poses, noise_px):
    from naocal.kinds.arm.identify import fit, initialise_sensors
    from naocal.kinds.arm.sim import CAMERA_FILING_ERROR, DUAL_HIDDEN, PRINT_SCALE_ERROR, dualarm_model, \
        simulate_dualarm

    effects = ("joint_offsets", "link_lengths", "tool", "points", "marker_scale", "intrinsics")
    for seed in seeds:
        for label, hidden in (("all", DUAL_HIDDEN), ("joint offsets exact",
                                                     tuple(h for h in DUAL_HIDDEN if h != "joint_offsets"))):
            cpu = time.process_time()
            sim = simulate_dualarm(None, seed=seed, n_poses=poses, noise_m=1e-5, noise_px=noise_px, write=False,
                                   hidden=hidden, camera_error=CAMERA_FILING_ERROR,
                                   print_scale_error=PRINT_SCALE_ERROR, outlier_fraction=0.02)
            cameras = [replace(s, noise=noise_px) for s in sim["sensors"] if s.kind == "camera"]
            rows = np.flatnonzero(sim["observations"].sensor < len(cameras))
            obs = sim["observations"].subset(rows)
            model = dualarm_model(effects, sensors=cameras)
            result = fit(model, obs, initialise_sensors(model, obs))
            key = lambda k: (obs.pose_name(obs.pose[k]), model.sensors[obs.sensor[k]].name,  # noqa: E731
                             model.point_names[obs.point[k]])
            true = {key(k) for k in np.flatnonzero(sim["mistaken"][rows])}
            flagged = {(o.pose, o.sensor, o.point): o.size for o in result.outliers}
            good = [size for k, size in flagged.items() if k not in true]
            row(f"arm seed {seed} {label} ({len(obs)})", set(flagged), true, good, time.process_time() - cpu)


def record_nao(seed, out: Path):
    """`naocal simulate --seed SEED` (realistic mock) into `out`, and out/corner_faults.json: the faults drawn."""
    from naocal.agent.calibrate import simulate
    from naocal.agent.measure import opencv_detector
    from naocal.agent.states import AgentSettings
    from naocal.backends.mock import MockBackend

    backend = MockBackend(seed, realism="realistic")
    try:
        detector = backend.faulty(opencv_detector)
        result, _ = simulate(backend, out, AgentSettings(seed=seed, progress_bar=False, save_images=False,
                                                         source=f"bench_outlier_flags seed {seed}"),
                             detector=detector)
    finally:
        backend.close()
    assert result.ok, result.reason
    faults = [{"t_image_s": t, "leg": leg, "vertex": f.vertex, "kind": f.kind} for t, leg, f in detector.faults]
    (out / "corner_faults.json").write_text(json.dumps(faults, indent=1) + "\n")


def nao(seeds, base: Path):
    from naocal.solver.dataset import read_dataset
    from naocal.solver.fit import identify_dataset

    for seed in seeds:
        out = base / f"nao-{seed}"
        cpu = time.process_time()
        if not (out / "corner_faults.json").exists():
            record_nao(seed, out)
        print(f"(nao seed {seed}: dataset {out}, {time.process_time() - cpu:.1f} s CPU)", flush=True)
        cpu = time.process_time()
        dataset = read_dataset(out)
        columns = dataset.as_v2().columns
        image = np.asarray(columns["image"], dtype=np.int64)
        vertex = np.asarray(columns["vertex"], dtype=np.int64)
        stamp = np.asarray(columns["t_image_s"], dtype=float)
        target = np.asarray(columns["target"])
        image_of = {(round(float(t), 6), str(g)): int(i) for t, g, i in zip(stamp, target, image)}
        vertices = set(zip(image.tolist(), vertex.tolist()))
        faults = json.loads((out / "corner_faults.json").read_text())
        true = {(image_of[(round(f["t_image_s"], 6), f["leg"])], f["vertex"]) for f in faults
                if (round(f["t_image_s"], 6), f["leg"]) in image_of}
        true &= vertices
        fit = identify_dataset(dataset)
        aside = {s.image for s in fit.images_set_aside}
        judged = set(fit.data.image_id.tolist()) | aside | {o.image for o in fit.outliers}  # not the moving ones
        vertices = {(i, v) for i, v in vertices if i in judged}
        true &= vertices
        flagged = {(o.image, o.vertex): o.size_px for o in fit.outliers}
        flagged.update({(i, v): float("nan") for i, v in vertices if i in aside})
        good = [s for k, s in flagged.items() if k not in true and np.isfinite(s)]
        row(f"nao seed {seed} ({len(vertices)}; {len(aside)} images aside)", set(flagged), true, good,
            time.process_time() - cpu)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm-seeds", type=int, nargs="*", default=[1, 2, 3])
    parser.add_argument("--poses", type=int, default=60)
    parser.add_argument("--noise-px", type=float, default=0.1)
    parser.add_argument("--nao-seeds", type=int, nargs="*", default=[1, 2])
    parser.add_argument("--nao-dir", type=Path, default=Path("runs/bench_outlier_flags"),
                        help="where the NAO datasets are recorded (reused when there)")
    args = parser.parse_args(argv)
    print(f"{'':>34s} {'flagged':>7s} {'true':>5s} {'tp':>5s} {'precision':>9s} {'recall':>7s} "
          f"{'worst good':>12s} {'CPU s':>6s}")
    arm(args.arm_seeds, args.poses, args.noise_px)
    nao(args.nao_seeds, args.nao_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
