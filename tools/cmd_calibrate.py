"""`naocal calibrate`: calibrate a robot (the mock, or a robot behind a bridge) end to end.

    naocal calibrate [--robot KIND] --backend BACKEND [--endpoint URL] [--seed N] --out DIR [--resume]
                     [--effect NAME=SIZE ...] [--report REPORT_DIR]

--robot chooses the robot kind (default: the NAO, its legs and cameras); the kind's own options follow the common
ones. DIR/summary.txt says what happened, DIR/run.json with which options, DIR/offsets.json holds the calibration;
with the mock, DIR/truth.json holds its hidden truth. With --report, REPORT_DIR/index.html is naocal diagnose's
report of DIR's data. One run at a time per DIR; --resume must repeat the run's options.
Exit 0 when calibrated, 2 on bad input (nothing changed), 3 when the calibration (or its --report) failed or the disk
is full, 130 after Ctrl-C, SIGTERM or SIGHUP (the reason is printed; what was measured stays in DIR, and the last
line printed is the command that continues the run). A finished run is not run again (nor resumed).
"""

import argparse

import naocal.kinds as kinds


def register(subparsers):
    able = [k.name for k in kinds.capable("calibrate")]
    p = subparsers.add_parser(
        "calibrate", help="calibrate a robot end to end: a NAO's legs and cameras (default), or --robot "
                          + ", ".join(n for n in able if n != kinds.default().name),
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=able, default=kinds.default().name,
                   help=f"the robot kind to calibrate (default {kinds.default().name})")
    backends = {}  # each kind's (calibrate_backends): name -> what it is, per kind
    for kind in kinds.capable("calibrate"):
        for name, what in getattr(kind, "calibrate_backends", {}).items():
            backends.setdefault(name, []).append(f"{kind.name}: {what}")
    p.add_argument("--backend", choices=tuple(backends), required=True,
                   help="; ".join(f"{name} ({', '.join(whats)})" for name, whats in backends.items()))
    p.add_argument("--endpoint", metavar="URL", help="bridge server address, e.g. tcp://nao.local:7790")
    p.add_argument("--seed", type=int, default=0, help="mock: seed of its hidden truth (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if absent)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run in DIR: captures already in DIR are kept, not repeated "
                        "(a finished run is refused: nothing to continue, and its verification would move the robot)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                   help="mock: inject a physical effect (repeatable): any effect the kind's mock simulates, e.g. "
                        "the NAO's elasticity=0.02 (docs/MOCK.md)")
    p.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                   help="mock: realistic (default: the robot as labs meet it, real robots' errors built in on "
                        "purpose; for the NAO a V6 with encoder steps, servo sag, rolling-shutter YUYV camera, "
                        "offsets up to 12 deg, faulty corners; docs/MOCK.md) or ideal (exact: for teaching and "
                        "exactness)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--report", metavar="REPORT_DIR",
                   help="once the measurement is complete, write the diagnostics report of the run's data to "
                        "REPORT_DIR/index.html, as `naocal diagnose DIR --report REPORT_DIR` does (outside DIR)")
    kinds.add_options(p, "calibrate")  # each kind's own (the NAO's plan, stances, speed ...)
    p.set_defaults(run=run)


def run(args) -> int:
    return kinds.named(args.robot).calibrate(args)
