"""The `naocal` command line.

Each verb lives in its own module `tools/cmd_<verb>.py` with two functions:
`register(subparsers)` adds its argparse parser (argparse only: no heavy imports, so `naocal --help` is instant)
and `run(args) -> int` does the work, importing numpy, scipy, pybullet ... inside.
"""

import argparse
import importlib
import os
import signal
import sys
import threading

# One BLAS thread unless the user says otherwise. naocal's matrices are small (3456 x 21): threads gain
# nothing on an idle 2-core machine (identify 12.4 ms with 2, 13.0 ms with 1) and lose badly when the other core
# is busy, as it is on a robot running NAOqi (see benchmarks/bench_identify.py --busy).
# Set before numpy is first imported, which happens only after argument parsing.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

VERB_MODULES = (
    "naocal.tools.cmd_calibrate",
    "naocal.tools.cmd_simulate",
    "naocal.tools.cmd_identify",
    "naocal.tools.cmd_diagnose",
    "naocal.tools.cmd_verify",
    "naocal.tools.cmd_offsets",
    "naocal.tools.cmd_bridge",
    "naocal.tools.cmd_detect",
    "naocal.tools.cmd_import",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="naocal",
        description="Automatic kinematic calibration of the NAO robot's legs and cameras (top and bottom), and of "
                    "any serial arm from its URDF.",
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
    from naocal.solver.errors import NaocalError

    _terminate_like_ctrl_c()
    try:
        return int(args.run(args) or 0)
    except NaocalError as err:
        if args.verbose:
            raise
        return _error(args.verb, str(err), err.exit_code)
    except BrokenPipeError:
        return 0
    # Last resorts: the readers and writers turn these into NaocalErrors naming the file; should one slip
    # through, the user still gets one line (with -v, the traceback), never a traceback.
    except OSError as err:
        if args.verbose:
            raise
        where = f"{err.filename}: " if err.filename else ""
        return _error(args.verb, f"{where}{(err.strerror or str(err)).lower()}", 2)
    except (MemoryError, RecursionError) as err:
        if args.verbose:
            raise
        what = "out of memory" if isinstance(err, MemoryError) else "input nested too deeply"
        return _error(args.verb, f"{what} (is an input file damaged or far too large?)", 2)
    except KeyboardInterrupt as interrupt:
        from naocal.agent.machine import interrupt_cause

        print(f"naocal {args.verb}: interrupted ({interrupt_cause(interrupt)})", file=sys.stderr)
        return 130


def _terminate_like_ctrl_c() -> None:
    """SIGTERM (systemd, `kill`, a closing terminal's SIGHUP) ends a run as Ctrl-C does: the state machine stops in
    `interrupted`, saves the summary and prints the resume command, instead of dying between two writes.
    `bridge serve` installs its own handlers later."""
    if threading.current_thread() is not threading.main_thread():
        return

    def interrupt(signum, _frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)  # the run records it: agent.machine.interrupt_cause

    for signum in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(signum) == signal.SIG_DFL:  # an ignored SIGHUP (nohup) stays ignored
            signal.signal(signum, interrupt)


def _error(verb: str, message: str, exit_code: int) -> int:
    """Print one line (line breaks in the message flattened) and return the exit code."""
    one_line = message.replace("\r\n", " ").replace("\n", " ").replace("\r", " ")
    print(f"naocal {verb}: error: {one_line}", file=sys.stderr)
    return exit_code


if __name__ == "__main__":
    sys.exit(main())
