"""`naocal calibrate --robot duckiebot`: the Duckiebot calibrated end to end by its mission (kinds.duckiebot.mission)
on the PyBullet mock (kinds.duckiebot.mock), or on the robot itself over Duckietown's ROS topics
(kinds.duckiebot.ros_driver; run inside Duckietown's dt-ros-commons container, $VEHICLE_NAME the robot's name:
docs/DEPLOY.md "Duckiebot (DB21)"), or from a laptop through `naocal bridge serve --robot duckiebot` on the robot
(kinds.duckiebot.bridge; CURVE keys from $NAOCAL_CURVE_SERVER_KEY, $NAOCAL_CURVE_CLIENT_KEY).

    naocal calibrate --robot duckiebot --backend mock [--mock ideal|realistic] [--seed N] --out RUN [--resume]
                     [--max-blind-m M]
    naocal calibrate --robot duckiebot --backend ros --out RUN [--resume] [--max-blind-m M]
    naocal calibrate --robot duckiebot --backend bridge --endpoint URL --out RUN [--resume] [--max-blind-m M]

RUN/log (the calibration drive: every command and frame as it happened, naocal.drive_log/1), RUN/validation (the
validation drive and leaving the area, the same format), RUN/encoders.csv (--backend ros on a DB21: every
encoder row as it came, appended and fsync'd; written into the logs' encoders.csv when the run is done),
RUN/offsets.json (the calibration, naocal.duckiebot_calibration/1, written once identified: `naocal offsets export`
makes Duckietown's files of it),
RUN/truth.json (the mock's hidden robot in the same names and units), RUN/summary.txt (what happened, the
validation, the truth beside the result), RUN/run.json (the options: --resume must repeat them), RUN/mission.json
(written last: the run is finished), RUN/mock_state.json (the mock's world: where its robot stands), RUN/bridge.token
(--backend bridge: the motion lease's secret, mode 0600, while the run holds it: a resumed run takes the robot back).
Exit 0 when calibrated and validated, 2 on bad input (nothing changed), 3 when the mission failed (the wheels are
stopped; summary.txt says why), 130 after Ctrl-C or SIGTERM (the wheels are stopped; --resume continues).

--resume keeps every capture saved. On the mock, whose world is saved with the run, the run goes on from where it
stopped. On the robot (--backend ros or bridge), whose pose is not saved (it may have been moved, or have rolled on
after a crash), the wheels are commanded stopped first, the logs replayed to rebuild the run, and the phase they end in
started again from its start conditions wherever the robot now stands (the marker line found again first); the
drive log gets a break there (segments.csv) and the joint fit a start pose per segment (mission.RestartedPhase).
A resumed run stopped again resumes again: the replay starts the phase again at each break as it went then.
Over the bridge by the same path: the client takes its lease back (RUN/bridge.token; DuckiebotBridge).
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

from naocal.agent.rundir import BRIDGE_TOKEN_NAME

RECORD_KEYS = ("robot", "backend", "mock_seed", "mock", "max_blind_m", "vehicle")
FINISHED_NAME = "mission.json"
ENCODER_JOURNAL = "encoders.csv"  # --backend ros: every encoder row as it came (ros_driver.keep_encoders)
ENTRIES = frozenset({"run.json", "log", "validation", "offsets.json", "truth.json", "summary.txt", FINISHED_NAME,
                     "mock_state.json", ".naocal.lock", ENCODER_JOURNAL, BRIDGE_TOKEN_NAME})
DEFAULT_MAX_BLIND_M = 0.3


def add_options(parser) -> None:
    """The Duckiebot's own options of `naocal calibrate` (the generic ones: --robot, --backend, --seed, --out,
    --resume, --mock)."""
    parser.add_argument("--max-blind-m", type=float, default=None, metavar="M",
                        help=f"duckiebot: stop when no floor marker has been seen for this far (default "
                             f"{DEFAULT_MAX_BLIND_M:g} m; at most 1): the robot never leaves the marked area by more")


def command_line(record: dict, out, resume: bool = True) -> str:
    parts = ["naocal", "calibrate", "--robot", "duckiebot", "--backend", record["backend"]]
    if record["backend"] == "mock":
        parts += ["--seed", str(record["mock_seed"])]
    if record["mock"] not in ("realistic", None):
        parts += ["--mock", record["mock"]]
    if record.get("endpoint"):
        parts += ["--endpoint", record["endpoint"]]
    if record["max_blind_m"] != DEFAULT_MAX_BLIND_M:
        parts += ["--max-blind-m", repr(record["max_blind_m"])]
    return shlex.join(parts + ["--out", str(out)] + (["--resume"] if resume else []))


def _record(args) -> dict:
    from naocal.kinds.duckiebot import KIND
    from naocal.solver.errors import NaocalError

    if args.backend not in KIND.calibrate_backends:
        raise NaocalError(f"--backend {args.backend}: the Duckiebot runs on --backend "
                          + " or ".join(KIND.calibrate_backends))
    vehicle = None
    if args.backend == "bridge":
        if not getattr(args, "endpoint", None):
            raise NaocalError("--backend bridge needs --endpoint URL (the address `naocal bridge serve --robot "
                              "duckiebot` prints)")
        if getattr(args, "mock", None) is not None:
            raise NaocalError("--backend bridge: --mock is the server's option (naocal bridge serve --robot duckiebot "
                              "--driver mock --mock ...)")
    if args.backend == "ros":
        import os

        vehicle = os.environ.get("VEHICLE_NAME")
        if not vehicle:
            raise NaocalError("--backend ros: $VEHICLE_NAME is not set (Duckietown's containers set it to the "
                              "robot's name: run inside dt-ros-commons on the robot; docs/DEPLOY.md)")
        if getattr(args, "mock", None) is not None:
            raise NaocalError("--mock chooses the simulated robot; --backend ros drives the real one")
    for option, given in (("--effect", getattr(args, "effect", None)),
                          ("--endpoint", args.backend != "bridge" and getattr(args, "endpoint", None)),
                          ("--report", getattr(args, "report", None))):
        if given:
            raise NaocalError(f"{option}: the Duckiebot's mock has no such option yet (its hidden effects are drawn "
                              "per seed; docs/DUCKIEBOT.md)")
    if args.seed < 0:
        raise NaocalError(f"--seed must not be negative, got {args.seed}")
    blind = DEFAULT_MAX_BLIND_M if getattr(args, "max_blind_m", None) is None else args.max_blind_m
    if not 0.05 <= blind <= 1.0:
        raise NaocalError(f"--max-blind-m must be within [0.05, 1] m, got {blind}")
    mock = args.backend == "mock"
    return {"schema": "naocal.run/1", "verb": "calibrate", "robot": "duckiebot", "backend": args.backend,
            "mock_seed": int(args.seed) if mock else None,
            "mock": (getattr(args, "mock", None) or "realistic") if mock else None, "max_blind_m": blind,
            "vehicle": vehicle, "endpoint": args.endpoint if args.backend == "bridge" else None}


def check_out_dir(out: Path, record: dict, resume: bool) -> None:
    """Refuse, before anything is written, a directory that is not this run's to write (NaocalError, exit 2)."""
    from naocal.agent.rundir import RECORD_NAME, check_resumable, entries, refuse_other_options
    from naocal.solver.errors import NaocalError
    from naocal.solver.fileio import read_json

    names = entries(out)
    if not names:
        return
    if (out / FINISHED_NAME).exists():
        raise NaocalError(f"{out} holds a finished calibration (offsets {out / 'offsets.json'}, summary "
                          f"{out / 'summary.txt'}): nothing to resume; choose another --out (nothing was changed)")
    check_resumable(out, names, resume=resume, own_entries=ENTRIES, what="a Duckiebot calibration run")
    recorded = read_json(out / RECORD_NAME)
    differ = [f"{key} {record[key]!r} (the run: {recorded.get(key)!r})" for key in RECORD_KEYS
              if recorded.get(key) != record[key]] if isinstance(recorded, dict) else ["run.json is not an object"]
    refuse_other_options(out / RECORD_NAME, differ,
                         command_line({**record, **recorded} if isinstance(recorded, dict) else record, out))


def summary_text(result, ctx, robot, truth: dict) -> str:
    lines = [f"naocal calibrate --robot duckiebot: {result.final}" + (f" ({result.reason})" if result.reason else ""),
             f"robot time {robot.now():.1f} s; frames: calibration {len(ctx.session.log.frames)}, validation "
             f"{len(ctx.validation_session.log.frames) if ctx.validation_session else 0}", "phases:"]
    lines += [f"  {s.state}: {s.outcome}{f' ({s.reason})' if s.reason else ''}, {s.robot_s:.1f} s robot, "
              f"{s.wall_s:.1f} s wall" for s in result.history]
    cal = ctx.calibration
    if cal is not None:
        kin, fit = cal.kinematics, cal.drive_fit
        lines.append(f"calibration: gain {kin.gain:.4f} (std {fit.stdev('gain'):.4f}), trim {kin.trim:.4f} (std "
                     f"{fit.stdev('trim'):.4f}), baseline {kin.baseline_m:.4f} m, lens {cal.lens.camera.model}, "
                     f"fit {fit.rms_px:.2f} px RMS over {len(fit.sightings.frame)} corners")
    if cal is not None and truth is not None:
        tk = truth["kinematics"]
        lines.append(f"the mock's truth: gain {tk['gain']:.4f}, trim {tk['trim']:.4f}, baseline "
                     f"{tk['baseline_m']:.4f} m (trim error {abs(kin.trim - tk['trim']):.4f}, gain error "
                     f"{100 * abs(kin.gain / tk['gain'] - 1):.2f} %)")
    if ctx.validation is not None:
        v = ctx.validation
        lines.append(f"validation: {v['driven_m']:.2f} m straight at {ctx.settings.speed_mps:g} m/s, "
                     f"{100 * v['deviation_m']:+.1f} cm off its start heading (Duckietown's rule: 10 cm; "
                     f"{100 * v['off_line_m']:+.1f} cm off the marker line)")
    return "\n".join(lines) + "\n"


def run(args) -> int:
    from naocal.agent.machine import DONE, INTERRUPTED
    from naocal.agent.rundir import RunLock, write_record
    from naocal.kinds.duckiebot.calibration import write_calibration_file
    from naocal.kinds.duckiebot.mission import MissionSettings, run_mission
    from naocal.solver.fileio import atomic_write_text

    record = _record(args)
    out = Path(args.out)
    resume = bool(getattr(args, "resume", False))
    check_out_dir(out, record, resume)
    settings = MissionSettings(max_blind_m=record["max_blind_m"])
    robot = None
    if record["backend"] == "ros":  # connected before anything is written: a robot not there leaves nothing
        from naocal.kinds.duckiebot.ros_driver import RosDuckiebot

        robot = RosDuckiebot(record["vehicle"])
        robot_id, source = record["vehicle"], f"naocal calibrate --robot duckiebot --backend ros ({record['vehicle']})"
    elif record["backend"] == "bridge":  # the server asked before anything is written, as the ROS topics
        from naocal.kinds.duckiebot.bridge import DuckiebotBridge

        robot = DuckiebotBridge(record["endpoint"], lease_file=out / BRIDGE_TOKEN_NAME)  # a resume takes it back
        try:
            robot_id = robot.robot_id
        except BaseException:
            robot.close()
            raise
        source = f"naocal calibrate --robot duckiebot --backend bridge ({robot_id} at {record['endpoint']})"
    else:
        robot_id, source = f"mock{record['mock_seed']}", (f"naocal calibrate --robot duckiebot --backend mock "
                                                          f"--seed {record['mock_seed']}")
    try:
        with RunLock(out, command_line(record, out, resume)):
            if not (out / "run.json").exists():
                write_record(out, record)
            if hasattr(robot, "keep_encoders"):  # a DB21's ticks saved as they come: a crash keeps them
                robot.keep_encoders(out / ENCODER_JOURNAL)
            truth = None
            if robot is None:
                from naocal.kinds.duckiebot.mock import DuckiebotMock, truth_document  # pybullet: not on the robot

                robot = DuckiebotMock(record["mock_seed"], record["mock"], state_path=out / "mock_state.json")
                truth = truth_document(robot.truth, record["mock_seed"], record["mock"])
                atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")  # the agent never reads it

            def write_offsets(calibration):
                what = (f"{robot_id}" if record["backend"] in ("ros", "bridge") else
                        f"mock seed {record['mock_seed']} ({record['mock']})")
                findings = write_calibration_file(out / "offsets.json", calibration,
                                                  source=f"naocal calibrate --robot duckiebot, {what}")
                for finding in findings:
                    print(f"naocal calibrate: warning: {finding}", file=sys.stderr)

            # the robot's pose is not saved with the run (the mock's is): a resumed phase starts again where it stands
            result, ctx = run_mission(robot, out, settings, robot_id=robot_id, source=source,
                                      on_calibration=write_offsets, restart_phase=record["backend"] != "mock")
            # a DB21's ticks into the drive logs (a DB18 has none) once finished: log.json then gives their resolution,
            # and a resumable run's log.json must stay the one it was started with (DriveLogAppender); until then
            # RUN/encoders.csv (--backend ros) or the server's driver (--backend bridge) keeps them
            if result.final == DONE and hasattr(robot, "save_encoders"):
                for session in (ctx.session, ctx.validation_session):
                    if session is not None and session.log.wheels:
                        robot.save_encoders(session.log.directory, session.log.wheels[0][0],
                                            session.log.last_time_s())
            text = summary_text(result, ctx, robot, truth)
            atomic_write_text(out / "summary.txt", text)
            print(text, end="")
            if result.final == DONE:
                atomic_write_text(out / FINISHED_NAME, json.dumps({"final": DONE, "validation": ctx.validation},
                                                                  indent=1) + "\n")
                return 0
            if result.final == INTERRUPTED:
                print(f"naocal calibrate: to continue: {command_line(record, out)}", file=sys.stderr)
                return 130
            print(f"naocal calibrate: error: {result.reason} (the wheels are stopped; {out / 'summary.txt'})",
                  file=sys.stderr)
            return 3
    finally:
        if robot is not None:
            robot.close()
