"""naocal offsets: inspect, compare, validate, export and apply offset files (naocal.offsets/2, and /1).

A stored joint offset c is ADDED to every commanded angle and SUBTRACTED from every measured angle (c = -alpha of
the model q_true = theta + alpha). Camera rotation and board mount are the model's alphas as they are.
Every error is one line on stderr and exit code 2.
"""

import argparse
import sys

import naocal.kinds as kinds
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
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=COMMANDS_HELP + kinds.help_blocks_by_kind("offsets_help", "offsets"))  # each kind says its own files
    commands = parser.add_subparsers(dest="offsets_command", metavar="COMMAND")
    commands.required = True

    show = commands.add_parser("show", help="print a file's contents as tables (angles in deg, lengths in mm)")
    show.add_argument("file", metavar="FILE")
    kinds.add_options(show, "offsets")  # a kind's own (the Duckiebot's --robot-name of a calibrations DIR)

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
    kinds.add_options(validate, "offsets")

    export = commands.add_parser(
        "export", help="write the offsets for other software (B-Human, HULKs, Nao Devils, URDF, JSON)",
        formatter_class=argparse.RawDescriptionHelpFormatter, description=EXPORT_HELP)
    export.add_argument("file", metavar="FILE")
    export.add_argument("--format", required=True, choices=kinds.export_formats())  # each kind's (docs/ARCHITECTURE.md)
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
    files = (args.file_a, args.file_b) if args.offsets_command == "diff" else (args.file,)
    return kinds.for_args(args, *files).offsets(args, args.offsets_command, sys.stdout)
