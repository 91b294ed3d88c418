"""`naocal diagnose DATASET`: compare the model with the measurements, locate where it fails, name what is missing."""

import argparse  # noqa: F401 (argparse only at import time: `naocal --help` stays instant)

import naocal.kinds as kinds
from naocal.tools.verb_options import add_dataset_argument, effect_names

EPILOG = """\
Sections of the output (a NAO's; other kinds' name their own parts of the data):
  compare  RMS overall, per leg, per head posture and the worst stances, against the noise floor: detector noise
           (the dataset's pixel_noise_px, else estimated from what no rigid board motion and no camera term can
           explain) combined with the error of quantised joint readings (step found in the data).
  locate   worst images; the rigid (kinematic) and non-rigid (camera, board) parts of the residuals; left against
           right board; the regressors (joint angles, gravity torques, approach directions, velocities, capture
           time, image position) a board motion proportional to which would explain most of the misfit.
  names    every effect not yet in the model (score test), ranked by the misfit it would explain beyond what its
           parameters would fit of pure noise, with the RMS predicted after adding it, a significance test
           clustered by stance (images of one stance share their errors; Bonferroni over the candidates,
           family-wise level 0.001) and its uniqueness (share of its signature the model cannot already produce;
           near 0: these data can hardly tell it apart, whatever its p-value). The default model's assumptions
           are candidates too, each dropped by its candidate: untie_shared_motors (the HipYawPitch pair's one
           offset; dropped by --no-tie-hip-yaw-pitch) and rigid_board (each board flat and as printed; no model
           drops it: the verdict says what to measure). With --angles X, the other angle hypotheses are fitted
           too and a better one is named ("assumption contradicted").
Add the top significant candidate with `naocal identify DATASET --effects NAME --out offsets.json` (its cv_rms_px
shows the error on stances the fit did not see), then diagnose again with --effects NAME; the verdict prints both
commands, ready to paste (with --fix for the candidate's parameters these data cannot tell from the model).
Exit 0 on success, 2 on bad input, 3 if the fit fails.
"""


def register(subparsers):
    p = subparsers.add_parser(
        "diagnose",
        help="compare the fitted model with the measurements and rank the missing physical effects",
        description=(
            "Fit a robot's model (its kind's, as identify fits it, plus --effects) to its data (DATASET), then\n"
            "compare it with the measurements, locate where it fails and rank every candidate effect not yet in\n"
            "the model by how much of the misfit it would explain."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_dataset_argument(p, "diagnose")
    p.add_argument("--effects", default="", metavar="E1,E2",
                   help="extra model terms already in the model: " + effect_names())
    p.add_argument("--fix", action="append", default=[], metavar="NAME",
                   help="keep a parameter or a whole effect at zero (repeatable), as naocal identify --fix does (an "
                        "arm's NAME=VALUE too)")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object: {"rms_px": [x, y], "noise_px": f, "candidates": [...], ...}')
    p.add_argument("--report", metavar="DIR", help="write an HTML report with plots to DIR/index.html")
    kinds.add_options(p, "diagnose")
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args, args.dataset).diagnose(args)
