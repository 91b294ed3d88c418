"""The NAO's `naocal simulate` (the verb and its help: tools/cmd_simulate.py): record a dataset of the simulated
NAO, with its hidden truth beside it."""


def run(args, kind) -> int:
    import json
    import shlex
    import sys
    from pathlib import Path

    from naocal.agent.options import check_common, log_warnings_to_stderr, settings_from_args
    from naocal.agent.rundir import RunLock, entries
    from naocal.solver.errors import NaocalError

    check_common(args)
    from naocal.kinds import foreign_options

    given = foreign_options(args, kind)
    if given:  # another kind's option (an arm's --poses, --camera-error) would be silently ignored here
        raise NaocalError(f"{given[0]} is not an option of the NAO's simulate (another robot kind's: give --robot)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise NaocalError(f"{out}: already exists and is not a directory (nothing was changed)")
    from naocal.backends.mock import MockBackend, parse_effect_sizes

    effects = parse_effect_sizes(args.effect)
    command = shlex.join(["naocal", "simulate", "--out", str(out), "--seed", str(args.seed)]
                         + (["--mock", args.mock] if args.mock else [])
                         + [f"--effect={k}={v!r}" for k, v in effects.items()])
    with RunLock(out, command):
        if entries(out):
            raise NaocalError(f"{out}: already exists and is not an empty directory (nothing was changed)")
        log_warnings_to_stderr("simulate", args.verbose)

        from naocal.agent.calibrate import simulate
        from naocal.agent.machine import INTERRUPTED
        from naocal.agent.measure import opencv_detector
        from naocal.solver.fileio import atomic_write_text

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
