"""The agent's settings from a command line's options, shared by `naocal calibrate` and the NAO's `naocal simulate`
(argparse Namespaces in, NaocalError (exit 2) for bad values)."""


def check_common(args) -> None:
    """Argument checks shared with `naocal simulate`: NaocalError (exit 2) for bad values."""
    from naocal.solver.errors import NaocalError

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

    from naocal.solver.effects import EFFECTS

    return {"max_joint_offset_deg": round(math.degrees(EFFECTS["joint_offsets"].offsets_limit), 9),
            "max_camera_rotation_deg": round(math.degrees(EFFECTS["camera_rotation"].offsets_limit), 9)}


def settings_from_args(args, *, seed: int, source: str):
    from naocal.agent.planner import PlanSettings
    from naocal.agent.states import AgentSettings

    import math

    from naocal.agent.states import Thresholds

    plan = PlanSettings(kind=args.plan, stances_per_leg=args.stances_per_leg, probe=not args.no_probe)
    given = {name: getattr(args, f"{name}_deg", None) for name in ("max_joint_offset", "max_camera_rotation")}
    thresholds = Thresholds(**{f"{name}_rad": math.radians(v) for name, v in given.items() if v is not None})
    return AgentSettings(seed=seed, plan=plan, speed_fraction=args.speed, resume=getattr(args, "resume", False),
                         save_images=not args.no_images, progress_bar=not args.no_progress, source=source,
                         thresholds=thresholds)


def log_warnings_to_stderr(verb: str, verbose: bool) -> None:
    """Warnings (all of it with -v) on stderr as `naocal VERB: LEVEL: message`, unless logging is set up already;
    the full log goes to the run's own file. For the verbs that run the agent (calibrate, simulate)."""
    import logging
    import sys

    if logging.getLogger().handlers:
        return
    console = logging.StreamHandler(sys.stderr)
    console.setLevel(logging.INFO if verbose else logging.WARNING)
    console.setFormatter(logging.Formatter(f"naocal {verb}: %(levelname)s: %(message)s"))
    logging.getLogger().addHandler(console)
