"""The `naocal` command line.

Each verb lives in its own module `tools/cmd_<verb>.py` with two functions:
`register(subparsers)` adds its argparse parser (argparse only: no heavy imports, so `naocal --help` is instant)
and `run(args) -> int` does the work, importing numpy, scipy, pybullet ... inside.
"""

import argparse
import importlib
import sys

VERB_MODULES = (
    "tools.cmd_calibrate",
    "tools.cmd_simulate",
    "tools.cmd_identify",
    "tools.cmd_diagnose",
    "tools.cmd_offsets",
    "tools.cmd_bridge",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="naocal",
        description="Automatic kinematic calibration of the NAO robot's legs and bottom camera.",
    )
    parser.add_argument("--verbose", "-v", action="store_true", help="log more, and show tracebacks of errors")
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB")
    subparsers.required = True
    for module_name in VERB_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from solver.errors import NaocalError

    try:
        return int(args.run(args) or 0)
    except NaocalError as err:
        if args.verbose:
            raise
        print(f"naocal {args.verb}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"naocal {args.verb}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
