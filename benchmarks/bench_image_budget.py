"""`naocal detect` against image size: why the pixel budget (solver.fileio.MAX_IMAGE_PIXELS, 4096 x 4096) is where
it is. Per size: wall and CPU time and peak memory of one `naocal detect IMAGE` process (a 7 x 5 sandal board over
a third of the image, PNG), then the same for files whose header claims more than the budget (refused unread).

    python benchmarks/bench_image_budget.py [--sizes 640x480,1280x960,2048x1536,4096x3072,4096x4096]

Each run is a fresh `python -m naocal detect` (import time included: about 1 s of it).
"""

import argparse
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def board_image(width: int, height: int):
    """A grey image with a 7 x 5 checkerboard (white margin) about a third of its width across."""
    import cv2
    import numpy as np

    image = np.full((height, width), 120, np.uint8)
    square = max(4, width // 3 // 9)
    board = np.full((7 * square, 9 * square), 255, np.uint8)  # 7 x 5 squares and a one-square margin
    for r in range(5):
        for c in range(7):
            if (r + c) % 2 == 0:
                board[(r + 1) * square:(r + 2) * square, (c + 1) * square:(c + 2) * square] = 0
    y, x = (height - board.shape[0]) // 2, (width - board.shape[1]) // 2
    image[y:y + board.shape[0], x:x + board.shape[1]] = board
    return cv2.GaussianBlur(image, (5, 5), 1.0)


def png_claiming(width: int, height: int) -> bytes:
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    packer = zlib.compressobj(9)
    idat = b"".join(packer.compress(bytes(width + 1)) for _ in range(height)) + packer.flush()
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def run_detect(path: Path) -> tuple[float, float, float, int, str]:
    """(wall s, CPU s, peak RSS MiB, exit code, last output line) of one `naocal detect path` process."""
    with tempfile.TemporaryFile() as out:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "naocal", "detect", str(path)], cwd=ROOT, stdout=out,
                                stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - start
        out.seek(0)
        lines = out.read().decode("utf-8", "replace").strip().splitlines() or [""]
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, proc.returncode, lines[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="640x480,1280x960,2048x1536,4096x3072,4096x4096")
    args = parser.parse_args()
    import cv2

    print(f"{'image':<28}{'file KiB':>9}{'wall s':>8}{'CPU s':>7}{'peak MiB':>9}  exit  result")
    with tempfile.TemporaryDirectory() as tmp:
        cases = []
        for size in args.sizes.split(","):
            width, height = (int(v) for v in size.split("x"))
            path = Path(tmp) / f"board_{width}x{height}.png"
            cv2.imwrite(str(path), board_image(width, height))
            cases.append((f"board {width} x {height}", path))
        for width, height in ((20000, 20000), (60000, 60000)):
            path = Path(tmp) / f"claims_{width}x{height}.png"
            path.write_bytes(png_claiming(width, height) if width == 20000 else png_claiming(1, 1).replace(
                struct.pack(">II", 1, 1), struct.pack(">II", width, height)))
            cases.append((f"header claims {width} x {height}", path))
        for label, path in cases:
            wall, cpu, rss, code, line = run_detect(path)
            print(f"{label:<28}{path.stat().st_size / 1024:>9.0f}{wall:>8.2f}{cpu:>7.2f}{rss:>9.0f}  {code:>4}  "
                  f"{line.split(': ', 1)[-1][:70]}")


if __name__ == "__main__":
    main()
