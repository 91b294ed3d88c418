"""`naocal simulate`: record a dataset of the simulated NAO, with its hidden truth beside it.

    naocal simulate --out DIR [--seed N] [--effect NAME=SIZE ...] [--mock ideal|realistic]
    naocal simulate --robot kuka_iiwa|franka_panda|URDF [--chain BASE:TIP] --out DIR [--seed N] [--poses N]
        a simulated arm instead (docs/ARM.md): naocal.arm_dataset/1 and its hidden truth in DIR/truth.json

Runs the agent's modelling and measurement (the standard plan: 24 stances per leg x 3 head postures, plus the lag
probe) on the PyBullet mock and writes the naocal.dataset/2 directory DIR (dataset.json, observations.csv,
images/) and DIR/truth.json (naocal.truth/2: the mock's alpha, camera rotations, board mounts and effects; with
--effect also DIR/truth_effects.json: what each effect drew, e.g. camera_translation's shift of each camera).
Exit 0 on success, 2 on bad input, 3 if the measurement failed.
"""

import argparse


def register(subparsers):
    p = subparsers.add_parser(
        "simulate", help="record a dataset of the simulated NAO (with its hidden truth in truth.json)",
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, metavar="DIR", help="the dataset directory to create")
    p.add_argument("--seed", type=int, default=0, help="seed of the mock's hidden truth and of the plan (default 0)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                   help="inject a physical effect (repeatable): any effect the mock simulates, e.g. "
                        "elasticity=0.02 or camera_translation=0.004 (docs/MOCK.md)")
    p.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                   help="realistic (default: a NAO V6 as teams meet it, with real robots' errors) or ideal (the "
                        "exact teaching robot) mock (docs/MOCK.md)")
    p.add_argument("--plan", choices=("paper", "optimal"), default="paper", help="the stance plan (default paper)")
    p.add_argument("--stances-per-leg", type=int, default=24, metavar="N", help="stances per leg (default 24)")
    p.add_argument("--no-probe", action="store_true", help="leave out the lag probe")
    p.add_argument("--speed", type=float, default=0.4, metavar="F", help="speed fraction of moves (default 0.4)")
    p.add_argument("--no-images", action="store_true", help="do not keep the rendered images")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    from tools.arm_cli import add_arm_options

    add_arm_options(p, simulate=True)  # an arm instead of the NAO (docs/ARM.md)
    p.add_argument("--poses", type=int, default=60, metavar="N", help="arm: stances (default 60)")
    p.add_argument("--noise-m", type=float, default=1e-4, help="arm: the 3-D sensor's noise per axis (default 1e-4 m)")
    p.add_argument("--noise-px", type=float, default=0.2, help="arm: the camera's noise per axis (default 0.2 px)")
    p.add_argument("--hidden", default="joint_offsets,link_lengths",
                   help="arm: the hidden errors (default joint_offsets,link_lengths)")
    p.set_defaults(run=run)


def run(args) -> int:
    import json
    import logging
    import shlex
    import sys
    from pathlib import Path

    from agent.rundir import RunLock, entries
    from solver.errors import NaocalError
    from tools.cmd_calibrate import check_common, settings_from_args

    if args.robot or args.chain:
        from tools.arm_cli import run_simulate

        return run_simulate(args)

    check_common(args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise NaocalError(f"{out}: already exists and is not a directory (nothing was changed)")
    from backends.mock import MockBackend, parse_effect_sizes

    effects = parse_effect_sizes(args.effect)
    command = shlex.join(["naocal", "simulate", "--out", str(out), "--seed", str(args.seed)]
                         + (["--mock", args.mock] if args.mock else [])
                         + [f"--effect={k}={v!r}" for k, v in effects.items()])
    with RunLock(out, command):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        if not logging.getLogger().handlers:  # warnings on stderr (all of it with -v); the full log goes to a file
            console = logging.StreamHandler(sys.stderr)
            console.setLevel(logging.INFO if args.verbose else logging.WARNING)
            console.setFormatter(logging.Formatter("naocal simulate: %(levelname)s: %(message)s"))
            logging.getLogger().addHandler(console)

        from agent.calibrate import simulate
        from agent.machine import INTERRUPTED
        from agent.measure import opencv_detector
        from solver.fileio import atomic_write_text

        settings = settings_from_args(args, seed=args.seed, source=f"naocal simulate --seed {args.seed}")
        backend = MockBackend(args.seed, effects=effects, realism=args.mock or "realistic")
        try:
            atomic_write_text(out / "truth.json", json.dumps(backend.truth_dict(), indent=1) + "\n")
            if effects:  # what each injected effect drew, as `naocal calibrate` writes it
                atomic_write_text(out / "truth_effects.json", json.dumps(backend.effect_values_dict(), indent=1) + "\n")
            result, ctx = simulate(backend, out, settings, detector=backend.faulty(opencv_detector))
        finally:
            backend.close()
    if result.final == INTERRUPTED:
        print(f"naocal simulate: interrupted; {out} holds the captures made so far (a dataset of its own; "
              "simulate does not resume)", file=sys.stderr)
        return 130
    if not result.ok:
        print(f"naocal simulate: failed: {result.reason}", file=sys.stderr)
        return 3
    m = ctx.measurement
    print(f"naocal simulate: wrote {out}: {m['n_saved']} of {m['n_planned']} images "
          f"({m['n_skipped']} skipped), {m['robot_time_s']:.1f} s of robot time; hidden truth in {out / 'truth.json'}")
    return 0
