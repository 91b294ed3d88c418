"""Reading a paper-sized dataset (144 images x 24 vertices = 3456 rows): read_dataset vs. a straightforward reader.

The straightforward reader (csv.DictReader, float() per value, per-row dict checks) is what read_dataset replaces;
both validate the same things. Run: python benchmarks/bench_dataset.py
"""

import csv
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.solver.dataset import (  # noqa: E402
    INT_COLUMNS, OBSERVATIONS_FILE, PER_IMAGE_COLUMNS, REQUIRED_COLUMNS, read_dataset, write_dataset,
)
from tests.test_dataset import make_columns, make_meta  # noqa: E402


def straightforward_read(path):
    columns = {name: [] for name in REQUIRED_COLUMNS}
    first_of_image = {}
    with open(Path(path) / OBSERVATIONS_FILE, newline="") as f:
        for line, row in enumerate(csv.DictReader(f), start=2):
            for name in REQUIRED_COLUMNS:
                text = row[name]
                if name == "leg":
                    if text not in ("L", "R"):
                        raise ValueError(f"line {line}: unknown leg")
                    columns[name].append(text)
                    continue
                value = float(text)
                if not math.isfinite(value):
                    raise ValueError(f"line {line}: {name} non-finite")
                columns[name].append(int(value) if name in INT_COLUMNS else value)
            key = row["image"]
            if key in first_of_image:
                if any(first_of_image[key][n] != row[n] for n in PER_IMAGE_COLUMNS):
                    raise ValueError(f"line {line}: differs within image")
            else:
                first_of_image[key] = row
    return {name: np.array(values) for name, values in columns.items()}


def best_of(function, repeats=7):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "paper"
        write_dataset((make_meta(), make_columns(n_images=144, n_vertices=24, velocities=True)), path)
        fast = best_of(lambda: read_dataset(path))
        plain = best_of(lambda: straightforward_read(path))
        rows = read_dataset(path).n_rows
    print(f"read_dataset          {rows} rows: {fast * 1000:7.1f} ms")
    print(f"straightforward read  {rows} rows: {plain * 1000:7.1f} ms")
    print(f"speed-up: {plain / fast:.1f}x")


if __name__ == "__main__":
    main()
