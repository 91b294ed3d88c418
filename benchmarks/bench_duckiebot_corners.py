"""The floor markers' corner error of kinds/duckiebot/detect.py against the truth, on the project's own renderer
(kinds/duckiebot/render.py: the floor markers seen through the hidden robot's real lens, true corner pixels from
solver.camera.project_points), tabulated over what the realistic mock shows: marker image sizes 15-80 px, the
markers' foreshortening on the floor from the camera's ~19 deg pitch, optical blur and image noise.

Each corner's error (detected - true) is split along the marker's image diagonal through it (outward +: a negative
mean is an inward shift, the marker seen too small) and across it; both in px and as a share of the local edge
length (the mean of the two true edges meeting at the corner). Rows are bins of that edge length; columns the
foreshortening (the marker's image height along the view over its width) and the renders' blur / noise; a second
table groups the same corners by the half-width of the window OpenCV's cornerSubPix refined them in, and the
outward error fitted as b0 + c / window (c: the samples of kinds/duckiebot/identify.py's CORNER_WINDOW_STD_PX2).

Robot poses: facing the marker line (render.calibration_scene: markers along -x), at random places along it, a
few cm aside, turned up to +-0.5 rad, as the mission's drives see them. Deterministic (seeded).

Run: `python benchmarks/bench_duckiebot_corners.py [--seeds 1 2 3] [--frames 40] [--refine subpix none contour
apriltag]`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.kinds.duckiebot import detect  # noqa: E402
from naocal.kinds.duckiebot.detect import refinement_window_px  # noqa: E402
from naocal.kinds.duckiebot.render import Renderer, calibration_scene, hidden_robot  # noqa: E402

EDGE_BINS_PX = (10, 15, 20, 25, 30, 40, 50, 65, 80, 120)
CONDITIONS = ((0.5, 1.5), (0.0, 0.0), (0.5, 0.0), (1.0, 1.5))  # (blur px, noise grey): the mock's first
REFINEMENTS = {"none": cv2.aruco.CORNER_REFINE_NONE, "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
               "contour": cv2.aruco.CORNER_REFINE_CONTOUR, "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG}


def detector(refine: str) -> cv2.aruco.ArucoDetector:
    """detect.py's detector, its refinement method swapped (its other settings kept)."""
    base = detect._marker_detector("tag36h11")
    if refine == "subpix":
        return base
    parameters = base.getDetectorParameters()
    parameters.cornerRefinementMethod = REFINEMENTS[refine]
    return cv2.aruco.ArucoDetector(base.getDictionary(), parameters)


def corner_errors(seeds, frames: int, blur_px: float, noise_grey: float, refine: str = "subpix"):
    """Rows (edge px, foreshortening, outward error px, across error px, detect.py's refinement window half-width
    px) over every corner detected."""
    scene = calibration_scene(n_markers=12)
    world = scene.marker_corners()
    aruco = detector(refine)
    rows = []
    for seed in seeds:
        robot = hidden_robot(seed)
        renderer = Renderer(scene, robot.camera, robot.T_base_camera, supersample=2)
        rng = np.random.default_rng(seed + 500)
        for _ in range(frames):
            pose = (rng.uniform(-1.6, -0.1), rng.uniform(-0.06, 0.06), np.pi + rng.uniform(-0.5, 0.5))
            image = renderer.render(pose, rng, noise_grey=noise_grey, blur_px=blur_px)
            corners, ids, _ = aruco.detectMarkers(image)
            if ids is None:
                continue
            for marker_id, found in zip(ids.ravel(), corners):
                if marker_id not in scene.marker_ids:
                    continue
                true, visible = renderer.project(pose, world[scene.marker_ids.index(int(marker_id))])
                if not visible.all() or not renderer.in_image(true, 3.0).all():
                    continue
                found = np.asarray(found, float).reshape(4, 2)
                centre = true.mean(axis=0)
                edges = np.linalg.norm(np.roll(true, -1, axis=0) - true, axis=1)  # edge i: corner i to i + 1
                width = (edges[0] + edges[2]) / 2.0  # top and bottom edges (across the view)
                height = (edges[1] + edges[3]) / 2.0  # along the view
                for i in range(4):
                    out = true[i] - centre
                    out /= np.linalg.norm(out)
                    error = found[i] - true[i]
                    local = (edges[i] + edges[i - 1]) / 2.0
                    rows.append((local, height / width, error @ out, out[0] * error[1] - out[1] * error[0],
                                 refinement_window_px(found)))
    return np.array(rows)


def table(rows: np.ndarray, title: str) -> str:
    """Markdown: per edge-length bin, the corners' count, mean outward error px (its standard error), as a share
    of the edge (%), its sd, the mean across error, and the mean outward error by foreshortening third."""
    ratio_cuts = np.quantile(rows[:, 1], [1 / 3, 2 / 3]) if len(rows) else (0.5, 0.7)
    lines = [f"{title}", "", "| edge px | corners | outward px (se) | outward % of edge | sd px | across px | "
             f"outward px, h/w < {ratio_cuts[0]:.2f} / to {ratio_cuts[1]:.2f} / above |",
             "|---|---|---|---|---|---|---|"]
    for lo, hi in zip(EDGE_BINS_PX[:-1], EDGE_BINS_PX[1:]):
        sel = rows[(rows[:, 0] >= lo) & (rows[:, 0] < hi)]
        if len(sel) < 8:
            continue
        out, share = sel[:, 2], sel[:, 2] / sel[:, 0]
        thirds = [sel[m, 2] for m in (sel[:, 1] < ratio_cuts[0],
                                      (sel[:, 1] >= ratio_cuts[0]) & (sel[:, 1] < ratio_cuts[1]),
                                      sel[:, 1] >= ratio_cuts[1])]
        third_text = " / ".join(f"{t.mean():+.3f}" if len(t) >= 4 else "-" for t in thirds)
        lines.append(f"| {lo}-{hi} | {len(sel)} | {out.mean():+.3f} ({out.std() / np.sqrt(len(sel)):.3f}) | "
                     f"{100 * share.mean():+.2f} | {out.std():.3f} | {sel[:, 3].mean():+.3f} | {third_text} |")
    lines += ["", "| refinement window half-width px | corners | outward px (se) | outward px x window |", "|---|---|---|---|"]
    for window in np.unique(rows[:, 4]) if len(rows) else ():
        out = rows[rows[:, 4] == window, 2]
        if len(out) >= 8:
            lines.append(f"| {window:.0f} | {len(out)} | {out.mean():+.3f} ({out.std() / np.sqrt(len(out)):.3f}) | "
                         f"{out.mean() * window:+.3f} |")
    fitted = window_fit(rows)
    if fitted is not None:
        lines += ["", f"outward px = b0 + c / window over windows 2-4 (least squares on the corners): b0 "
                      f"{fitted[0]:+.3f} px, c {fitted[1]:+.3f} px^2 (identify.CORNER_WINDOW_STD_PX2's samples)"]
    return "\n".join(lines)


def window_fit(rows: np.ndarray):
    """(b0 px, c px^2) of the outward error as b0 + c / w over the corners refined in windows of 2-4 px (the
    windows of 1 px: too few corners, none at blur 1 px), or None with fewer than two windows."""
    sel = rows[(rows[:, 4] >= 2)] if len(rows) else rows
    if len(np.unique(sel[:, 4])) < 2:
        return None
    X = np.column_stack([np.ones(len(sel)), 1.0 / sel[:, 4]])
    return np.linalg.lstsq(X, sel[:, 2], rcond=None)[0]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--frames", type=int, default=40, help="random poses per seed and condition")
    parser.add_argument("--refine", nargs="+", default=["subpix"], choices=sorted(REFINEMENTS))
    parser.add_argument("--conditions", type=int, default=len(CONDITIONS),
                        help="the first N of (blur px, noise grey) " + str(CONDITIONS))
    args = parser.parse_args(argv)
    for refine in args.refine:
        for blur, noise in CONDITIONS[:args.conditions]:
            cpu, wall = time.process_time(), time.perf_counter()
            rows = corner_errors(args.seeds, args.frames, blur, noise, refine)
            print(table(rows, f"### refinement {refine}, blur {blur} px, noise {noise} grey (seeds "
                              f"{' '.join(map(str, args.seeds))}, {args.frames} poses each; "
                              f"{time.process_time() - cpu:.0f} s CPU / {time.perf_counter() - wall:.0f} s wall)"))
            print(flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
