"""How often the diagnostics call an effect significant when none is hidden: the table in docs/DIAGNOSTICS.md.

100 synthetic datasets (24 stances x 3 head postures per leg, 0.1 px noise), with exact and with 0.1 deg
quantised joint readings; the paper's model is fitted and every candidate effect tested. Prints how many datasets
had any significant candidate (should be about 0) and each candidate's share of p < 0.05 (about 0.05 or below for
a calibrated or conservative test). About a minute.

    python benchmarks/false_positives.py [--datasets 100]
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.solver.diagnostics import diagnose_result  # noqa: E402
from naocal.solver.identify import identify  # noqa: E402
from naocal.solver.registry import Registry  # noqa: E402
from naocal.sim.synthetic import random_truth, synthesize  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=100)
    args = parser.parse_args()
    print("| data | datasets | any candidate significant | per candidate P(p < 0.05) |")
    print("|---|---|---|---|")
    for label, resolution in (("exact joint readings", 0.0), ("readings quantised to 0.1 deg", np.radians(0.1))):
        any_significant, below = 0, {}
        for seed in range(args.datasets):
            rng = np.random.default_rng(1000 + seed)
            data = synthesize(rng, random_truth(rng), pixel_noise_px=0.1, encoder_resolution_rad=resolution)
            diagnosis = diagnose_result(identify(data, Registry()), pixel_noise_px=0.1)
            any_significant += any(c.significant for c in diagnosis.candidates)
            for c in diagnosis.candidates:
                if c.testable:
                    below.setdefault(c.effect, []).append(c.p_value < 0.05)
        rates = [np.mean(v) for v in below.values()]
        print(f"| {label} | {args.datasets} | {any_significant} | {min(rates):.2f} - {max(rates):.2f} |")


if __name__ == "__main__":
    main()
