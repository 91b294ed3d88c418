"""The Duckiebot's intrinsics on mission runs of the realistic mock: where over the image the fitted lens is off the
true camera, beside the std the fit gives (issue 23's goal: within 0.5 px RMS over the whole image).

For each run directory (`naocal calibrate --robot duckiebot --backend mock --seed N --out DIR`: DIR/log and
DIR/truth.json; or a bench_duckiebot_mock.py cache folder `realistic_seedN`, its truth drawn again from N): detects
the log (kinds.duckiebot.identify.detect_log), fits the lens (identify.fit_intrinsics: boards and floor markers,
the model by held-out error), and prints per model the whole-image RMS against the truth
(intrinsics.camera_difference_px) with its std (LensFit.whole_image_std_px), and for the chosen model the RMS in each
cell of a 4 x 4 grid over the image beside where the board corners and the floor markers' usable corners lie.
Reads the runs, writes nothing. About 60-90 s CPU a run (detection most of it).

Run: `python benchmarks/bench_duckiebot_lens.py DIR [DIR ...]`.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import naocal.tools.cli  # noqa: E402,F401  (one BLAS thread, as the command line)
from naocal.kinds.duckiebot.drive_log import read_drive_log  # noqa: E402
from naocal.kinds.duckiebot.identify import detect_log, fit_intrinsics, marker_sightings  # noqa: E402
from naocal.kinds.duckiebot.intrinsics import FloorMarkers, LensCamera, _grid_rays, camera_difference_px  # noqa: E402
from naocal.kinds.duckiebot.mock import draw_truth  # noqa: E402
from naocal.kinds.duckiebot.robot import nominal_for  # noqa: E402

CELLS = 4


def true_camera(run: Path) -> LensCamera:
    if (run / "truth.json").exists():
        lens = json.loads((run / "truth.json").read_text())["camera"]["lenses"]["plumb_bob"]
        return LensCamera("plumb_bob", np.array(lens["K"]), np.array(lens["distortion"]))
    seed = re.fullmatch(r"realistic_seed(\d+)", run.name)
    if not seed:
        raise SystemExit(f"{run}: no truth.json, and not a bench_duckiebot_mock.py cache folder (realistic_seedN)")
    return LensCamera.from_intrinsics(draw_truth(int(seed.group(1))).camera)


def cells(uv, size, values=None) -> np.ndarray:
    """(CELLS, CELLS) rows top to bottom: the count of the points uv in each cell, or the RMS of `values` there."""
    w, h = size
    i = np.minimum((uv[:, 1] * CELLS // h).astype(int), CELLS - 1)
    j = np.minimum((uv[:, 0] * CELLS // w).astype(int), CELLS - 1)
    if values is None:
        return np.bincount(i * CELLS + j, minlength=CELLS * CELLS).reshape(CELLS, CELLS)
    total = np.bincount(i * CELLS + j, values ** 2, minlength=CELLS * CELLS)
    count = np.bincount(i * CELLS + j, minlength=CELLS * CELLS)
    return np.sqrt(total / np.maximum(count, 1)).reshape(CELLS, CELLS)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args(argv)
    for run in args.runs:
        truth = true_camera(run)
        cpu = time.process_time()
        log = read_drive_log(run / "log", check_images=False)
        detections = detect_log(log)
        lens, fits = fit_intrinsics(log, detections)
        cpu = time.process_time() - cpu
        size = (log.width_px, log.height_px)
        print(f"{run}: {sum(len(b) for b in detections.boards)} board views, chosen {lens.camera.model}, "
              f"{cpu:.0f} s CPU")
        for model, fit in fits.items():
            print(f"  {model}: {camera_difference_px(truth, fit.camera, size):.3f} px over the whole image "
                  f"(std {fit.whole_image_std_px:.3f}), held-out {fit.held_out_rms_px:.4f} px")
        uv, rays = _grid_rays(truth, size, 8.0)
        error = np.linalg.norm(lens.camera.project(rays, np.zeros(3), np.zeros(3)) - uv, axis=1)
        boards = np.concatenate([s.corners_px.reshape(-1, 2) for frame in detections.boards for s in frame])
        floor = FloorMarkers(marker_sightings(detections), log.marker_size_m, nominal_for(log.model).T_base_camera)
        usable = floor.usable().sightings.uv_px
        print("  per cell (rows top to bottom): RMS px | board corners | usable floor corners")
        for a, b, c in zip(cells(uv, size, error), cells(boards, size), cells(usable, size)):
            print(f"    {' '.join(f'{x:5.2f}' for x in a)} | {' '.join(f'{x:4d}' for x in b)} | "
                  f"{' '.join(f'{x:4d}' for x in c)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
