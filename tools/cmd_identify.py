"""`naocal identify DATASET`: fit the model to a dataset and print (or save) the parameters."""


import naocal.kinds as kinds
from naocal.tools.verb_options import add_identify_options


def register(subparsers):
    p = subparsers.add_parser(
        "identify",
        help="identify joint offsets, camera rotation and board mounts from a dataset",
        description=(
            "Fit the paper's 21-parameter model (12 leg joint offsets, camera roll/pitch/yaw, board rot_z/x/y per "
            "leg), plus any --effects, to a naocal.dataset/2 (or /1) directory by Levenberg-Marquardt on the pixel "
            "error of the board vertices. Prints a table (or --json); --out writes a naocal.offsets/2 file. Exit 0 on "
            "success, 2 on bad input, 3 if the solve fails or does not converge (nothing is written then)."
        ),
    )
    add_identify_options(p)
    kinds.add_options(p, "identify")
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args, args.dataset).identify(args)
