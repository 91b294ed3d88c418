"""naocal offsets: inspect, compare, validate, export and apply offset files (naocal.offsets/2, and /1).

A stored joint offset c is ADDED to every commanded angle and SUBTRACTED from every measured angle (c = -alpha of
the model q_true = theta + alpha). Camera rotation and board mount are the model's alphas as they are.
Every error is one line on stderr and exit code 2.
"""

import argparse
import sys

from tools.columns import number_column as _num, shown_value as _shown  # shared with tools/arm_offsets.py

COMMANDS_HELP = """commands:
  show FILE                       offsets (deg, with std), camera rotation, board mount, model effects, fit, source
  diff A B                        per-parameter differences; '*' marks |B - A| > sqrt(std_A^2 + std_B^2)
  diff RESULT RUN/truth.json      a result against the simulator's hidden truth: each parameter's error and
                                  error / std (z); '*' marks |z| > 3
  validate FILE                   schema, names, units, finite values, plausible sizes: prints 'ok' (exit 0)
                                  or one line with the reason (exit 2)
  export FILE --format FORMAT     bhuman | hulks | naodevils | urdf | json, to stdout or --out; team formats
                                  merge into the team's files with --merge-from (written atomically: a failed
                                  export never replaces an existing file, a replaced one is kept as NAME.bak)
  apply FILE --command|--reading JOINT=ANGLE ...
                                  compensated command = requested + c, corrected reading = measured - c
An arm's naocal.arm_calibration/1 (docs/ARM.md) works with show, diff, validate, apply and export --format
urdf (its URDF with the calibration in the joint origins) or json.
"""


EXPORT_HELP = """Formats (values, frames, signs and sources: docs/EXPORTS.md):
  bhuman     Robots/<body>/Body/jointCalibration.cfg (offsets = { headYaw = ..deg; ... };) and
             Robots/<head>/<body>/cameraCalibration.cfg (cameraRotationCorrections = { upper = {x; y; z};
             lower = {...}; }; bodyRotationCorrection). B-Human adds the offset to every joint request and
             subtracts it from every reading: naocal's c, same sign. Its camera turns by rotateY(tilt + y) *
             rotateX(x) * rotateZ(z), x forward, y left, z up: x = roll, y = pitch, z = yaw of naocal's camera
             rotation, same signs; lower = bottom camera, upper = top. --bhuman-release picks 26 keys (2017-2024)
             or 27 (2025+, waistYaw).
  hulks      body.<BodyId>.json (joint_calibration_offsets: head {yaw, pitch}, left_leg/right_leg
             {hip_yaw_pitch, ...}, rad, naocal's c) and head.<HeadId>.json
             (camera_matrix_parameters.calibration.correction_in_camera_bottom/_top = [x, y, z] rad: Euler angles
             of the correction in HULKs' camera frame, x right, y down, z optical axis). Only calibrated values
             are written: HULKs overlays these files on default.json.
  naodevils  Robots/<body>/Body/jointCalibration.cfg (<joint> = { offset; minAngle; maxAngle; }) and
             Robots/<head>/<body>/cameraCalibration.cfg (lower/upperCameraRotationCorrection {x; y; z},
             bodyRotationCorrection {x; y}); same signs as B-Human.
  urdf       the nominal NAO URDF (nao_v50) with <calibration rising="c"/> in every calibrated joint, the
             RHipYawPitch mimic offset c_L - c_R, and each calibrated camera's fixed joint turned by its
             correction (T_head_cam = T_nominal @ Rot_y(pitch) @ Rot_x(roll) @ Rot_z(yaw)).
  json       the file itself, validated, in canonical form.

What is written: joint offsets of the joints the file calibrates (legs; head only if fitted) and the rotation of
each camera it calibrates. Team formats, fresh (no --merge-from): B-Human and Nao Devils files need every key,
so what naocal did not calibrate (arms, waistYaw, an uncalibrated camera, body rotation) is written as 0 (nominal)
and said so; HULKs files are sparse, so it is left out. With --merge-from DIR the files the team's code reads now
for this head and body are edited value by value: everything else (other values, comments, layout) is kept byte
for byte; a file found only in a default directory is written to the robot's own directory. A file an export
replaces is kept as NAME.bak. B-Human and Nao Devils name robot directories by robot names: give yours with
--head-id and --body-id (default: the offsets file's head and body ids).
Examples:
  naocal offsets export runs/nao-17/offsets.json --format bhuman --bhuman-release 2025 \\
      --merge-from ~/BHuman/Config --out ~/BHuman/Config --head-id Dante --body-id Dante
  naocal offsets export runs/nao-17/offsets.json --format hulks --merge-from hulk/etc/parameters \\
      --out hulk/etc/parameters"""


def _release_year(text: str) -> int:
    """--bhuman-release: a year such as 2025."""
    if not text.isdigit() or not 2000 <= int(text) <= 2100:
        raise argparse.ArgumentTypeError(f"expected a release year such as 2025, got {text!r}")
    return int(text)


def register(subparsers):
    parser = subparsers.add_parser(
        "offsets", help="inspect, compare, validate, export and apply offset files",
        description=__doc__, epilog=COMMANDS_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="offsets_command", metavar="COMMAND")
    commands.required = True

    show = commands.add_parser("show", help="print a file's contents as tables (angles in deg, lengths in mm)")
    show.add_argument("file", metavar="FILE")

    diff = commands.add_parser(
        "diff", help="compare two files parameter by parameter",
        description="Per-parameter differences B - A. A '*' marks a difference larger than the combined "
                    "uncertainty sqrt(std_A^2 + std_B^2) (std from model.parameters; 0 where a file has none). "
                    "One of A, B may be a simulator's truth.json (naocal simulate or calibrate --backend mock; "
                    "truth_effects.json beside it is read too): then each parameter's error (result - truth) and "
                    "z = error / the result's std, '*' where |z| > 3. "
                    "Exit code 0 unless --fail-on-difference is given and something is marked (then 1).")
    diff.add_argument("file_a", metavar="A")
    diff.add_argument("file_b", metavar="B")
    diff.add_argument("--fail-on-difference", action="store_true",
                      help="exit 1 if any difference exceeds the combined uncertainty")

    validate = commands.add_parser(
        "validate", help="check a file: prints 'ok' (exit 0) or one line with the reason (exit 2)")
    validate.add_argument("file", metavar="FILE")

    export = commands.add_parser(
        "export", help="write the offsets for other software (B-Human, HULKs, Nao Devils, URDF, JSON)",
        formatter_class=argparse.RawDescriptionHelpFormatter, description=EXPORT_HELP)
    export.add_argument("file", metavar="FILE")
    export.add_argument("--format", required=True, choices=("bhuman", "hulks", "naodevils", "urdf", "json"))
    export.add_argument("--out", metavar="PATH",
                        help="output directory (bhuman, hulks, naodevils: the team layout is created below it) or "
                             "file (urdf, json); default: standard output")
    export.add_argument("--merge-from", metavar="DIR",
                        help="bhuman, naodevils: the team's Config directory; hulks: its etc/parameters directory. "
                             "Its current files are edited: only what naocal calibrated changes. May equal --out")
    export.add_argument("--bhuman-release", metavar="YEAR", type=_release_year,
                        help="bhuman: the release whose jointCalibration.cfg to write (2017-2024: 26 keys; 2025 "
                             "and later: 27 with waistYaw). Default: the --merge-from file's layout, else 2025")
    export.add_argument("--head-id", metavar="ID",
                        help="head id or name in the team's file names (default: robot.head_id of FILE)")
    export.add_argument("--body-id", metavar="ID",
                        help="body id or name in the team's file names (default: robot.body_id of FILE)")
    export.add_argument("--strip-meshes", action="store_true",
                        help="urdf: drop the mesh visuals/collisions (their files are not shipped), e.g. for PyBullet")
    export.add_argument("--nominal-urdf", metavar="URDF", help="urdf: start from this URDF instead of nao_v50 (an "
                                                               "arm's file: of its robot.urdf)")

    apply = commands.add_parser(
        "apply", help="compensate commands or correct readings with a file's joint offsets",
        description="Prints JOINT=ANGLE lines, in the unit given (deg unless --rad). --command: the angle to "
                    "send so that the joint reaches the requested one (requested + c). --reading: the true "
                    "angle for an encoder reading (measured - c). Joints without an offset pass unchanged. "
                    "Example: naocal offsets apply nao17.json --command LHipPitch=-20 LKneePitch=40")
    apply.add_argument("file", metavar="FILE")
    mode = apply.add_mutually_exclusive_group(required=True)
    mode.add_argument("--command", dest="mode", action="store_const", const="command",
                      help="the angles are requested angles: print the commands to send")
    mode.add_argument("--reading", dest="mode", action="store_const", const="reading",
                      help="the angles are encoder readings: print the corrected (true) angles")
    apply.add_argument("angles", nargs="+", metavar="JOINT=ANGLE", help="e.g. LHipPitch=-20.5")
    apply.add_argument("--rad", action="store_true", help="angles in and out in rad instead of deg")
    parser.set_defaults(run=run)


def run(args) -> int:
    handlers = {"show": run_show, "diff": run_diff, "validate": run_validate, "export": run_export,
                "apply": run_apply}
    return handlers[args.offsets_command](args, sys.stdout)


# ----------------------------------------------------------------------------------------------- display

# Display units: angles in deg, lengths in mm, time in ms.
_SHOWN_ELSEWHERE = ("joint_offset.", "head_offset.", "board.")  # model names with their own table


def _shown_elsewhere(name: str) -> bool:
    """Whether a model parameter has its own table (joint offsets, camera rotations, board mounts)."""
    parts = name.split(".")
    return name.startswith(_SHOWN_ELSEWHERE) or (parts[0] == "camera" and parts[-1] in ("roll", "pitch", "yaw"))
_BOARD_ROWS = (("rot_z_rad", "rot_z", "rad"), ("trans_x_m", "trans_x", "m"), ("trans_y_m", "trans_y", "m"))


def _unit(unit) -> str:
    from solver.effect import shown

    return shown(0.0, unit)[1]


def _joint_std(offsets, joint):
    for name in (f"joint_offset.{joint}", f"head_offset.{joint}"):
        if offsets.std(name) is not None:
            return offsets.std(name)
    tied = joint == "RHipYawPitch" and offsets.joint_offset("RHipYawPitch") == offsets.joint_offset("LHipYawPitch")
    return offsets.std("joint_offset.LHipYawPitch") if tied else None  # one motor: R follows L


def parameter_rows(offsets) -> list:
    """(label, unit, value, std) in SI units for everything a file holds, in display order.

    Joint offsets are c (the file's value); the other parameters are the model's values.
    """
    from solver.offsets import CAMERA_ANGLES, OFFSET_JOINTS

    rows = [(f"c {j}", "rad", offsets.joint_offsets_rad[j], _joint_std(offsets, j))
            for j in OFFSET_JOINTS if j in offsets.joint_offsets_rad]
    for camera, angles in offsets.camera_rotation_rad.items():
        rows += [(f"camera.{camera}.{a}", "rad", angles[a], offsets.std(f"camera.{camera}.{a}"))
                 for a in CAMERA_ANGLES]
    for leg, mount in offsets.board_mount.items():
        rows += [(f"board.{leg}.{short}", unit, mount[key], offsets.std(f"board.{leg}.{short}"))
                 for key, short, unit in _BOARD_ROWS]
    for name, entry in offsets.model["parameters"].items():
        if not _shown_elsewhere(name):
            rows.append((name, entry["unit"], entry["value"], entry["std"]))
    return rows


def format_show(offsets, name: str) -> str:
    from solver.offsets import CAMERA_ANGLES, OFFSET_JOINTS

    robot, fit = offsets.robot, offsets.fit
    out = [name,
           f"  robot     id {robot.get('id')}, body {robot.get('body_id')}, head {robot.get('head_id')}",
           f"  created   {offsets.created}",
           "  source    " + ("; ".join(f"{k}: {v}" for k, v in offsets.source.items()) or "-"),
           "",
           "joint offsets c (added to commands, subtracted from readings)",
           f"  {'joint':<16}{'c [deg]':>10}{'std [deg]':>11}"]
    for joint in OFFSET_JOINTS:
        if joint in offsets.joint_offsets_rad:
            out.append(f"  {joint:<16}{_num(_shown(offsets.joint_offsets_rad[joint], 'rad'))} "
                       f"{_num(_shown(_joint_std(offsets, joint), 'rad'))}")
    for camera, angles in offsets.camera_rotation_rad.items():
        out += ["", f"camera rotation, {camera} camera (model alpha: T_head_cam = T_nominal @ Rot_y(pitch) "
                    "@ Rot_x(roll) @ Rot_z(yaw))",
                f"  {'angle':<16}{'[deg]':>10}{'std [deg]':>11}"]
        for a in CAMERA_ANGLES:
            std = offsets.std(f"camera.{camera}.{a}")
            out.append(f"  {a:<16}{_num(_shown(angles[a], 'rad'))} {_num(_shown(std, 'rad'))}")
    out += ["", "board mount (model alpha: p = Rot_z(rot_z) Trans_x(trans_x) Trans_y(trans_y) p_sole)",
            f"  {'leg':<6}{'rot_z [deg]':>12}{'trans_x [mm]':>14}{'trans_y [mm]':>14}"]
    for leg, mount in offsets.board_mount.items():
        values = "".join(f"{_num(_shown(mount[key], unit), width)}"
                         for (key, _, unit), width in zip(_BOARD_ROWS, (12, 14, 14)))
        out.append(f"  {leg:<6}{values}")
        stds = [offsets.std(f"board.{leg}.{short}") for _, short, _ in _BOARD_ROWS]
        if any(s is not None for s in stds):
            out.append(f"  {'  std':<6}" + "".join(_num(_shown(s, unit), width) for s, (_, _, unit), width
                                                  in zip(stds, _BOARD_ROWS, (12, 14, 14))))
    effects = offsets.model["effects"]
    out += ["", "model effects: " + (", ".join(effects) if effects else "-")]
    extra = [r for r in parameter_rows(offsets) if r[0] in offsets.model["parameters"] and not _shown_elsewhere(r[0])]
    if extra:
        out.append(f"  {'parameter':<28}{'value':>12}{'std':>12}  unit")
        for label, unit, value, std in extra:
            out.append(f"  {label:<28}{_num(_shown(value, unit), 12, 5)}{_num(_shown(std, unit), 12, 5)}  "
                       f"{_unit(unit)}")
    rms_x, rms_y = fit["rms_px"]
    out += ["", f"fit: rms {rms_x:.3f} px (x), {rms_y:.3f} px (y) over {fit['n_vertices']} vertices "
                f"in {fit['n_images']} images"]
    return "\n".join(out) + "\n"


def format_diff(a, b, name_a: str, name_b: str):
    """(text, number of marked differences): B - A per parameter, '*' where it exceeds the combined std."""
    import math

    rows_a = {label: (unit, value, std) for label, unit, value, std in parameter_rows(a)}
    rows_b = {label: (unit, value, std) for label, unit, value, std in parameter_rows(b)}
    labels = list(rows_a) + [label for label in rows_b if label not in rows_a]
    out = [f"A = {name_a}", f"B = {name_b}"]
    for key in ("id", "body_id", "head_id"):
        if a.robot.get(key) != b.robot.get(key):
            out.append(f"note: robot {key} differs ({a.robot.get(key)} vs {b.robot.get(key)})")
    out.append(f"  {'parameter':<28}{'A':>11}{'B':>11}{'B - A':>11}{'sigma':>10}  unit")
    marked = 0
    for label in labels:
        unit = (rows_a.get(label) or rows_b[label])[0]  # a parameter in one file only (was a KeyError: B lacks it)
        _, value_a, std_a = rows_a.get(label, (unit, None, None))
        _, value_b, std_b = rows_b.get(label, (unit, None, None))
        delta = sigma = None
        mark = ""
        if value_a is not None and value_b is not None:
            delta = value_b - value_a
            sigma = math.hypot(std_a or 0.0, std_b or 0.0)
            if abs(delta) > sigma:
                mark, marked = " *", marked + 1
        else:
            mark = " (only in A)" if value_b is None else " (only in B)"
        out.append(f"  {label:<28}{_num(_shown(value_a, unit), 11)}{_num(_shown(value_b, unit), 11)}"
                   f"{_num(_shown(delta, unit), 11)}{_num(_shown(sigma, unit), 10)}  {_unit(unit)}{mark}")
    out.append(f"{marked} of {len(labels)} parameters differ by more than their combined uncertainty (*)")
    return "\n".join(out) + "\n", marked


# -------------------------------------------------------------------------------------------------- verbs


def run_show(args, out) -> int:
    from solver.offsets import read_offsets
    from tools.arm_cli import format_calibration, is_calibration_file

    if is_calibration_file(args.file):  # an arm's (docs/ARM.md)
        out.write(format_calibration(args.file))
        return 0

    out.write(format_show(read_offsets(args.file), args.file))
    return 0


def run_diff(args, out) -> int:
    from solver.offsets import is_truth_file, read_offsets, read_truth
    from tools.arm_cli import is_calibration_file

    if is_calibration_file(args.file_a) or is_calibration_file(args.file_b):  # an arm's (docs/ARM.md)
        from tools.arm_offsets import run_diff as run_arm_diff

        return run_arm_diff(args, out)

    truth_a, truth_b = is_truth_file(args.file_a), is_truth_file(args.file_b)
    if truth_a or truth_b:  # a result against the simulator's truth
        from solver.errors import NaocalError

        if truth_a and truth_b:
            raise NaocalError(f"{args.file_a}, {args.file_b}: both are a simulator's truth; give a result and a truth")
        result_path, truth_path = (args.file_b, args.file_a) if truth_a else (args.file_a, args.file_b)
        truth, notes = read_truth(truth_path)
        text, marked = format_truth_diff(read_offsets(result_path), truth, result_path, truth_path, notes)
    else:
        text, marked = format_diff(read_offsets(args.file_a), read_offsets(args.file_b), args.file_a, args.file_b)
    out.write(text)
    return 1 if (marked and args.fail_on_difference) else 0


TRUTH_Z = 3.0  # an error beyond this many of the result's standard deviations is marked against the truth


def format_truth_diff(result, truth, result_name: str, truth_name: str, notes=()):
    """(text, number marked): each parameter's error (result - truth) and z = error / the result's std, '*' where
    |z| > TRUTH_Z; parameters in one file only listed as such."""
    rows_r = {label: (unit, value, std) for label, unit, value, std in parameter_rows(result)}
    rows_t = {label: (unit, value) for label, unit, value, _ in parameter_rows(truth)}
    out = [f"result = {result_name}", f"truth  = {truth_name} (the simulator's hidden values; joint offsets as c = "
                                      "-alpha)", f"  {'parameter':<28}{'result':>11}{'truth':>11}{'error':>11}"
                                                 f"{'std':>10}{'z':>8}  unit"]
    marked = compared = 0
    for label in list(rows_r) + [label for label in rows_t if label not in rows_r]:
        unit = (rows_r.get(label) or rows_t[label])[0]
        value, std = rows_r[label][1:] if label in rows_r else (None, None)
        true = rows_t[label][1] if label in rows_t else None
        error = z = None
        mark = " (not in the truth)" if true is None else (" (not in the result)" if value is None else "")
        if value is not None and true is not None:
            compared += 1
            error = value - true
            z = error / std if std else None
            if z is not None and abs(z) > TRUTH_Z:
                mark, marked = " *", marked + 1
        z_text = f"{'-':>8}" if z is None else f"{z:>+8.2f}"
        out.append(f"  {label:<28}{_num(_shown(value, unit), 11)}{_num(_shown(true, unit), 11)}"
                   f"{_num(_shown(error, unit), 11)}{_num(_shown(std, unit), 10)}{z_text}  {_unit(unit)}{mark}")
    out.append(f"{marked} of {compared} parameters are off the truth by more than {TRUTH_Z:g} standard deviations "
               "(*)")
    out += [f"note: {n}" for n in notes]
    return "\n".join(out) + "\n", marked


def run_validate(args, out) -> int:
    from solver.offsets import read_offsets
    from tools.arm_cli import is_calibration_file

    if is_calibration_file(args.file):  # an arm's (docs/ARM.md)
        from tools.arm_offsets import run_validate as run_arm_validate

        return run_arm_validate(args, out)

    read_offsets(args.file)
    out.write("ok\n")
    return 0


def run_export(args, out) -> int:
    from tools.arm_cli import is_calibration_file
    from tools.export.write import run_export as export

    if is_calibration_file(args.file):  # an arm's (docs/ARM.md): a corrected URDF, or the file itself
        from tools.arm_offsets import run_export as run_arm_export

        return run_arm_export(args, out)

    return export(args, out)


def parse_assignment(text: str):
    """'LHipPitch=-20.5' -> ('LHipPitch', -20.5); NaocalError for anything else."""
    import math

    from solver.errors import NaocalError
    from solver.joints import JOINTS

    joint, sep, value = text.partition("=")
    joint = joint.strip()
    if not sep or not joint:
        raise NaocalError(f"expected JOINT=ANGLE, got {text!r}")
    try:
        angle = float(value)
    except ValueError:
        raise NaocalError(f"{joint}: not a number: {value!r}") from None
    if not math.isfinite(angle):
        raise NaocalError(f"{joint}: non-finite angle {value!r}")
    known = set(JOINTS) | {"LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll", "LWristYaw", "LHand",
                           "RShoulderPitch", "RShoulderRoll", "RElbowYaw", "RElbowRoll", "RWristYaw", "RHand"}
    if joint not in known:
        raise NaocalError(f"unknown joint {joint!r}")
    return joint, angle


def run_apply(args, out) -> int:
    import math

    from solver.compensation import compensate_command, correct_reading
    from solver.offsets import read_offsets
    from tools.arm_cli import is_calibration_file

    if is_calibration_file(args.file):  # an arm's (docs/ARM.md): its chain's joints
        from tools.arm_offsets import run_apply as run_arm_apply

        return run_arm_apply(args, out)

    offsets = read_offsets(args.file)
    posture = dict(parse_assignment(text) for text in args.angles)
    to_rad = 1.0 if args.rad else math.pi / 180.0
    posture_rad = {joint: angle * to_rad for joint, angle in posture.items()}
    apply = compensate_command if args.mode == "command" else correct_reading
    for joint, angle_rad in apply(posture_rad, offsets).items():
        out.write(f"{joint}={angle_rad / to_rad:.10g}\n")
    return 0
