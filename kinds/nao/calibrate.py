"""The NAO's body of `naocal calibrate` (tools/cmd_calibrate.py dispatches to it; docs/AGENT.md).

Modelling (plan) -> measurement (DIR/dataset) -> identification -> compensation (DIR/offsets.json) ->
verification; DIR/summary.txt says what happened, DIR/calibrate.log how, DIR/run.json with which options. With the
mock, DIR/truth.json holds its hidden truth. With --report, REPORT_DIR/index.html is naocal diagnose's report of
DIR's dataset. One run at a time per DIR; --resume must repeat the run's options.
"""


def calibrate_command(record: dict, out, *, endpoint=None, no_progress: bool = False, resume: bool = True) -> str:
    """The shell command (quoted) that runs, or with `resume` continues, the run `record` describes in `out`."""
    import shlex

    parts = ["naocal", "calibrate", "--backend", record["backend"]]
    if endpoint:
        parts += ["--endpoint", endpoint]
    if record["backend"] == "mock":
        parts += ["--seed", str(record["mock_seed"])]
        if record.get("mock", "ideal") != "realistic":  # the default mock; runs from before --mock were ideal
            parts += ["--mock", record.get("mock", "ideal")]
    for name, size in record["effects"].items():
        parts += ["--effect", f"{name}={size!r}"]
    if record["plan"] != "paper":
        parts += ["--plan", record["plan"]]
    if record["plan_seed"]:
        parts += ["--plan-seed", str(record["plan_seed"])]
    if record["stances_per_leg"] != 24:
        parts += ["--stances-per-leg", str(record["stances_per_leg"])]
    if not record["probe"]:
        parts.append("--no-probe")
    if record.get("speed", 0.4) != 0.4:
        parts += ["--speed", repr(record["speed"])]
    if not record.get("images", True):
        parts.append("--no-images")
    if no_progress:
        parts.append("--no-progress")
    parts += ["--out", str(out)] + (["--resume"] if resume else [])
    return shlex.join(parts)


def check_out_dir(out, *, resume: bool, record: dict, command) -> None:
    """Refuse, before anything is written, a directory that is not this run's to write: a dataset (naocal
    simulate's), a finished run, another run without --resume, foreign files, or a run started with other options.
    `command(record)` is the command line that resumes the run `record` describes."""
    from naocal.agent.calibrate import check_unfinished
    from naocal.agent.rundir import CALIBRATE_ENTRIES, check_resumable, entries, mismatches, recorded_run, \
        refuse_other_options
    from naocal.solver.errors import NaocalError

    names = entries(out)
    if not names:
        return  # new or empty: a new run
    if "dataset.json" in names or "observations.csv" in names:
        raise NaocalError(f"{out} holds a dataset ({out / 'dataset.json'}, e.g. from naocal simulate); calibrate "
                          "writes a run directory of its own: choose another --out (nothing was changed)")
    check_unfinished(out)  # with or without --resume: a finished run is not run again
    check_resumable(out, names, resume=resume, own_entries=CALIBRATE_ENTRIES, what="a calibration run")
    recorded, source = recorded_run(out)
    refuse_other_options(source, mismatches(recorded, record), command({**record, **recorded}))


def realistic_mock_note(realism) -> str:
    """The one line a run on the realistic mock prints first: the warnings that follow (a large offset, skipped
    captures, corners set aside) are the errors it has on purpose, found as they would be on a real robot. Its
    figures are the mock's own (backends.mock_realism.Realism)."""
    return (f"naocal calibrate: note: the realistic mock (the default) is a NAO V6 with real robots' errors, built in "
            f"on purpose: joint offsets up to {realism.hip_yaw_pitch_max_deg:g} deg (HipYawPitch), glare on "
            f"{100 * realism.glare_rate:g} % of the frames, {100 * realism.corner_fault_rate:g} % of the corners "
            "mis-detected. The warnings that follow of an unusually large offset and of skipped captures, and the "
            "corners the summary sets aside, are these errors, found as on a real robot: nothing is wrong "
            "(docs/MOCK.md, 'The realistic NAO V6'; --mock ideal: the exact teaching robot)")


def check_report_directory(report, out) -> None:
    """--report: a directory we may write in, outside the run directory (which holds the run's own files only)."""
    from naocal.solver.errors import NaocalError
    from naocal.solver.fileio import check_output_directory

    check_output_directory(report)
    if report.resolve() == out.resolve() or out.resolve() in report.resolve().parents:
        raise NaocalError(f"--report {report} lies in --out {out}, which holds the run's own files only: choose a "
                          f"directory beside it, e.g. --report {out.with_name(out.name + '-report')}")


def write_run_report(report, out, ctx) -> str | None:
    """The diagnostics report of the run's dataset in `report` (naocal diagnose's, its routine and defaults), once
    the measurement is complete; prints where it is, or why there is none. Returns the error, if it failed."""
    import sys

    from naocal.agent.rundir import find_dataset
    from naocal.kinds.nao.diagnose import diagnose_dataset, write_diagnosis_report
    from naocal.solver.errors import NaocalError

    if ctx.measurement is None:
        print("naocal calibrate: no report: the measurement did not finish", file=sys.stderr)
        return None
    try:
        dataset_path = find_dataset(out)
        dataset, _, diagnosis = diagnose_dataset(dataset_path)  # `naocal diagnose DATASET --report DIR`'s defaults
        print(f"report: {write_diagnosis_report(report, diagnosis, dataset, dataset_path)}")
    except NaocalError as err:
        print(f"naocal calibrate: error: report not written: {err}", file=sys.stderr)
        return str(err)
    return None


def run(args, backends: dict) -> int:
    """The NAO's `naocal calibrate`; backends: the kind's calibrate_backends {name: what it is} (the kind passes
    its own: this module imports nothing of its package, which imports it)."""
    import logging
    from pathlib import Path

    from naocal.agent.rundir import RunLock, calibrate_record
    from naocal.agent.options import check_common
    from naocal.solver.errors import NaocalError

    check_common(args)
    out = Path(args.out)
    if args.report:
        check_report_directory(Path(args.report), out)
    from naocal import kinds

    if args.backend not in backends:  # another kind's backend (the parser offers every kind's)
        owners = [k.name for k in kinds.capable("calibrate") if args.backend in getattr(k, "calibrate_backends", {})]
        raise NaocalError(f"--backend {args.backend} is another robot kind's (--robot {' or '.join(owners)}); a NAO "
                          "runs on --backend " + " or ".join(backends))
    if args.backend == "bridge":
        if not args.endpoint:
            raise NaocalError("--backend bridge needs --endpoint URL (the address `naocal bridge serve` prints)")
        from naocal.backends.bridge_endpoint import check_client_endpoint

        check_client_endpoint(args.endpoint)
        if args.effect:
            raise NaocalError("--effect injects effects into the mock; a bridge's robot is what it is")
        if args.mock is not None:
            raise NaocalError("--mock chooses the in-process mock; serve a realistic one with "
                              "`naocal bridge serve --driver mock --mock realistic`")
        from naocal.backends.bridge import check_server_answers

        check_server_answers(args.endpoint)  # before the run directory exists: a dead endpoint leaves nothing
    elif args.endpoint:
        raise NaocalError("--endpoint is for --backend bridge")
    effects = {}
    if args.backend == "mock":
        from naocal.backends.mock import parse_effect_sizes

        effects = parse_effect_sizes(args.effect)
    realism = (args.mock or "realistic") if args.backend == "mock" else None
    record = calibrate_record(backend=args.backend, mock_seed=args.seed if args.backend == "mock" else None,
                              mock=realism, effects=effects, plan=args.plan,
                              plan_seed=args.plan_seed, stances_per_leg=args.stances_per_leg, probe=not args.no_probe,
                              speed=args.speed, images=not args.no_images)

    def command(the_record, resume=True):
        return calibrate_command(the_record, out, endpoint=args.endpoint, no_progress=args.no_progress,
                                 resume=resume)

    with RunLock(out, command(record, args.resume)):
        check_out_dir(out, resume=args.resume, record=record, command=command)
        if args.resume:  # a session killed mid-write left temporary files: ours (we hold the lock), never used
            from naocal.solver.fileio import remove_stale_temporaries

            for path in remove_stale_temporaries(out):
                logging.getLogger("naocal.calibrate").info("removed %s, left by a session killed while writing it",
                                                           path)
        return _calibrate(args, out, record, effects, resume_hint=command(record))


def _calibrate(args, out, record, effects, *, resume_hint: str) -> int:
    """The run itself, in a checked and locked DIR."""
    import json
    import sys
    from pathlib import Path

    from naocal.agent.options import log_warnings_to_stderr
    from naocal.agent.rundir import RECORD_NAME, write_record

    log_warnings_to_stderr("calibrate", args.verbose)

    from naocal.agent.calibrate import calibrate
    from naocal.agent.machine import INTERRUPTED
    from naocal.agent.options import settings_from_args
    from naocal.agent.summary import resumable
    from naocal.solver.fileio import atomic_write_text

    settings = settings_from_args(args, seed=args.plan_seed, source=f"naocal calibrate --backend {args.backend}")
    settings.mock_seed = record["mock_seed"]
    settings.resume_command = resume_hint
    truth = None
    detector = None
    if args.backend == "mock":
        from naocal.agent.measure import opencv_detector
        from naocal.backends.mock import MockBackend

        backend = MockBackend(args.seed, effects=effects, realism=record["mock"])
        detector = backend.faulty(opencv_detector)  # the realistic mock's detector errs now and then
        deliberate = record["mock"] == "realistic"  # errors built in on purpose: say so, first and once
        if deliberate:
            print(realistic_mock_note(backend.realism), file=sys.stderr)
        label = f"mock (seed {args.seed}, {record['mock']}" + (
            ": real robots' errors on purpose, docs/MOCK.md" if deliberate else "") + (
            ", effects " + ", ".join(f"{k}={v:g}" for k, v in effects.items()) if effects else "") + ")"
        truth = backend.truth_dict()
    else:
        from naocal.agent.rundir import BRIDGE_TOKEN_NAME
        from naocal.backends.bridge import BridgeBackend

        # The lease token stays with the run, so `--resume` after a crash takes the robot back at once.
        backend = BridgeBackend(args.endpoint, lease_file=out / BRIDGE_TOKEN_NAME)
        label = f"bridge {args.endpoint}"
    try:
        if not (out / RECORD_NAME).exists():
            write_record(out, record)
        if truth is not None and not (out / "truth.json").exists():  # on --resume: the same truth, kept as it is
            atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")
            atomic_write_text(out / "truth_effects.json", json.dumps(backend.effect_values_dict(), indent=1) + "\n")
        result, ctx = calibrate(backend, out, settings, backend_label=label, truth=truth,
                                detector=detector)
    finally:
        backend.close()
    print(ctx.summary, end="")
    report_error = write_run_report(Path(args.report), out, ctx) if args.report else None
    if result.ok:
        return 3 if report_error else 0
    unsaved = f"; {ctx.summary_error} (the summary is printed above)" if ctx.summary_error else ""
    if result.final == INTERRUPTED:
        stopped = result.history[-1]  # its reason: what stopped the run (Ctrl-C, SIGTERM, SIGHUP)
        saved = ""
        if ctx.store is not None and ctx.plan is not None:
            n_saved = len(ctx.store.saved_images() & set(ctx.plan.image_indices()))
            saved = f"; {n_saved} of {ctx.plan.n_images()} images saved"
        print(f"naocal calibrate: interrupted during {stopped.state} ({stopped.reason}{saved}){unsaved}; continue "
              f"with: {resume_hint}", file=sys.stderr)
        return 130
    continue_hint = f"; continue with: {resume_hint}" if resumable(result) else ""
    print(f"naocal calibrate: failed: {result.reason}{unsaved}{continue_hint}", file=sys.stderr)
    return 3
