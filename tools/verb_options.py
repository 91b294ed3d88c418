"""The options of `naocal identify` every kind shares (argparse only), in their own module so that a kind can parse
identify's options (the NAO's diagnose parses the identify command it suggests) without importing the verb."""


def effect_names(verb: str) -> str:
    """The effects --effects takes, by kind (each kind's effects_help: its model's effects of the one registry,
    solver/effects/, one module each), for --help."""
    from naocal.kinds import help_by_kind

    return help_by_kind("effects_help", verb)


def add_dataset_argument(p, verb: str) -> None:
    """DATASET: what it is for each kind with a body for `verb`."""
    from naocal.kinds import help_by_kind

    p.add_argument("dataset", metavar="DATASET", help="the robot's data, by kind: " + help_by_kind("data_help", verb))


def add_identify_options(p) -> None:
    from naocal.kinds import help_by_kind

    add_dataset_argument(p, "identify")
    p.add_argument("--effects", default="",
                   help="extra model terms, comma separated, by kind: " + effect_names("identify"))
    p.add_argument("--out", metavar="FILE", help="write the calibration file (atomic, an old one kept as .bak), by "
                                                 "kind: " + help_by_kind("calibration_help", "identify"))
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--keep-outliers", action="store_true",
                   help="fit every corner and image (default: corners no rigid board motion explains, and images no "
                        "view of their flat board explains, are set aside and listed)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME",
                   help="keep a parameter or a whole effect at zero (repeatable), e.g. board_mount or camera.yaw; an "
                        "arm's NAME=VALUE holds it at VALUE in the units its table shows (deg, mm; docs/ARM.md)")
    p.add_argument("--loss", default="linear", choices=("linear", "soft_l1", "huber", "cauchy"),
                   help="robust loss; images it down-weights are reported (default: linear)")
    p.add_argument("--cv-folds", type=int, default=5,
                   help="folds of grouped cross-validation (whole stances held out) for cv_rms_px; 0 to skip")
