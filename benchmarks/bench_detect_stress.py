"""`naocal detect`'s detector on images as a real NAO camera shows them (tests/stress_boards.py: a printed board
warped by OpenCV through a homography and a lens, then blur, motion, rolling shutter, vignetting, exposure, glare,
a Bayer sensor, YUYV 4:2:2, JPEG, clutter, a foot, a second board), against OpenCV's findChessboardCornersSB and
findChessboardCorners alone in the same run. Every detector gets the board size (squares) and no colours, as
`naocal detect --board WxH` runs; OpenCV's are tried on grey, then Cr, then Cb (the first that finds a board).

    python benchmarks/bench_detect_stress.py [--per-category 3] [--sizes 320x240,640x480,1280x960] [--seed 0]

Per category: found (of the cases with a board of the size to find), false boards (corners given where there is
no such board, or corners that are not the board's: more than 2 px off, a cut-down bigger board, the wrong order),
and refusals where refusing is right (a board cut by the edge or covered by a foot: "no board" or the right
corners). Corner error against the exact truth (median, p95, max px) over the boards found. Time per image per
resolution (CPU seconds, OpenCV on one thread) and the ratios.
"""

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from naocal.agent.board_detect import BoardSpec, channel_image, detect_board, image_order, labellings  # noqa: E402
from tests.stress_boards import CATEGORIES, scene  # noqa: E402

TOLERANCE_PX = 2.0


def ours(image, board):
    found = detect_board(image, board)
    if found.image_order_px is None or found.reason not in (None, "ambiguous"):
        return None
    return found.image_order_px.reshape(*board.shape, 2)


def _opencv(function):
    def detect(image, board):
        for channel in ("grey", "cr", "cb"):
            img = channel_image(image, channel)
            found, corners = function(img, board.shape[::-1])
            if found:
                grid = corners.reshape(-1, 2).astype(float)
                return image_order(grid.reshape(*board.shape, 2), board.shape)
        return None
    return detect


def _sb(img, pattern):
    return cv2.findChessboardCornersSB(img, pattern, flags=cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE)


def _classic(img, pattern):
    found, corners = cv2.findChessboardCorners(img, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                               | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if found:  # the usual pipeline: cornerSubPix in a window of about a third of a square
        grid = corners.reshape(pattern[1], pattern[0], 2)
        side = min(float(np.linalg.norm(np.diff(grid, axis=a), axis=-1).min()) for a in (0, 1))
        half = max(2, int(round(0.3 * side)))
        corners = cv2.cornerSubPix(img, corners, (half, half), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.01))
    return found, corners


DETECTORS = {"naocal": ours, "SB": _opencv(_sb), "classic": _opencv(_classic)}


def judge(case, grid):
    """('found', errors) | ('refused', None) | ('missed', None) | ('false', why)."""
    if grid is None:
        return ("missed" if case.expect == "found" else "refused"), None
    if case.truth_px is None:
        return "false", "corners where there is no such board"
    shape = case.truth_px.shape[:2]
    expected = image_order(case.truth_px, shape)
    error = np.linalg.norm(grid - expected, axis=-1)
    if error.max() <= TOLERANCE_PX:
        return "found", error.ravel()
    others = [g for _, g in labellings(grid) if g.shape == expected.shape]
    if any(np.linalg.norm(g - expected, axis=-1).max() <= TOLERANCE_PX for g in others):
        return "false", "the board's corners in another order"
    return "false", f"corners up to {error.max():.1f} px off"


def main():
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-category", type=int, default=3)
    parser.add_argument("--sizes", default="320x240,640x480,1280x960")
    parser.add_argument("--categories", default=",".join(CATEGORIES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--detectors", default="naocal,SB,classic")
    parser.add_argument("--verbose", action="store_true", help="one line per case and detector")
    args = parser.parse_args()
    sizes = [tuple(int(x) for x in s.split("x")) for s in args.sizes.split(",")]
    categories = args.categories.split(",")
    names = args.detectors.split(",")
    tally = {(name, c): {"cases": 0, "should": 0, "found": 0, "found_should": 0, "false": 0, "refused": 0,
                               "missed": 0}
             for name in names for c in categories}
    errors = {name: [] for name in names}
    by_category = {(name, c): [] for name in names for c in categories}
    seconds = {(name, size): [] for name in names for size in sizes}
    for size in sizes:
        for c_index, category in enumerate(categories):
            for k in range(args.per_category):
                seed = args.seed * 100000 + 1000 * c_index + 10 * k + sizes.index(size)
                case = scene(category, size, seed=seed)
                board = BoardSpec(case.columns, case.rows)
                for name in names:
                    before = time.process_time()
                    grid = DETECTORS[name](case.image, board)
                    seconds[name, size].append(time.process_time() - before)
                    verdict, extra = judge(case, grid)
                    t = tally[name, category]
                    t["cases"] += 1
                    t["should"] += case.expect == "found"
                    t[verdict] += 1
                    t["found_should"] += verdict == "found" and case.expect == "found"
                    if verdict == "found":
                        errors[name].append(extra)
                        by_category[name, category].append(extra)
                    if args.verbose or (verdict == "false" and name == "naocal"):
                        print(f"  {size[0]}x{size[1]} {category} seed {seed} {case.columns}x{case.rows} {name}: "
                              f"{verdict}{': ' + extra if verdict == 'false' else ''}", flush=True)
    print(f"\n{args.per_category} cases per category and size at {', '.join(f'{w}x{h}' for w, h in sizes)}; "
          "found / should be found (false boards; right refusals of cut or covered boards)")
    print("| category | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    totals = {name: {"should": 0, "found": 0, "false": 0} for name in names}
    for category in categories:
        cells = []
        for name in names:
            t = tally[name, category]
            expect_found = t["should"]
            found_of_should = t["found_should"]
            text = f"{found_of_should}/{expect_found}" if expect_found else ""
            if t["cases"] > expect_found:  # cut, covered or no board: refusing is right, or giving the right corners
                text += (", " if text else "") + f"{t['refused']}/{t['cases'] - expect_found} refused"
                if t["found"] > found_of_should:
                    text += f", {t['found'] - found_of_should} right corners"
            if t["false"]:
                text += f" ({t['false']} false)"
            cells.append(text)
            totals[name]["should"] += expect_found
            totals[name]["found"] += found_of_should
            totals[name]["false"] += t["false"]
        print(f"| {category} | " + " | ".join(cells) + " |")
    print("| all | " + " | ".join(f"{v['found']}/{v['should']} ({v['false']} false)" for v in totals.values()) + " |")
    print("\ncorner error of the boards found, px: median / p95 / max")
    for name in names:
        e = np.concatenate(errors[name]) if errors[name] else np.zeros(0)
        if len(e):
            print(f"  {name:8s} {np.median(e):.3f} / {np.percentile(e, 95):.3f} / {e.max():.3f} ({len(e)} corners)")
    print("\ncorner error per category, px: median / p95 (" + ", ".join(names) + ")")
    for category in categories:
        cells = []
        for name in names:
            e = np.concatenate(by_category[name, category]) if by_category[name, category] else np.zeros(0)
            cells.append(f"{np.median(e):.2f} / {np.percentile(e, 95):.2f}" if len(e) else "-")
        print(f"  {category:13s} " + "; ".join(cells))
    print("\nCPU time per image, ms: mean / max")
    for size in sizes:
        parts = [f"{name} {1000 * np.mean(seconds[name, size]):.0f} / {1000 * np.max(seconds[name, size]):.0f}"
                 for name in names]
        ratio = ""
        if "naocal" in names:
            ratio = "; naocal's time over " + ", ".join(
                f"{name}'s {np.mean(seconds['naocal', size]) / max(np.mean(seconds[name, size]), 1e-9):.2f}"
                for name in names if name != "naocal")
        print(f"  {size[0]}x{size[1]}: " + ", ".join(parts) + ratio)


if __name__ == "__main__":
    main()
