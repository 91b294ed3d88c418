"""`naocal verify DATASET --offsets FILE`: is a calibration still good on new data? (its values are not refitted; a
kind whose `verify_finds_calibration` is true finds its robot's calibration without --offsets)"""

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
            "moved. Exit 0 still good, 1 drifted, 2 bad input (docs/DIAGNOSTICS.md; an arm's: docs/ARM.md). "
            + kinds.help_by_kind("verify_help", "verify")
        ),
    )
    add_dataset_argument(p, "verify")
    p.add_argument("--offsets", metavar="FILE",
                   help="the calibration (identify --out's), by kind: " + kinds.help_by_kind("calibration_help",
                                                                                            "verify")
                   + "; required unless the kind finds its robot's calibration itself (above)")
    p.add_argument("--json", action="store_true", help="print one JSON object (docs/DIAGNOSTICS.md) instead of text")
    kinds.add_options(p, "verify")  # each kind's own, its help saying whose
    p.set_defaults(run=run)


def run(args) -> int:
    kind = kinds.for_args(args, args.dataset, args.offsets)
    if args.offsets is None and not getattr(kind, "verify_finds_calibration", False):
        raise NaocalError(f"--offsets FILE is required: the calibration to verify {args.dataset} under ({kind.name}: "
                          f"{kind.calibration_help})")
    return kind.verify(args)
