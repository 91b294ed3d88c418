"""`naocal calibrate`: calibrate a robot (the mock, or a NAO behind a bridge) end to end.

    naocal calibrate --backend mock|bridge [--endpoint URL] [--seed N] --out DIR [--resume] [--effect NAME=SIZE ...]

Modelling (plan) -> measurement (DIR/dataset) -> identification -> compensation (DIR/offsets.json) ->
verification; DIR/summary.txt says what happened, DIR/calibrate.log how. With the mock, DIR/truth.json holds its
hidden truth. Exit 0 when calibrated, 2 on bad input, 3 when the calibration failed (the reason is printed; what
was measured stays in DIR/dataset and a run that stopped during measurement continues with --resume).
"""

import argparse


def register(subparsers):
    p = subparsers.add_parser(
        "calibrate", help="calibrate the legs and bottom camera of a robot (mock or NAO) end to end",
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--backend", choices=("mock", "bridge"), required=True,
                   help="mock: the simulated NAO in this process; bridge: a robot behind `naocal bridge serve`")
    p.add_argument("--endpoint", metavar="URL", help="bridge server address, e.g. tcp://nao.local:7790")
    p.add_argument("--seed", type=int, default=0, help="mock: seed of its hidden truth (default 0)")
    p.add_argument("--plan-seed", type=int, default=0,
                   help="seed of the measurement plan (default 0; the same plan for every robot)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if absent)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run in DIR: captures already in DIR/dataset are kept, not repeated")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=SIZE",
                   help="mock: inject a physical effect (repeatable): elasticity, backlash, link_lengths, "
                        "head_offsets, intrinsics, distortion, time_lag")
    p.add_argument("--mock", choices=("ideal", "realistic"), default=None,
                   help="mock: realistic (default: a NAO V6 "
                        "as teams meet it: encoder steps, servo sag, rolling-shutter YUYV camera, offsets up to 12 "
                        "deg, faulty corners; docs/MOCK.md) or ideal (exact servos, 0.1 deg readings, small offsets: for teaching and exactness)")
    p.add_argument("--plan", choices=("paper", "optimal"), default="paper",
                   help="paper: 24 random stances per leg x 3 head postures (default); optimal: greedy D-optimal "
                        "stances reaching the paper plan's precision")
    p.add_argument("--stances-per-leg", type=int, default=24, metavar="N",
                   help="stances per leg of the paper plan (default 24)")
    p.add_argument("--no-probe", action="store_true", help="leave out the lag probe (slow sweeps; see docs/AGENT.md)")
    p.add_argument("--speed", type=float, default=0.4, metavar="F",
                   help="fraction of the joints' maximum speed for moves between stances (default 0.4)")
    p.add_argument("--max-joint-offset-deg", type=float, metavar="DEG",
                   help="refuse a calibration with a larger joint offset (default: the offsets file's limit, 20, "
                        "solver/effects/joint_offsets.py; a warning above 8)")
    p.add_argument("--max-camera-rotation-deg", type=float, metavar="DEG",
                   help="refuse a calibration with a larger camera rotation (default: the offsets file's limit, 15; "
                        "a warning above 7)")
    p.add_argument("--no-images", action="store_true", help="do not keep the captured images")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(run=run)


def check_common(args) -> None:
    """Argument checks shared with `naocal simulate`: NaocalError (exit 2) for bad values."""
    from solver.errors import NaocalError

    if args.seed < 0:
        raise NaocalError(f"--seed must not be negative, got {args.seed}")
    if getattr(args, "plan_seed", 0) < 0:
        raise NaocalError(f"--plan-seed must not be negative, got {args.plan_seed}")
    if not 1 <= args.stances_per_leg <= 200:
        raise NaocalError(f"--stances-per-leg must be within 1..200, got {args.stances_per_leg}")
    if not 0.0 < args.speed <= 1.0:
        raise NaocalError(f"--speed must be within (0, 1], got {args.speed}")
    for option, limit in _file_limits_deg().items():
        value = getattr(args, option, None)
        if value is not None and not 0.0 < value <= limit:
            raise NaocalError(f"--{option.replace('_', '-')} must be within (0, {limit:g}] (the offsets file's limit), "
                              f"got {value}")


def _file_limits_deg() -> dict:
    """{option: the largest value the offsets file holds, deg}: the effects' own limits (solver/effects/)."""
    import math

    from solver.effects import EFFECTS

    return {"max_joint_offset_deg": round(math.degrees(EFFECTS["joint_offsets"].offsets_limit), 9),
            "max_camera_rotation_deg": round(math.degrees(EFFECTS["camera_rotation"].offsets_limit), 9)}


def settings_from_args(args, *, seed: int, source: str):
    from agent.planner import PlanSettings
    from agent.states import AgentSettings

    import math

    from agent.states import Thresholds

    plan = PlanSettings(kind=args.plan, stances_per_leg=args.stances_per_leg, probe=not args.no_probe)
    given = {name: getattr(args, f"{name}_deg", None) for name in ("max_joint_offset", "max_camera_rotation")}
    thresholds = Thresholds(**{f"{name}_rad": math.radians(v) for name, v in given.items() if v is not None})
    return AgentSettings(seed=seed, plan=plan, speed_fraction=args.speed, resume=getattr(args, "resume", False),
                         save_images=not args.no_images, progress_bar=not args.no_progress, source=source,
                         thresholds=thresholds)


def check_out_dir(out, *, resume: bool, plan_seed: int) -> None:
    """Refuse to overwrite a run's data; on --resume, the stored plan must have this seed."""
    from agent.plan import read_plan
    from solver.errors import NaocalError

    if out.exists() and not out.is_dir():
        raise NaocalError(f"{out}: exists and is not a directory")
    if (out / "dataset" / "observations.csv").exists() and not resume:
        raise NaocalError(f"{out} already holds a calibration run: continue it with --resume, or choose another "
                          "--out (nothing was changed)")
    plan_path = out / "plan.json"
    if resume and plan_path.exists():
        plan = read_plan(plan_path)
        if plan.seed != plan_seed:
            raise NaocalError(f"{plan_path}: the run was planned with --plan-seed {plan.seed}; resume with it")


def run(args) -> int:
    import json
    import logging
    import sys
    from pathlib import Path

    from solver.errors import NaocalError

    check_common(args)
    out = Path(args.out)
    if args.backend == "bridge":
        if not args.endpoint:
            raise NaocalError("--backend bridge needs --endpoint URL (the address `naocal bridge serve` prints)")
        if args.effect:
            raise NaocalError("--effect injects effects into the mock; a bridge's robot is what it is")
        if args.mock is not None:
            raise NaocalError("--mock chooses the in-process mock; serve a realistic one with "
                              "`naocal bridge serve --driver mock --mock realistic`")
    elif args.endpoint:
        raise NaocalError("--endpoint is for --backend bridge")
    check_out_dir(out, resume=args.resume, plan_seed=args.plan_seed)
    if not logging.getLogger().handlers:  # warnings on stderr (all of it with -v); the full log goes to a file
        console = logging.StreamHandler(sys.stderr)
        console.setLevel(logging.INFO if args.verbose else logging.WARNING)
        console.setFormatter(logging.Formatter("naocal calibrate: %(levelname)s: %(message)s"))
        logging.getLogger().addHandler(console)

    from agent.calibrate import calibrate
    from solver.fileio import atomic_write_text

    settings = settings_from_args(args, seed=args.plan_seed, source=f"naocal calibrate --backend {args.backend}")
    truth = None
    detector = None
    if args.backend == "mock":
        from agent.measure import opencv_detector
        from backends.mock import MockBackend, parse_effect_sizes

        effects = parse_effect_sizes(args.effect)
        backend = MockBackend(args.seed, effects=effects, realism=args.mock or "realistic")
        detector = backend.faulty(opencv_detector)  # the realistic mock's detector errs now and then
        label = f"mock (seed {args.seed}, {args.mock or 'realistic'}" + (
            ", effects " + ", ".join(f"{k}={v:g}" for k, v in effects.items()) if effects else "") + ")"
        truth = backend.truth_dict()
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")
        atomic_write_text(out / "truth_effects.json", json.dumps(backend.effect_values_dict(), indent=1) + "\n")
    else:
        from backends.bridge import BridgeBackend

        backend = BridgeBackend(args.endpoint)
        label = f"bridge {args.endpoint}"
    try:
        result, ctx = calibrate(backend, out, settings, backend_label=label, truth=truth, detector=detector)
    finally:
        backend.close()
    summary = (out / "summary.txt").read_text(encoding="utf-8")
    if not result.ok:
        print(summary, end="")
        print(f"naocal calibrate: failed: {result.reason}", file=sys.stderr)
        return 3
    print(summary, end="")
    return 0
