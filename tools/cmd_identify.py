"""`naocal identify DATASET`: fit the model to a dataset and print (or save) the parameters."""


import naocal.kinds as kinds
from naocal.tools.verb_options import add_identify_options


def register(subparsers):
    p = subparsers.add_parser(
        "identify",
        help="identify a robot's calibration from its data (the robot's kind found from the data)",
        description=(
            "Fit a robot's model, plus any --effects, to its data (DATASET) by Levenberg-Marquardt. The model, by "
            f"kind: {kinds.help_by_kind('model_help', 'identify')}. Prints a table (or --json); --out writes the "
            "kind's calibration file. Exit 0 on success, 2 on bad input, 3 if the solve fails or does not converge "
            "(nothing is written then)."
        ),
    )
    add_identify_options(p)
    kinds.add_options(p, "identify")
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args, args.dataset).identify(args)
