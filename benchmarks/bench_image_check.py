"""The check of whole images before a fit (solver.image_check.check_images): its time against the straightforward
per-image one (OpenCV's least-squares findHomography and the same tests, image by image) and against the
identification it guards (solver.fit.identify_dataset's default fit), on the same data in the same run.

Datasets: the paper's plan (144 images, 3456 vertices, 0.1 px noise) and larger synthetic plans (24 corners an image).

    python benchmarks/bench_image_check.py [--stances 24,400] [--repeats 5]

BLAS threads: one (as `naocal` runs).
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def straightforward(data):
    """Image by image: OpenCV's least-squares homography, its residuals, the spread and orientation tests."""
    import cv2
    import numpy as np

    from naocal.solver.camera import undistort_points
    from naocal.solver.image_check import _board_coordinates

    board = _board_coordinates(data)
    bad = []
    for m in range(data.n_images):
        rows = np.flatnonzero(data.image_of_row == m)
        uv = undistort_points(data.uv_px[rows], data.cameras[data.camera[m]])
        spread = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False)
        H, _ = cv2.findHomography(board[rows], uv, 0)
        p = board[rows] @ H[:2, :2].T + H[:2, 2]
        w = board[rows] @ H[2, :2] + H[2, 2]
        distance = np.linalg.norm(p / w[:, None] - uv, axis=1)
        if spread[1] < 0.5 or np.linalg.det(H) * w[0] >= 0 or np.sum(distance > 3.0) > len(rows) / 3:
            bad.append(m)
    return bad


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stances", default="24,400", help="stances per leg (3 head postures each)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    import numpy as np

    from naocal.sim.synthetic import dataset_parts, random_truth, synthesize
    from naocal.solver.fit import identify_dataset
    from naocal.solver.image_check import check_images

    for stances in (int(s) for s in args.stances.split(",")):
        rng = np.random.default_rng(0)
        data = synthesize(rng, random_truth(rng), n_stances_per_leg=stances, n_head_postures=3, pixel_noise_px=0.1)
        check_images(data), straightforward(data)  # warm (OpenCV's import)
        ours = timed(lambda: check_images(data), args.repeats)
        plain = timed(lambda: straightforward(data), max(1, args.repeats // 2))
        line = (f"{data.n_rows} vertices, {data.n_images} images: check_images {ours * 1e3:.1f} ms "
                f"({ours / data.n_rows * 1e6:.2f} us/vertex), image by image {plain * 1e3:.1f} ms (x{plain / ours:.1f})")
        if stances <= 24:
            from naocal.solver.dataset import Dataset

            meta, columns = dataset_parts(data, pixel_noise_px=0.1)
            dataset = Dataset(meta, columns)
            fit = timed(lambda: identify_dataset(dataset), 1)
            line += f"; identify_dataset {fit * 1e3:.0f} ms (the check {100 * ours / fit:.1f} % of it)"
        print(line, flush=True)


if __name__ == "__main__":
    main()
