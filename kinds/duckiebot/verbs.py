"""The Duckiebot's bodies of `naocal identify LOG`, `naocal verify LOG [--offsets CAL|DIR]` and `naocal offsets` (show,
validate, diff, export --format duckietown|json); the kind (kinds/duckiebot/__init__.py) claims drive logs, its
calibration files and `--robot duckiebot` (docs/DUCKIEBOT.md)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from naocal.solver.errors import DataError, NaocalError, SolveError

# Duckietown's wheel calibration (docs/DUCKIEBOT.md): commanded straight at 0.3 m/s for 2 m, the robot must end
# within 10 cm of the line; naocal's goal is 2 cm.
STRAIGHT_DISTANCE_M = 2.0
STRAIGHT_SPEED_MPS = 0.3
DUCKIETOWN_RULE_M = 0.10
GOAL_M = 0.02
# Options of other kinds a Duckiebot's verb takes as they are: simulate's mock options are the NAO's in the parser
# (registered first) but mean the same for any mock.
SHARED_WITH_THE_DEFAULT_KIND = {"simulate": ("--mock", "--effect", "--no-progress")}


def check_options(args, kind) -> None:
    """Refuse, in one line, another kind's options given to a Duckiebot's verb (`--robot duckiebot` itself chose
    this kind)."""
    allowed = SHARED_WITH_THE_DEFAULT_KIND.get(getattr(args, "verb", ""), ())
    from naocal.kinds import foreign_options

    given = [o for o in foreign_options(args, kind) if o not in allowed
             and not (o == "--robot" and getattr(args, "robot", None) == kind.name)]
    if given:
        raise NaocalError(f"{given[0]} is not a Duckiebot's option (another robot kind's; docs/DUCKIEBOT.md)")


def _refuse_unsupported(args) -> None:
    """identify's options every kind shares that a Duckiebot's joint fit has no use for."""
    if getattr(args, "cv_folds", 5) not in (0, 5):
        raise NaocalError("--cv-folds: a Duckiebot's fit is judged by its lens models' held-out error, not by folds")


def log_inputs(log) -> list:
    """Every file a drive log's reading used (an output must be none of them)."""
    from naocal.kinds.duckiebot.drive_log import ENCODERS_FILE, FRAMES_FILE, META_FILE, WHEELS_FILE

    files = [log.path / META_FILE, log.path / WHEELS_FILE, log.path / FRAMES_FILE, log.path / ENCODERS_FILE]
    return files + [log.frame_path(i) for i in range(len(log.frame_files))]


def check_log_output(out, log, inputs) -> None:
    """DataError unless `out` can be written (check_output_file: never over one of `inputs`) and lies outside the
    drive log's directory: a log is a record, and naocal writes nothing into it."""
    import os

    from naocal.solver.fileio import check_output_file

    check_output_file(out, inputs=inputs)
    log_dir = os.path.realpath(log.path)
    if os.path.commonpath([log_dir, os.path.realpath(out)]) == log_dir:
        raise DataError(out, f"is inside the drive log {log.path}: naocal writes nothing into a log; give a name "
                             "outside it (nothing was changed)")


def _no_marker(log) -> DataError:
    from naocal.kinds.duckiebot.drive_log import FRAMES_FILE

    return DataError(log.path / FRAMES_FILE, f"no AprilTag {log.marker_family} marker was seen in any of its "
                                             f"{len(log.frame_files)} frames: the drive cannot be fitted")


# ------------------------------------------------------------------------------------------------ identify

def run_identify(args, kind) -> int:
    """Read the log, detect, fit the intrinsics and the joint fit (kinds.duckiebot.identify), print the summary,
    write --out atomically. Exit 0, 2 bad input (nothing written), 3 the fit failed or is implausible."""
    from naocal.kinds.duckiebot.calibration import checked_document, write_document
    from naocal.kinds.duckiebot.drive_log import read_drive_log
    from naocal.kinds.duckiebot.identify import calibrate, detect_log, fit_intrinsics
    from naocal.kinds.duckiebot.diagnose import parse_effects

    check_options(args, kind)
    _refuse_unsupported(args)
    if getattr(args, "refine", None) is not None:
        return run_refine(args)
    if getattr(args, "max_step", None) is not None:
        raise NaocalError("--max-step bounds a refinement's step: give it with --refine CAL.json")
    effects = parse_effects(getattr(args, "effects", "") or "")  # the wheel effects diagnose names
    log = read_drive_log(args.dataset)
    inputs = log_inputs(log)
    if args.out:
        check_log_output(args.out, log, inputs)  # before a minute of work, not after
    detections = detect_log(log)
    if not any(detections.markers):
        raise _no_marker(log)
    lens, fits = fit_intrinsics(log, detections)
    try:
        cal = calibrate(log, detections, lens, fits, fixed=tuple(args.fix), loss=args.loss, effects=effects)
    except ValueError as err:  # an unknown --fix name
        raise NaocalError(f"--fix: {err} (the joint fit's parameters: naocal offsets show CAL.json)") from None
    if not cal.drive_fit.success:
        raise SolveError(f"the joint fit did not converge ({cal.drive_fit.message}): nothing written")
    doc, result = checked_document(cal, args.out or args.dataset, width_px=log.width_px, height_px=log.height_px,
                                   source=f"naocal identify {log.path}")
    if args.json:
        print(json.dumps(doc, indent=1, allow_nan=False))
    else:
        print(format_calibration(result, f"{log.path}: robot {log.robot_id} ({log.model}), "
                                         f"{len(log.frame_files)} frames"))
    _warn(args.verb, result.findings)
    if args.out:
        write_document(args.out, doc, inputs=inputs)
        print(f"wrote {args.out}", file=sys.stderr)
    return 0


MAX_STEP_LIMIT = 0.2  # --max-step beyond this is no bound: three times the real robots' trim sd (0.068)


def run_refine(args) -> int:
    """`naocal identify LOG --refine CAL.json [--out NEW.json] [--max-step TRIM] [--json]`: the online refinement
    (kinds.duckiebot.refine) of CAL's trim (and gain) from the lane pass LOG; prints old -> new +- std; --out writes
    the new calibration file atomically (never over CAL or a file of LOG). Exit 0, 2 bad input, 3 refused (the
    evidence is weak) or the result implausible: nothing written."""
    from naocal.kinds.duckiebot.calibration import check_document, parse_calibration, write_document
    from naocal.kinds.duckiebot.drive_log import read_drive_log
    from naocal.kinds.duckiebot.refine import MAX_STEP, refine_trim, refined_document
    from naocal.solver.fileio import json_safe, read_json

    for option, given in (("--effects", args.effects), ("--fix", args.fix), ("--loss", args.loss != "linear"),
                          ("--keep-outliers", args.keep_outliers)):
        if given:
            raise NaocalError(f"{option} is not for --refine: it refits gain and trim only, everything else held at "
                              "the calibration's (docs/DUCKIEBOT.md)")
    max_step = MAX_STEP if args.max_step is None else args.max_step
    if not 0 < max_step <= MAX_STEP_LIMIT:  # NaN fails too
        raise NaocalError(f"--max-step must be within (0, {MAX_STEP_LIMIT:g}] (a change of trim), got {max_step!r}")
    doc = read_json(args.refine)
    calibration = parse_calibration(doc, args.refine)
    log = read_drive_log(args.dataset)
    inputs = [args.refine] + log_inputs(log)
    if args.out:
        check_log_output(args.out, log, inputs)  # before the work, not after
    refinement = refine_trim(log.path, calibration, max_step=max_step)  # RefinementRefused: exit 3
    source = (f"naocal identify {log.path} --refine {args.refine}: trim {refinement.trim_before:+.5f} -> "
              f"{refinement.trim:+.5f} +- {refinement.trim_std:.5f}")
    new = refined_document(doc, refinement, source)
    result = check_document(new, args.out or args.refine)
    if args.json:
        print(json.dumps(json_safe({"log": str(log.path), "calibration": str(args.refine), "out": args.out,
                                    "max_step": max_step, "refinement": dataclasses.asdict(refinement),
                                    "kinematics": new["kinematics"]}), indent=1, allow_nan=False))
    else:
        print(f"{log.path} refining {args.refine} (robot {calibration.robot_id}, at most {max_step:g} of trim): "
              f"{refinement.describe()}")
    _warn(args.verb, result.findings)
    if args.out:
        write_document(args.out, new, inputs=inputs)
        print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _warn(verb: str, findings) -> None:
    for finding in findings:
        print(f"naocal {verb}: warning: {finding}", file=sys.stderr)


def _pm(value: float, std: float, scale: float = 1.0, digits: int = 4) -> str:
    return f"{value * scale:.{digits}f} +- {std * scale:.{digits}f}"


def format_calibration(cal, title: str = "") -> str:
    """A calibration file's content (kinds.duckiebot.calibration.CalibrationFile) as a few lines: the kinematics,
    the camera's pose on the body and the lens chosen, with the joint fit's cluster-robust stds; of Duckietown's
    files (calibration.from_duckietown: no fit, no stds) the values alone, the pose recovered from the homography."""
    kin = cal.kinematics
    fitted = cal.fit["rms_px"] is not None

    def shown(name, scale=1.0, digits=4):
        return _pm(cal.value(name), cal.std(name), scale, digits) if fitted else f"{cal.value(name) * scale:.{digits}f}"

    lines = [title] if title else []
    lines.append(f"kinematics: gain {shown('gain')}, trim {shown('trim', digits=5)}, baseline "
                 f"{shown('baseline_m', 1e3, 2)} mm (k {kin.k:g}, radius {kin.radius_m * 1e3:g} mm, limit "
                 f"{kin.limit:g})")
    pose = [f"{axis} {shown(f'camera.{axis}_m', 1e3, 1)} mm" for axis in "xyz"]
    pose += [f"{angle} {shown(f'camera.{angle}_rad', 180 / math.pi, 2)} deg" for angle in ("roll", "pitch", "yaw")]
    lines.append("camera on the body (from the wheel axle's midpoint on the floor"
                 + ("" if fitted else "; recovered from the homography") + "): " + ", ".join(pose))
    K = cal.lens.K
    if cal.lens_errors:
        held = ", ".join(f"{m} {e['held_out_rms_px']:.3f} px" for m, e in cal.lens_errors.items())
        chosen = f" (held-out RMS: {held}; {cal.lens_errors[cal.lens_model]['views']} board views)"
    else:
        chosen = ""
    lines.append(f"lens: {cal.lens_model}{chosen}, {cal.width_px} x {cal.height_px} px, fx {K[0, 0]:.2f} fy "
                 f"{K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} px, distortion "
                 + " ".join(f"{d:.4g}" for d in cal.lens.distortion))
    if not fitted:
        lines.append("fit: none recorded (Duckietown's files hold the values, no stds)")
        return "\n".join(lines)
    markers = sum(1 for n in cal.parameters if n.endswith(".yaw_rad") and n.startswith("marker")) + 1
    fit = cal.fit
    lines.append(f"fit: RMS {fit['rms_px']:.3f} px over {fit['corners']} marker corners ({fit['outliers']} set "
                 f"aside), {markers} markers (reference {fit['reference_marker']}); stds clustered by sighting run"
                 + ("" if fit["converged"] else "; NOT CONVERGED"))
    parts = _std_parts_line(cal)
    if parts:
        lines.append(parts)
    lines += [f"fit warning: {w}" for w in fit["warnings"]]
    return "\n".join(lines)


# (name, label, scale, digits) of the parameters whose std's parts format_calibration shows
PARTS_SHOWN = (("gain", "gain", 1.0, 4), ("trim", "trim", 1.0, 5), ("baseline_m", "baseline mm", 1e3, 2)) + tuple(
    (f"camera.{a}_m", f"camera {a} mm", 1e3, 2) for a in "xyz") + tuple(
    (f"camera.{a}_rad", f"{a} deg", 180 / math.pi, 3) for a in ("roll", "pitch", "yaw"))


def _std_parts_line(cal) -> str:
    """One line: which part of each std is statistical (the fit's, cluster-robust) and which the model errors the
    fit considered (the lens's intrinsics, the detector's corner error; calibration's std_parts); "" without."""
    from naocal.kinds.duckiebot.fit import CORNER_WINDOW, LENS, STATISTICAL, STD_PARTS

    labels = {STATISTICAL: "statistical", LENS: "lens", CORNER_WINDOW: "detector's corner error"}
    shown = [(n, label, scale, digits) for n, label, scale, digits in PARTS_SHOWN
             if "std_parts" in cal.parameters.get(n, {})]
    if not shown:
        return ""
    names = [p for p in STD_PARTS if any(p in cal.parameters[n]["std_parts"] for n, *_ in shown)]
    return (f"std parts: {' / '.join(labels.get(p, p) for p in names)} (all but the first model errors carried "
            "in; the std is their root sum of squares): " + ", ".join(
                f"{label} " + " / ".join(f"{cal.parameters[n]['std_parts'].get(p, 0.0) * scale:.{digits}f}"
                                         for p in names) for n, label, scale, digits in shown))


# ------------------------------------------------------------------------------------------------ verify

def straight_drive(commanded, true, distance_m: float = STRAIGHT_DISTANCE_M, speed_mps: float = STRAIGHT_SPEED_MPS):
    """(lateral deviation m, speed m/s) of a robot whose true kinematics are `true` (robot.Kinematics), asked to
    drive straight at `speed_mps` through Duckietown's inverse kinematics with the calibration `commanded`, after
    `distance_m` of travel (exact arc; positive: to the left)."""
    from naocal.kinds.duckiebot.kinematics import forward_kinematics, integrate_pose, inverse_kinematics

    u_left, u_right = inverse_kinematics(speed_mps, 0.0, commanded)
    v, omega = forward_kinematics(u_left, u_right, true)
    if v <= 0:
        return math.inf, float(v)
    pose = integrate_pose(np.zeros(3), v, omega, distance_m / v)
    return float(pose[1]), float(v)


@dataclasses.dataclass(frozen=True)
class Judged:
    """The calibration verify judges a log under (kinds.duckiebot.calibration.CalibrationFile), what it is, said in
    words (`label`) and as a key (`source`: naocal, duckietown, or log, the log's own camera with `label`'s
    kinematics), and the log's detections when finding it needed them (the log's own camera)."""

    calibration: object
    label: str
    source: str
    detections: object = None


def duckietown_directory(directory, robot: str, verb: str = "verify"):
    """The calibration in Duckietown's three files of `robot` under `directory` (calibration_files.read_calibration:
    DataError naming the file and field), its warnings shown as `verb`'s."""
    from naocal.kinds.duckiebot.calibration import from_duckietown
    from naocal.kinds.duckiebot.calibration_files import read_calibration

    files, findings = read_calibration(directory, robot)
    calibration = from_duckietown(files, str(directory), findings)  # a broken homography: one line, no warnings
    _warn(verb, findings)
    return calibration


def directory_robot(directory, given) -> str:
    """Whose files in the calibrations `directory` to read: `given` (--robot-name), else the only robot there.
    NaocalError (exit 2) when it holds none or several."""
    from naocal.kinds.duckiebot.calibration_files import robots_in
    from naocal.kinds.duckiebot.robot import robot_name_problem

    if given is not None:
        if robot_name_problem(given):
            raise NaocalError(f"--robot-name: {robot_name_problem(given)}")
        return given
    robots = robots_in(directory)
    if not robots:
        raise NaocalError(f"{directory}: no robot's calibration files (kinematics/, camera_intrinsic/, "
                          "camera_extrinsic/<robot>.yaml) in it")
    if len(robots) > 1:
        shown = ", ".join(robots[:10]) + (f" and {len(robots) - 10} more" if len(robots) > 10 else "")
        raise NaocalError(f"{directory} holds the files of {len(robots)} robots ({shown}): give --robot-name NAME")
    return robots[0]


def judged_calibration(args, log) -> Judged:
    """What verify judges LOG under: --offsets CAL.json (naocal's file) or a calibrations DIR (Duckietown's three
    files of --robot-name, default the log's robot.id); without --offsets, the robot's files in Duckietown's own
    directory (calibration_files.default_calibrations_dir), else the log's own camera (its board views: identify's
    intrinsics and joint fit) under the robot's kinematics file there or, without one, Duckietown's defaults (gain
    1, trim 0: default.yaml, what a robot never calibrated runs). NaocalError (exit 2) when none of these is
    possible."""
    from pathlib import Path

    from naocal.kinds.duckiebot.calibration import read_calibration_file
    from naocal.kinds.duckiebot.calibration_files import KINEMATICS_DIR, calibration_paths, default_calibrations_dir
    from naocal.kinds.duckiebot.robot import robot_name_problem

    given_name = getattr(args, "robot_name", None)
    if given_name is not None and robot_name_problem(given_name):
        raise NaocalError(f"--robot-name: {robot_name_problem(given_name)}")
    robot = given_name or log.robot_id
    if args.offsets is not None:
        if Path(args.offsets).is_dir():
            return Judged(duckietown_directory(args.offsets, robot), f"{args.offsets} (Duckietown's files of {robot})",
                          "duckietown")
        if given_name is not None:
            raise NaocalError("--robot-name picks a robot's files in a calibrations directory: --offsets "
                              f"{args.offsets} is a file")
        return Judged(read_calibration_file(args.offsets), str(args.offsets), "naocal")
    directory = default_calibrations_dir()
    paths = calibration_paths(directory, robot)
    if all(path.exists() for path in paths.values()):
        return Judged(duckietown_directory(directory, robot), f"{directory} (Duckietown's files of {robot})",
                      "duckietown")
    missing = ", ".join(str(path) for path in paths.values() if not path.exists())
    kinematics_file = paths[KINEMATICS_DIR] if paths[KINEMATICS_DIR].exists() else None
    return _own_camera(log, robot, kinematics_file, missing)


def robot_kinematics(log, robot: str, kinematics_file) -> tuple:
    """(Kinematics, its label) `robot` runs: its kinematics file (None: it has none) or Duckietown's defaults."""
    from naocal.kinds.duckiebot.calibration_files import read_kinematics
    from naocal.kinds.duckiebot.robot import nominal_for

    if kinematics_file is None:
        kinematics = nominal_for(log.model).nominal_kinematics()
        return kinematics, (f"Duckietown's default kinematics (gain {kinematics.gain:g}, trim {kinematics.trim:g}: "
                            f"no kinematics file of {robot} found) with the log's own camera")
    kinematics, _, findings = read_kinematics(kinematics_file)
    _warn("verify", findings)
    return kinematics, f"{kinematics_file} with the log's own camera (no camera files of {robot})"


def _own_camera(log, robot: str, kinematics_file, missing: str) -> Judged:
    """The log's own camera (identify's intrinsics and joint fit on it) under the robot's kinematics file, or
    Duckietown's defaults without one."""
    from naocal.kinds.duckiebot.calibration import checked_document
    from naocal.kinds.duckiebot.identify import MIN_BOARD_VIEWS, calibrate, detect_log, fit_intrinsics, sample_boards

    def refuse(views: str):
        return NaocalError(f"no calibration to verify {log.path} under: give --offsets CAL.json (naocal identify's) "
                           f"or --offsets DIR (Duckietown's calibrations); not found: {missing}; the log's own camera "
                           f"needs {MIN_BOARD_VIEWS} board views, it has {views}")

    sampled = sample_boards(log)  # a log without boards is told in a fraction of the full search's time
    if not any(sampled.values()):
        raise refuse(f"none in {len(sampled)} frames sampled over the log")
    detections = detect_log(log, searched=sampled)
    views = sum(len(boards) for boards in detections.boards)
    if views < MIN_BOARD_VIEWS:
        raise refuse(str(views))
    if not any(detections.markers):
        raise _no_marker(log)
    lens, fits = fit_intrinsics(log, detections)
    fitted = calibrate(log, detections, lens, fits)
    if not fitted.drive_fit.success:
        raise SolveError(f"the joint fit of {log.path} did not converge ({fitted.drive_fit.message})")
    _, own = checked_document(fitted, log.path, width_px=log.width_px, height_px=log.height_px,
                              source=f"naocal verify {log.path}: the log's own camera")
    kinematics, label = robot_kinematics(log, robot, kinematics_file)
    return Judged(dataclasses.replace(own, kinematics=kinematics, fit={**own.fit, "pwm_driver": False}), label, "log",
                  detections)


def run_verify(args, kind) -> int:
    """Does the robot still drive straight under the calibration (judged_calibration)? Refit gain and trim on the
    new log (the camera's pose and the baseline held at the calibration's: a lane pass without turns cannot tell the
    baseline from trim), predict the 2 m straight drive at 0.3 m/s commanded with the calibration's gain and trim.
    Exit 0 still good, 1 drifted, 2 bad input (or no calibration to judge), 3 a fit failed or too few frames with a
    marker (refine's MIN_MARKER_FRAMES) for a verdict."""
    from naocal.kinds.duckiebot.drive_log import read_drive_log
    from naocal.kinds.duckiebot.fit import CAMERA, Drive, fit_drive
    from naocal.kinds.duckiebot.identify import add_corner_covariance, detect_log, rectified_sightings
    from naocal.kinds.duckiebot.refine import MIN_MARKER_FRAMES
    from naocal.kinds.duckiebot.robot import Kinematics

    check_options(args, kind)
    log = read_drive_log(args.dataset)
    judged = judged_calibration(args, log)
    cal = judged.calibration
    detections = judged.detections or detect_log(log, boards=False)
    if not any(detections.markers):
        raise _no_marker(log)
    marker_frames = sum(1 for markers in detections.markers if markers)
    if marker_frames < MIN_MARKER_FRAMES:  # as few as refine's: its stds would speak for a handful of poses
        raise SolveError(f"{log.path}: {marker_frames} frames with a marker in view, at least {MIN_MARKER_FRAMES} "
                         "are needed to tell whether the robot still drives straight: no verdict")
    # through the calibration's model of the wheel driver (its trim is that model's)
    drive = dataclasses.replace(Drive.of_log(log, pwm_driver=cal.pwm_driver), baseline_m=cal.value("baseline_m"))
    fit = fit_drive(drive, rectified_sightings(detections, cal.lens), cal.lens.K, log.marker_size_m,
                    cal.T_base_camera, fixed=CAMERA + ("baseline_m",))
    if not fit.success:
        raise SolveError(f"the fit of {log.path} did not converge ({fit.message})")
    # the detector's corner error, shared by the whole log, as identify carries it (no cluster-robust std sees it)
    add_corner_covariance(fit, drive, detections, cal.lens, log.marker_size_m)
    now = {"gain": fit.value("gain"), "trim": fit.value("trim")}
    std = {"gain": fit.stdev("gain"), "trim": fit.stdev("trim")}
    parts = {part: {n: float(values[fit.names.index(n)]) for n in now} for part, values in fit.std_parts().items()}

    def predicted(gain, trim):
        true = Kinematics(baseline_m=drive.baseline_m, radius_m=drive.radius_m, gain=gain, trim=trim, k=drive.k,
                          limit=drive.limit)
        return straight_drive(cal.kinematics, true)

    lateral, speed = predicted(now["gain"], now["trim"])
    # the std by first-order propagation of the fitted gain's and trim's stds (their correlation neglected)
    variance = 0.0
    for name in now:
        step = 1e-3 * std[name] or 1e-9
        moved = predicted(**{**now, name: now[name] + step})[0]
        variance += ((moved - lateral) / step * std[name]) ** 2
    lateral_std = math.sqrt(variance)
    good = abs(lateral) <= DUCKIETOWN_RULE_M
    calibration_rms = cal.fit["rms_px"]  # None: Duckietown's files record no fit
    report = {"log": str(log.path), "calibration": judged.label, "calibration_source": judged.source,
              "calibrated": {"gain": cal.kinematics.gain, "trim": cal.kinematics.trim},
              "now": {n: {"value": now[n], "std": std[n], "std_parts": {p: parts[p][n] for p in parts}} for n in now},
              "fit_rms_px": fit.rms_px,
              "calibration_rms_px": calibration_rms, "distance_m": STRAIGHT_DISTANCE_M,
              "speed_mps": STRAIGHT_SPEED_MPS, "lateral_deviation_m": lateral, "lateral_deviation_std_m": lateral_std,
              "predicted_speed_mps": speed, "rule_m": DUCKIETOWN_RULE_M, "goal_m": GOAL_M,
              "verdict": "still good" if good else "drifted"}
    if args.json:
        print(json.dumps(report, indent=1, allow_nan=False))
        return 0 if good else 1
    own = "the calibration's " + ("not recorded" if calibration_rms is None else f"{calibration_rms:.3f} px")
    print(f"{log.path} under {judged.label} (gain {cal.kinematics.gain:.4f}, trim {cal.kinematics.trim:.5f}): the "
          f"robot now has gain {_pm(now['gain'], std['gain'])}, trim {_pm(now['trim'], std['trim'], digits=5)} "
          f"(baseline and camera pose held at the calibration's; fit RMS {fit.rms_px:.3f} px, {own})")
    print(f"commanded straight at {STRAIGHT_SPEED_MPS:g} m/s for {STRAIGHT_DISTANCE_M:g} m with the calibration: "
          f"lateral deviation {_pm(lateral, lateral_std, 100, 1)} cm (positive: left), speed {speed:.3f} m/s "
          f"({100 * (speed / STRAIGHT_SPEED_MPS - 1):+.1f} %)")
    certain = abs(lateral) + 2 * lateral_std <= DUCKIETOWN_RULE_M if good else \
        abs(lateral) - 2 * lateral_std > DUCKIETOWN_RULE_M
    hedge = "" if certain else " (within 2 stds of the limit: drive again to be sure)"
    remedy = (f"run naocal identify {log.path} --out CAL.json (this log has board views), then naocal offsets "
              "export CAL.json --format duckietown --out DIR" if judged.source == "log" else
              "recalibrate (naocal identify LOG --out CAL.json on a calibration drive)")
    if good:
        goal = "and naocal's 2 cm goal" if abs(lateral) <= GOAL_M else "but not naocal's 2 cm goal"
        print(f"verdict: still good: within Duckietown's {DUCKIETOWN_RULE_M * 100:g} cm rule {goal}{hedge}")
    else:
        print(f"verdict: drifted: beyond Duckietown's {DUCKIETOWN_RULE_M * 100:g} cm rule{hedge}; the log says trim "
              f"{now['trim']:.5f}: {remedy}")
    return 0 if good else 1


# ------------------------------------------------------------------------------------------------ offsets

def run_offsets(args, action: str, out) -> int:
    """`naocal offsets ACTION` for Duckiebot calibration files (show, validate, diff, export; apply is refused)."""
    from naocal.kinds.duckiebot.calibration import read_calibration_file

    if action == "apply":
        raise NaocalError("a Duckiebot's calibration has no joints to apply: its wheel commands are compensated by "
                          "Duckietown's inverse kinematics on the robot (naocal offsets export FILE --format "
                          "duckietown --out DIR)")
    if action == "diff":
        return _diff(read_calibration_file(args.file_a), read_calibration_file(args.file_b), args, out)
    robot_name = getattr(args, "robot_name", None)
    if Path(args.file).is_dir():  # Duckietown's calibrations DIR: its warnings shown as it is read
        if action not in ("show", "validate"):
            raise NaocalError(f"offsets {action} takes naocal's calibration file: {args.file} is a directory "
                              "(Duckietown's calibrations: offsets show or validate)")
        cal = duckietown_directory(args.file, directory_robot(args.file, robot_name), "offsets")
    else:
        if robot_name is not None:
            raise NaocalError(f"--robot-name picks a robot's files in a calibrations directory: {args.file} is a file")
        cal = read_calibration_file(args.file)
        _warn("offsets", cal.findings)
    if action == "show":
        out.write(format_calibration(cal, f"{args.file}: robot {cal.robot_id}, {cal.source}, {cal.created}") + "\n")
        return 0
    if action == "validate":
        out.write("ok\n")
        return 0
    return _export(cal, args, out)


def _diff(a, b, args, out) -> int:
    """Per-parameter B - A; '*' where it exceeds sqrt(std_A^2 + std_B^2) (as the NAO's diff)."""
    marked = 0
    out.write(f"{'parameter':24s} {'A':>12s} {'B':>12s} {'B - A':>12s} {'combined std':>12s}\n")
    for name in [n for n in a.parameters if n in b.parameters]:
        pa, pb = a.parameters[name], b.parameters[name]
        difference, combined = pb["value"] - pa["value"], math.hypot(pa["std"], pb["std"])
        mark = "*" if abs(difference) > combined else ""
        marked += bool(mark)
        out.write(f"{name:24s} {pa['value']:12.6g} {pb['value']:12.6g} {difference:12.4g} {combined:12.4g} {mark}\n")
    only = sorted(set(a.parameters) ^ set(b.parameters))
    if only:
        out.write(f"in one file only (markers seen in one drive): {', '.join(only)}\n")
    out.write(f"lens: {a.lens_model} -> {b.lens_model}\n")
    return 1 if marked and args.fail_on_difference else 0


def _export(cal, args, out) -> int:
    from naocal.kinds.duckiebot.calibration_files import calibration_paths, write_calibration
    from naocal.solver.fileio import atomic_write_text, check_not_an_input, check_output_file, read_json

    for option in ("merge_from", "head_id", "body_id", "bhuman_release", "nominal_urdf"):
        if getattr(args, option, None) is not None:
            raise NaocalError(f"--{option.replace('_', '-')} is not for a Duckiebot's calibration (the NAO's team "
                              "formats' or an URDF's)")
    if getattr(args, "strip_meshes", False):
        raise NaocalError("--strip-meshes is for an URDF export, not a Duckiebot's calibration")
    if args.format not in ("duckietown", "json"):
        raise NaocalError(f"--format {args.format}: a Duckiebot's calibration exports to duckietown or json")
    if args.format == "json":
        text = json.dumps(read_json(args.file), indent=1, allow_nan=False) + "\n"
        if args.out is None:
            out.write(text)
        else:
            check_output_file(args.out, inputs=[args.file])
            atomic_write_text(args.out, text)
            print(f"wrote {args.out}", file=sys.stderr)
        return 0
    if args.out is None:
        raise NaocalError("--format duckietown writes three files (kinematics/, camera_intrinsic/, "
                          "camera_extrinsic/<robot>.yaml): give --out DIR, e.g. the robot's /data/config/calibrations")
    paths = calibration_paths(args.out, cal.robot_id)  # the robot's name checked first
    for path in paths.values():
        check_not_an_input(path, [args.file])
    # the robot's calibrations directory is where these go: a file already there is replaced, and said so
    existed = {path: path.exists() for path in paths.values()}
    findings = write_calibration(args.out, cal.duckietown())
    for path in paths.values():
        print(f"{'replaced the previous' if existed[path] else 'wrote'} {path}", file=sys.stderr)
    _warn("offsets", findings)
    return 0
