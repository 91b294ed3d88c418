"""The NAO's options of each verb (argparse only, no heavy imports: `naocal --help` stays instant)."""

import argparse


class FlagPair(argparse.Action):
    """`--X` / `--no-X` setting one destination to True / False: argparse.BooleanOptionalAction's behaviour, which
    is Python 3.9+ (the command line is built on the Duckiebot's Python 3.8 too: docs/DEPLOY.md)."""

    def __init__(self, option_strings, dest, default=None, help=None, **kwargs):
        strings = [s for o in option_strings for s in ((o, "--no-" + o[2:]) if o.startswith("--") else (o,))]
        super().__init__(strings, dest, nargs=0, default=default, help=help, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, not option_string.startswith("--no-"))

    def format_usage(self) -> str:
        return " | ".join(self.option_strings)


def add_tie_option(parser) -> None:
    """--tie-hip-yaw-pitch, shared by identify and diagnose."""
    # default None (on for the NAO) so that an arm can refuse the option only when it is given
    parser.add_argument("--tie-hip-yaw-pitch", action=FlagPair, default=None,
                        help="NAO: joints on one motor take one offset (the NAO's HipYawPitch pair; default: on)")


def add_angles_option(parser) -> None:
    """--angles, shared by identify, diagnose and verify (each must read a dataset the same way)."""
    parser.add_argument("--angles", default="auto", choices=("auto", "measured", "cell", "commanded"),
                        help="NAO: joint angles used as theta: measured readings (the paper), cell (a still joint "
                             "whose readings are quantised and whose command lies inside its reading's step uses the "
                             "command), commanded, or auto (default): each is fitted and the best fit chosen")


def add_options(parser, verb: str) -> None:
    """The NAO's options of `verb` (kinds.Kind.add_options)."""
    if verb == "identify":
        add_tie_option(parser)
        parser.add_argument("--loss-scale-px", type=float, default=1.0,
                            help="NAO: residual where the robust loss bends (px)")
        parser.add_argument("--solver", default="lm", choices=("lm", "minpack"),
                            help="NAO: lm: naocal's Levenberg-Marquardt (fast); minpack: "
                                 "scipy.optimize.least_squares(method='lm')")
        add_angles_option(parser)
        parser.add_argument("--gls", action=FlagPair, default=True,
                            help="NAO: when the readings fit best and are quantised, refine by generalised least "
                                 "squares: the images of one held command share its error in the step, intrinsics "
                                 "free (docs/AGENT.md; the agent does the same; default: on)")
    elif verb == "diagnose":
        add_angles_option(parser)
        add_tie_option(parser)
    elif verb == "verify":
        add_angles_option(parser)
    elif verb == "simulate":
        parser.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                            help="inject a physical effect (repeatable): any effect the mock simulates, e.g. "
                                 "elasticity=0.02 or camera_translation=0.004 (docs/MOCK.md)")
        parser.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                            help="realistic (default: a NAO V6 as teams meet it, with real robots' errors) or ideal "
                                 "(the exact teaching robot) mock (docs/MOCK.md)")
        parser.add_argument("--plan", choices=("paper", "optimal"), default="paper",
                            help="the stance plan (default paper)")
        parser.add_argument("--stances-per-leg", type=int, default=24, metavar="N",
                            help="stances per leg (default 24)")
        parser.add_argument("--no-probe", action="store_true", help="leave out the lag probe")
        parser.add_argument("--speed", type=float, default=0.4, metavar="F",
                            help="speed fraction of moves (default 0.4)")
        parser.add_argument("--no-images", action="store_true", help="do not keep the rendered images")
        parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    elif verb == "calibrate":  # the generic options are tools/cmd_calibrate.py's
        parser.add_argument("--plan-seed", type=int, default=0,
                            help="seed of the measurement plan (default 0; the same plan for every robot)")
        parser.add_argument("--plan", choices=("paper", "optimal"), default="paper",
                            help="paper: 24 random stances per leg x 3 head postures (default); optimal: greedy "
                                 "D-optimal stances reaching the paper plan's precision")
        parser.add_argument("--stances-per-leg", type=int, default=24, metavar="N",
                            help="stances per leg of the paper plan (default 24)")
        parser.add_argument("--no-probe", action="store_true",
                            help="leave out the lag probe (slow sweeps; see docs/AGENT.md)")
        parser.add_argument("--speed", type=float, default=0.4, metavar="F",
                            help="fraction of the joints' maximum speed for moves between stances (default 0.4)")
        parser.add_argument("--max-joint-offset-deg", type=float, metavar="DEG",
                            help="refuse a calibration with a larger joint offset (default: the offsets file's "
                                 "limit, 20, solver/effects/joint_offsets.py; a warning above 8)")
        parser.add_argument("--max-camera-rotation-deg", type=float, metavar="DEG",
                            help="refuse a calibration with a larger camera rotation (default: the offsets file's "
                                 "limit, 15; a warning above 7)")
        parser.add_argument("--no-images", action="store_true", help="do not keep the captured images")
