"""Detection without a prediction (agent.board_detect.detect_board, what `naocal detect` runs) against the
straightforward implementation: OpenCV's findChessboardCornersSB (CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE) on
the grey image, then on Cr, then on Cb, the first that finds the board. Both get the board size; neither gets
the colours.

    python benchmarks/bench_detect.py [--synthetic 40] [--seed 0]

Real: the six MRL-SPL NAO images of a 4 x 4 orange/blue board (tests/data/realdata/mrlspl-nao-2009/), no truth:
found counts, time, the RMS distance of the corners from straight lines through each row and column, and the
two detectors' disagreement. Synthetic (tests/synthetic_boards.py): random boards of 4 x 4 to 10 x 7 squares,
black/white (either polarity) or orange/blue, turned, tilted up to 45 deg, 16 to 60 px squares, blurred and noisy,
at 320 x 240 or 640 x 480, with exact corners: found counts, RMS and largest error, time. Times are CPU time
(OpenCV on one thread).
"""

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from naocal.agent.board_detect import BoardSpec, channel_image, detect_board, image_order, labellings, line_rms_px  # noqa
from tests.synthetic_boards import board_homography, render  # noqa: E402

SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE


def straightforward(image: np.ndarray, board: BoardSpec):
    """findChessboardCornersSB on grey, Cr, Cb in turn: ((rows, cols, 2) in image order, channel) or (None, '')."""
    for channel in ("grey", "cr", "cb") if image.ndim == 3 else ("grey",):
        found, corners = cv2.findChessboardCornersSB(channel_image(image, channel), board.shape[::-1], flags=SB_FLAGS)
        if found:
            return image_order(corners.reshape(*board.shape, 2).astype(float), board.shape), channel
    return None, ""


def ours(image: np.ndarray, board: BoardSpec):
    found = detect_board(image, board)
    if found.image_order_px is None or found.reason not in (None, "ambiguous"):
        return None, ""
    return found.image_order_px.reshape(*board.shape, 2), found.channel


def closest_labelling(grid: np.ndarray, truth: np.ndarray) -> np.ndarray:
    options = [g for _, g in labellings(grid) if g.shape == truth.shape]
    return min(options, key=lambda g: np.abs(g - truth).max())


def timed(function, *args):
    """(result, CPU seconds): process time with OpenCV on one thread, so that a busy shared machine changes the
    numbers little (wall-clock time on an idle one is about the same)."""
    before = time.process_time()
    result = function(*args)
    return result, time.process_time() - before


def real_images():
    folder = ROOT / "tests" / "data" / "realdata" / "mrlspl-nao-2009"
    board = BoardSpec(4, 4)
    print("real: six 320 x 240 NAO images of a 4 x 4 orange/blue board")
    seconds = {"naocal": 0.0, "SB": 0.0}
    found = {"naocal": 0, "SB": 0}
    for i in range(6):
        image = cv2.imread(str(folder / f"image_{i}.png"))
        (a, ca), ta = timed(ours, image, board)
        (b, cb), tb = timed(straightforward, image, board)
        seconds["naocal"] += ta
        seconds["SB"] += tb
        found["naocal"] += a is not None
        found["SB"] += b is not None
        text = [f"  image_{i}: naocal {'found in ' + ca if a is not None else 'not found'} ({1000 * ta:.0f} ms"]
        text.append(f", line fit {line_rms_px(a):.3f} px)" if a is not None else ")")
        text.append(f"; SB {'found in ' + cb if b is not None else 'not found'} ({1000 * tb:.0f} ms")
        text.append(f", line fit {line_rms_px(b):.3f} px)" if b is not None else ")")
        if a is not None and b is not None:
            text.append(f"; largest disagreement {np.abs(closest_labelling(b, a) - a).max():.2f} px")
        print("".join(text))
    print(f"  found: naocal {found['naocal']}/6, SB {found['SB']}/6; time per image: naocal "
          f"{1000 * seconds['naocal'] / 6:.0f} ms, SB {1000 * seconds['SB'] / 6:.0f} ms")


def random_scene(rng):
    columns, rows = (int(x) for x in rng.choice([(4, 4), (5, 4), (7, 5), (8, 5), (8, 6), (9, 6), (10, 7)]))
    size = (320, 240) if rng.random() < 0.5 else (640, 480)
    colours = [("black", "white"), ("white", "black"), ("orange", "blue")][rng.integers(3)]
    square_px = rng.uniform(16, 60) * size[0] / 640 * 1.5
    square_px = min(square_px, 0.8 * size[1] / (rows + 1))
    H = board_homography(columns, rows, size=size, square_px=square_px, tilt_x=rng.uniform(-0.8, 0.8),
                         tilt_y=rng.uniform(-0.5, 0.5), turn=rng.uniform(-np.pi, np.pi),
                         shift_px=rng.uniform(-0.1, 0.1, 2) * size[0])
    scene = render(columns, rows, H, size=size, colours=colours, blur_px=rng.uniform(0.4, 1.2),
                   noise=rng.uniform(1, 6), margin_squares=0.0 if colours[0] == "orange" else 0.5,
                   background="green" if colours[0] == "orange" else "grey", seed=int(rng.integers(1 << 30)))
    inside = np.all((scene.corners_px > 8) & (scene.corners_px < np.array(size) - 9))
    return scene, BoardSpec(columns, rows), inside


def synthetic(n: int, seed: int):
    rng = np.random.default_rng(seed)
    print(f"synthetic: {n} random boards with exact corners")
    results = {"naocal": ([], 0.0, 0), "SB": ([], 0.0, 0)}
    made = 0
    while made < n:
        scene, board, inside = random_scene(rng)
        if not inside:
            continue
        made += 1
        for name, function in (("naocal", ours), ("SB", straightforward)):
            (grid, _), seconds = timed(function, scene.image, board)
            errors, total, wrong = results[name]
            if grid is not None:
                error = closest_labelling(grid, scene.corners_px) - scene.corners_px
                if np.abs(error).max() > 2.0:
                    wrong += 1
                else:
                    errors.append(error.reshape(-1, 2))
            results[name] = (errors, total + seconds, wrong)
    for name, (errors, total, wrong) in results.items():
        e = np.concatenate(errors) if errors else np.zeros((0, 2))
        rms = np.sqrt(np.mean(np.sum(e ** 2, axis=1))) if len(e) else float("nan")
        print(f"  {name:6s}: found {len(errors)}/{n} (wrong {wrong}), error RMS {rms:.3f} px, largest "
              f"{np.abs(e).max() if len(e) else float('nan'):.2f} px, {1000 * total / n:.0f} ms per image")
    ratio = (results["SB"][1]) / max(results["naocal"][1], 1e-9)
    print(f"  speed ratio (naocal / straightforward, images per second): {ratio:.2f}")


def main():
    cv2.setNumThreads(1)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--synthetic", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    real_images()
    synthetic(args.synthetic, args.seed)


if __name__ == "__main__":
    main()
