"""The Duckiebot (Duckietown's differential-drive robot with one camera) as a robot kind (issues 22, 23;
docs/DUCKIEBOT.md): its data are drive logs (LOG/log.json of schema naocal.drive_log/1) and its calibration files
(naocal.duckiebot_calibration/1); `--robot duckiebot` asks for it where no data say (calibrate, simulate).

- `robot`: the DB21 / DB18 description (wheels, encoders, camera prior and mount) and Duckietown's kinematics
  parameters;
- `kinematics`: Duckietown's forward and inverse kinematics, its duty-to-PWM map, pose integration;
- `drive_log`: the strict reader of a drive log (`naocal.drive_log/1`);
- `calibration`: the calibration file (`naocal.duckiebot_calibration/1`: strict reader, atomic writer);
- `calibration_files`: Duckietown's three calibration files (writer and strict reader, plausibility checks);
- `detect`: AprilTag 36h11 markers (OpenCV's class API) and chessboards (agent.board_detect);
- `intrinsics`: the camera's intrinsics, the lens model chosen by held-out reprojection error;
- `fit`, `identify`: the joint fit of a drive log (wheels, camera pose on the body, floor markers);
- `render`: an independent OpenCV renderer of the calibration set-up writing a drive log;
- `verbs`: the bodies of identify, verify and offsets; `diagnose`, `simulate`, `calibrate` the other verbs'.

Facts and numbers come from docs/DUCKIEBOT.md, which cites their public sources. This module is imported while the
command line is built: argparse only here, the bodies import what they need.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
from pathlib import Path

from naocal.kinds import json_schema

NAME = "duckiebot"
LOG_SCHEMA = "naocal.drive_log/1"  # kinds.duckiebot.drive_log.SCHEMA (not imported here: it imports cv2)
CALIBRATION_SCHEMA = "naocal.duckiebot_calibration/1"  # kinds.duckiebot.calibration.SCHEMA
LOG_FILES = ("log.json", "wheels.csv", "frames.csv")  # kinds.duckiebot.drive_log's required files
# Duckietown's calibrations DIR: these folders of <robot>.yaml (calibration_files.KINEMATICS_DIR, ...)
CALIBRATION_DIRS = ("kinematics", "camera_intrinsic", "camera_extrinsic")
# The verbs whose bodies live in a module of their own, each with add_options(parser) and the body's function.
VERB_MODULES = {"calibrate": ("calibrate", "run"), "diagnose": ("diagnose", "run_diagnose"),
                "simulate": ("simulate", "run_simulate")}


def _verb_module(verb: str):
    """The module of `verb`'s body, None if this checkout does not have it."""
    name = f"{__name__}.{VERB_MODULES[verb][0]}"
    return importlib.import_module(name) if importlib.util.find_spec(name) is not None else None


class DuckiebotKind:
    name = NAME
    rank = 10  # before the arm, whose --robot takes any name: `--robot duckiebot` is this kind's
    export_formats = ("duckietown", "json")
    # calibrate's options of this kind that define its run (recorded in run.json; --resume must repeat them)
    run_options = {"--max-blind-m": "the out-of-area bound the mission drove under"}
    calibrate_backends = {"mock": "the simulated Duckiebot", "ros": "a Duckiebot's own ROS topics, naocal on the robot",
                          "bridge": "a Duckiebot behind `naocal bridge serve --robot duckiebot`"}
    # the robots `naocal bridge serve --robot duckiebot --driver D` serves (bridge.open_served)
    served_drivers = {"mock": "the simulated Duckiebot",
                      "ros": "a Duckiebot through its ROS topics (in dt-ros-commons on the robot, docs/DEPLOY.md)"}
    data_help = f"a drive log directory (log.json of {LOG_SCHEMA}, wheels.csv, frames.csv; docs/DUCKIEBOT.md)"
    offsets_help = (f"{CALIBRATION_SCHEMA} (docs/DUCKIEBOT.md) works with show, diff, validate and export\n"
                    "--format duckietown|json; show and validate also take a Duckietown calibrations DIR\n"
                    "(kinematics/, camera_intrinsic/, camera_extrinsic/<robot>.yaml; --robot-name NAME when it holds\n"
                    "several robots' files).")
    calibration_help = (f"a {CALIBRATION_SCHEMA} file, or a directory of Duckietown's calibration files "
                        "(kinematics/, camera_intrinsic/, camera_extrinsic/<robot>.yaml)")
    # `naocal verify LOG` without --offsets: the robot's files in Duckietown's calibrations directory, else the log's
    # own camera under Duckietown's default kinematics (verbs.judged_calibration)
    verify_finds_calibration = True
    verify_help = ("a drive log: gain and trim refitted, the 2 m straight drive at 0.3 m/s predicted under the "
                   "calibration (--offsets CAL.json, or a Duckietown calibrations DIR; without --offsets the robot's "
                   "files in /data/config/calibrations, else the log's own camera under Duckietown's default "
                   "kinematics): still good within 10 cm (0), drifted (1), bad input or no calibration (2), a fit "
                   "failed (3) (docs/DUCKIEBOT.md)")
    model_help = ("the wheels' gain, trim and baseline, the camera's lens and pose on the body and the floor markers' "
                  "poses on the pixel error of the marker corners")
    diagnose_help = """\
COMPARE  the marker corners' RMS against their expected detection noise (whitened RMS: 1 at the floor).
LOCATE   the corners' RMS by the drive phase before each frame (turning or straight, by duty).
LENS     each lens model's held-out board RMS: one well below the lens in use's is named first.
NAMES    a score test per wheel effect not in the model (clustered by frame; Bonferroni, family-wise 0.001), each
         significant one refitted; pwm_driver, without a parameter, judged by its refit.
ENCODERS with encoders.csv: each wheel's turn from the encoders over the fitted model's ground travel of it
         (log.json's radius and baseline), straight, curving and in place: slip in turns (the wheels turn more than
         the ground moves, beyond what they do straight) or a wrong radius (one ratio); evidence only, the fit and
         what is named are the same without it.
VERDICT  the missing effect or lens, the command that adds it, and the RMS before and after."""
    diagnose_json_help = ('{"rms_px": f, "floor_px": f, "tests": [...], "named": NAME or null, "after": {...}, '
                          '"encoders": {"phases", "slip", "radius_ratio", "verdict"} or null, ...}')

    @property
    def effects_help(self) -> str:
        """The registry's differential-drive effects (those with `drive_parameters`), each off unless named."""
        from naocal.solver.effects import DRIVE_EFFECTS

        return ", ".join(DRIVE_EFFECTS) + " (pwm_driver: the PWM driver, a choice of model without a parameter)"

    def claims(self, source) -> bool:
        if isinstance(source, argparse.Namespace):  # --robot duckiebot, or identify's options of this kind
            return getattr(source, "robot", None) == NAME or any(
                getattr(source, option, None) is not None for option in ("refine", "max_step", "robot_name"))
        path = Path(source)
        if path.is_dir():  # a drive log, even a broken one (its reader names what is wrong), never a NAO's dataset;
            # or Duckietown's calibrations DIR
            return json_schema(path / "log.json") == LOG_SCHEMA or (
                (any((path / name).is_file() for name in LOG_FILES)
                 or any((path / name).is_dir() for name in CALIBRATION_DIRS))
                and not (path / "dataset.json").exists())
        if path.is_file() and path.name in LOG_FILES + ("encoders.csv", "segments.csv") and self.claims(path.parent):
            return True  # a drive log's own file named for its folder: its reader says to name the folder
        return json_schema(path) == CALIBRATION_SCHEMA

    def add_options(self, parser, verb: str) -> None:
        if verb == "identify":  # the online refinement (refine.py, verbs.run_refine); defaults None: not given
            parser.add_argument("--refine", metavar="CAL_JSON",
                                help="duckiebot: refine CAL_JSON's trim (and gain) from LOG, a pass along a marked "
                                     "straight lane section; --out writes the new calibration (never over CAL_JSON);"
                                     " weak evidence: exit 3, nothing written")
            parser.add_argument("--max-step", type=float, default=None, metavar="TRIM",
                                help="duckiebot, with --refine: the most trim may change (default 0.02; the pass's "
                                     "estimate is still printed)")
        if verb == "verify":  # whose files in a calibrations directory (verbs.judged_calibration)
            parser.add_argument("--robot-name", default=None, metavar="NAME",
                                help="duckiebot: read NAME's files (<kind>/NAME.yaml) in --offsets DIR or, without "
                                     "--offsets, in $NAOCAL_DUCKIETOWN_CALIBRATIONS (default /data/config/calibrations)"
                                     "; default: the log's robot.id. Without --offsets and without the robot's three "
                                     "files there, the log's own camera (its board views) is judged under the "
                                     "robot's kinematics file there, else Duckietown's defaults (gain 1, trim 0)")
        if verb == "offsets":  # show and validate of a calibrations DIR (verbs.run_offsets)
            parser.add_argument("--robot-name", default=None, metavar="NAME",
                                help="duckiebot, with a Duckietown calibrations DIR: read NAME's files "
                                     "(<kind>/NAME.yaml); default: the only robot whose files DIR holds")
        if verb in VERB_MODULES:
            module = _verb_module(verb)
            if module is not None:
                module.add_options(parser)

    def _run_module(self, verb: str, args) -> int:
        from naocal.kinds.duckiebot.verbs import check_options
        from naocal.solver.errors import NaocalError

        check_options(args, self)
        module = _verb_module(verb)
        if module is None:
            raise NaocalError(f"a Duckiebot's {verb} is not in this version of naocal "
                              f"(kinds/duckiebot/{VERB_MODULES[verb][0]}.py is missing)")
        return getattr(module, VERB_MODULES[verb][1])(args)

    def open_served(self, args):
        """The Duckiebot `naocal bridge serve --robot duckiebot` serves (--driver mock|ros)."""
        from naocal.kinds.duckiebot.bridge import open_served

        return open_served(args)

    def calibrate(self, args) -> int:
        return self._run_module("calibrate", args)

    def diagnose(self, args) -> int:
        return self._run_module("diagnose", args)

    def simulate(self, args) -> int:
        return self._run_module("simulate", args)

    def identify(self, args) -> int:
        from naocal.kinds.duckiebot.verbs import run_identify

        return run_identify(args, self)

    def verify(self, args) -> int:
        from naocal.kinds.duckiebot.verbs import run_verify

        return run_verify(args, self)

    def offsets(self, args, action: str, out) -> int:
        from naocal.kinds.duckiebot.verbs import run_offsets

        return run_offsets(args, action, out)


KIND = DuckiebotKind()
