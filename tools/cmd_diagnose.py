"""`naocal diagnose DATASET`: compare the model with the measurements, locate where it fails, name what is missing."""

import argparse  # noqa: F401 (argparse only at import time: `naocal --help` stays instant)

import naocal.kinds as kinds
from naocal.tools.verb_options import add_dataset_argument, effect_names

EPILOG = """\
Sections of the output, by kind:
{sections}
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
        epilog=EPILOG.format(sections=kinds.help_blocks_by_kind("diagnose_help", "diagnose")),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_dataset_argument(p, "diagnose")
    p.add_argument("--effects", default="", metavar="E1,E2",
                   help="extra model terms already in the model, by kind: " + effect_names("diagnose"))
    p.add_argument("--fix", action="append", default=[], metavar="NAME",
                   help="keep a parameter or a whole effect at zero (repeatable), as naocal identify --fix does (an "
                        "arm's NAME=VALUE too)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object, by kind: " + kinds.help_by_kind("diagnose_json_help", "diagnose"))
    p.add_argument("--report", metavar="DIR", help="write an HTML report with plots to DIR/index.html")
    kinds.add_options(p, "diagnose")
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.for_args(args, args.dataset).diagnose(args)
