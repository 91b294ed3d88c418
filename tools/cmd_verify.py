"""`naocal verify DATASET --offsets FILE`: is a calibration still good on new data? (its values are not refitted)"""

import naocal.kinds as kinds
def register(subparsers):
    p = subparsers.add_parser(
        "verify",
        help="the residuals of new data under a fixed calibration: still good, or drifted (and what moved)",
        description=(
            "Evaluate a naocal.dataset/2 (or /1) under the calibration of a naocal.offsets/2 (or /1) file without "
            "refitting it, after setting aside what identify sets aside (moving captures, mis-detected corners and "
            "images): RMS, median, 95th percentile and maximum pixel error overall, per camera, per target and per "
            "image, against the calibration's own RMS and the data's noise floor. Verdict 'still good' or 'drifted' "
            "(the RMS beyond 1.5 x both, or a calibrated value moved by 5 standard deviations), naming the joints, "
            "cameras or boards whose calibrated values the new data say have moved. Exit 0 still good, 1 drifted, "
            "2 bad input (docs/DIAGNOSTICS.md). An arm's naocal.arm_dataset/1 under its naocal.arm_calibration/1: "
            "per sensor and pose, drifted on the RMS (docs/ARM.md)."
        ),
    )
    p.add_argument("dataset", metavar="DATASET",
                   help="naocal.dataset/2 (or /1) directory of new captures, or a `naocal calibrate --out` run")
    p.add_argument("--offsets", required=True, metavar="FILE",
                   help="the calibration: naocal.offsets/2 (or /1); an arm's naocal.arm_calibration/1")
    p.add_argument("--json", action="store_true", help="print one JSON object (docs/DIAGNOSTICS.md) instead of text")
    kinds.add_options(p, "verify")  # an arm's (docs/ARM.md): DATASET a naocal.arm_dataset/1, FILE its calibration
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args, args.dataset, args.offsets).verify(args)
