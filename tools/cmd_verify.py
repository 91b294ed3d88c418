"""`naocal verify DATASET --offsets FILE`: is a calibration still good on new data? (its values are not refitted; a
Duckiebot's `naocal verify LOG` finds its calibration without --offsets, docs/DUCKIEBOT.md)"""

import naocal.kinds as kinds
from naocal.solver.errors import NaocalError
from naocal.tools.verb_options import add_dataset_argument


def register(subparsers):
    p = subparsers.add_parser(
        "verify",
        help="the residuals of new data under a fixed calibration: still good, or drifted (and what moved)",
        description=(
            "Evaluate a robot's new data (DATASET) under the calibration of --offsets FILE without refitting it, after "
            "setting aside what identify sets aside (moving captures, mis-detected corners and images): the error "
            "overall and per part of the data (camera, target, image; an arm's sensor and pose), against the "
            "calibration's own error and the data's noise floor. Verdict 'still good' or 'drifted' (the error beyond "
            "1.5 x both, or a calibrated value moved by 5 standard deviations), naming what the new data say has "
            "moved. Exit 0 still good, 1 drifted, 2 bad input (docs/DIAGNOSTICS.md; an arm's: docs/ARM.md). A "
            "Duckiebot's drive log: gain and trim refitted, the 2 m straight drive at 0.3 m/s predicted under the "
            "calibration (--offsets CAL.json, or a Duckietown calibrations DIR; without --offsets the robot's files "
            "in /data/config/calibrations, else the log's own camera under Duckietown's default kinematics): still "
            "good within 10 cm (0), drifted (1), bad input or no calibration (2), a fit failed (3) "
            "(docs/DUCKIEBOT.md)."
        ),
    )
    add_dataset_argument(p, "verify")
    p.add_argument("--offsets", metavar="FILE",
                   help="the calibration (identify --out's), by kind: " + kinds.help_by_kind("calibration_help",
                                                                                            "verify")
                   + "; required unless the kind finds its robot's calibration itself (a Duckiebot's: "
                     "see --robot-name)")
    p.add_argument("--json", action="store_true", help="print one JSON object (docs/DIAGNOSTICS.md) instead of text")
    kinds.add_options(p, "verify")  # each kind's own, its help saying whose
    p.set_defaults(run=run)


def run(args) -> int:
    kind = kinds.for_args(args, args.dataset, args.offsets)
    if args.offsets is None and not getattr(kind, "verify_finds_calibration", False):
        raise NaocalError(f"--offsets FILE is required: the calibration to verify {args.dataset} under ({kind.name}: "
                          f"{kind.calibration_help})")
    return kind.verify(args)
