"""Fuzz every verb that reads a dataset, an offsets file or an image with seeded damage of valid files (a larger run
than tests/test_fuzz_inputs.py). Prints the number of runs, the failures and the time.

Run: python benchmarks/fuzz_inputs.py [--seeds 0 1 2] [--json-cases 60] [--csv-cases 120] [--image-cases 40]
     [--groups dataset,offsets,images] [--one-verb] [-v]
Exit 1 if any run failed (a hang, a traceback, a wrong exit code, or not one line naming the file).
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from tests import fuzz_inputs as fz  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--json-cases", type=int, default=60, help="seeded JSON mutations per file and seed")
    parser.add_argument("--csv-cases", type=int, default=120, help="seeded CSV mutations per seed")
    parser.add_argument("--one-verb", action="store_true", help="one verb per case (in turn) instead of all")
    parser.add_argument("--deadline", type=float, default=20.0, help="seconds before a run counts as a hang")
    parser.add_argument("--image-cases", type=int, default=40, help="seeded header changes per image and seed")
    parser.add_argument("--groups", default="dataset,offsets,images",
                        help="which inputs to damage (comma separated: dataset, offsets, images)")
    parser.add_argument("-v", "--verbose", action="store_true", help="print every failing run")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="naocal-fuzz-"))
    os.chmod(work, 0o755)  # the permission-denied cases run as nobody
    try:
        wanted = set(args.groups.split(","))
        valid_ds, valid_offsets = fz.make_valid_inputs(work / "valid")
        valid_images = fz.make_valid_images(work / "valid" / "images")
        totals = {}
        start = time.perf_counter()
        for seed in args.seeds:
            groups = {
                "dataset": (fz.dataset_cases(valid_ds, seed, args.json_cases, args.csv_cases), valid_ds,
                            lambda d, out: fz.dataset_verbs(d, out, valid_offsets / fz.OFFSETS)),
                "offsets": (fz.offsets_cases(valid_offsets / fz.OFFSETS, seed, args.json_cases), valid_offsets,
                            lambda d, out: fz.offsets_verbs(d / fz.OFFSETS, valid_offsets / "reference.json")),
                "images": (fz.image_cases(valid_images, seed, args.image_cases), valid_images, fz.image_verbs),
            }
            for kind, (cases, valid, verbs) in groups.items():
                if kind not in wanted:
                    continue
                runs, failures = fz.run_cases(cases, valid, work / f"{kind}-{seed}", verbs,
                                              every_verb=not args.one_verb, deadline_s=args.deadline)
                failed_cases = {f.case for f in failures}
                t = totals.setdefault(kind, [0, 0, 0, 0])
                for i, n in enumerate((len(cases), runs, len(failed_cases), len(failures))):
                    t[i] += n
                if args.verbose:
                    for f in failures:
                        print(f"  {f}")
        for kind, (cases, runs, failed_cases, failed_runs) in totals.items():
            print(f"{kind}: {cases} damaged inputs, {runs} runs: {failed_cases} inputs failed ({failed_runs} runs)")
        print(f"time {time.perf_counter() - start:.1f} s")
        return 1 if any(t[3] for t in totals.values()) else 0
    finally:
        fz.remove_tree(work)


if __name__ == "__main__":
    sys.exit(main())
