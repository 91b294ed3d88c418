"""The board search of a drive log (kinds.duckiebot.identify.search_boards) against the full one (every frame
board_search_frames picks): frames searched, board views found by each, and the CPU of each.

Logs: the drive logs given (default: the realistic mock's missions, `naocal calibrate --robot duckiebot --backend
mock --seed N --out RUN`, RUN/log; make them first). The full search is the reference: search_boards must find
every view it finds. Run: `python benchmarks/bench_duckiebot_board_search.py LOG [LOG ...]`.
Measured (2026-11-28, seeds 1-5 and 8): 44 / 50 / 59 / 44 / 51 / 45 frames searched of 100 / 115 / 133 / 101 / 120
/ 103, every view found (28 / 28 / 37 / 23 / 28 / 24); the full search 46-56 s CPU a log. `naocal identify` of seed
8's log: 46.2 -> 23.4 s CPU, the same output.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import naocal.tools.cli  # noqa: E402,F401  (one BLAS thread, as the command line)
from naocal.kinds.duckiebot import identify  # noqa: E402
from naocal.kinds.duckiebot.drive_log import read_drive_log  # noqa: E402


def main(paths) -> int:
    print("| log | frames | full search: frames / views / CPU s | search_boards: frames / views / CPU s | all found |")
    print("|---|---|---|---|---|")
    for path in paths:
        log = read_drive_log(path, check_images=False)
        t = time.process_time()
        full = {int(i): identify.detect_boards(log.load_frame(int(i), cv2.IMREAD_GRAYSCALE), log.board_inner_corners,
                                               log.board_square_m)
                for i in np.flatnonzero(identify.board_search_frames(log.frame_t_s))}
        full_s = time.process_time() - t
        t = time.process_time()
        found = identify.search_boards(log)
        found_s = time.process_time() - t
        views = {frame: len(boards) for frame, boards in full.items() if boards}
        every = all(len(found.get(frame, [])) == n for frame, n in views.items())
        print(f"| {path} | {len(log.frame_files)} | {len(full)} / {sum(views.values())} / {full_s:.0f} | "
              f"{len(found)} / {sum(len(b) for b in found.values())} / {found_s:.0f} | {'yes' if every else 'NO'} |",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
