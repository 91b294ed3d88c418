"""The serial arm as a robot kind (docs/ARM.md): any arm described by a URDF; its data are naocal.arm_dataset/1
directories and naocal.arm_calibration/1 files. The bodies live in kinds/arm/verbs.py and kinds/arm/offsets.py."""

from __future__ import annotations

import argparse


class ArmKind:
    name = "arm"
    rank = 20  # before the NAO: a pair of an arm's file and a NAO's reaches the arm's reader, which names the mismatch
    data_help = "a naocal.arm_dataset/1 directory (docs/ARM.md)"
    calibration_help = "a naocal.arm_calibration/1 file"
    offsets_help = ("naocal.arm_calibration/1 (docs/ARM.md) works with show, diff, validate, apply and export\n"
                    "--format urdf (its URDF with the calibration in the joint origins) or json.")
    model_help = ("its sensors' frames plus joint_offsets and link_lengths, or the --effects named (docs/ARM.md), on "
                  "the 3-D and pixel error of its sensors' readings")
    diagnose_help = """\
COMPARE  RMS per sensor against its noise, the held-out poses' RMS, the worst poses.
LOCATE   the misfit a joint's or a link's missing parameters would explain.
NAMES    the candidate effects (score test, clustered by pose), best first; PHYSICAL? each significant one on
         data its fit did not see; the verdict names the effect to add with its identify command."""
    diagnose_json_help = '{"rms": {...}, "noise": {...}, "candidates": [...], "verdict": NAME or null, ...}'

    @property
    def effects_help(self) -> str:
        """The effects of the registry an arm's model takes (with `arm_parameters`; its sensors' frames always)."""
        from naocal.kinds.arm.model import DEFAULT_EFFECTS
        from naocal.solver.effects import ARM_EFFECTS

        return f"{', '.join(ARM_EFFECTS)} (default {','.join(DEFAULT_EFFECTS)})"

    def claims(self, source) -> bool:
        if isinstance(source, argparse.Namespace):  # options that exist only for an arm: a NAO's data given them
            return bool(getattr(source, "robot", None) or getattr(source, "chain", None)  # get the arm's refusal,
                        or getattr(source, "no_priors", False) or getattr(source, "start", None)  # not silence
                        or getattr(source, "refit", "sensors") != "sensors"
                        or (getattr(source, "verb", "") == "verify" and getattr(source, "fix", None)))
        from naocal.kinds.arm.calibration import is_arm_calibration
        from naocal.kinds.arm.dataset import is_arm_dataset

        return is_arm_dataset(source) or is_arm_calibration(source)

    def add_options(self, parser, verb: str) -> None:
        from naocal.kinds.arm.verbs import add_arm_options

        if verb in ("identify", "diagnose", "verify"):
            add_arm_options(parser, verb=verb)  # DATASET a naocal.arm_dataset/1; --effects then names its effects
        elif verb == "simulate":
            add_arm_options(parser, simulate=True)  # an arm instead of the NAO
            parser.add_argument("--poses", type=int, default=60, metavar="N", help="arm: stances (default 60)")
            parser.add_argument("--noise-m", type=float, default=1e-4,
                                help="arm: the 3-D sensor's noise per axis (default 1e-4 m)")
            parser.add_argument("--noise-px", type=float, default=0.2,
                                help="arm: the camera's noise per axis (default 0.2 px)")
            parser.add_argument("--camera-error", action="store_true",
                                help="dual arm: the cameras' true intrinsics off what dataset.json files, by a "
                                     "separate checkerboard calibration's plausible error (docs/ARM.md)")
            parser.add_argument("--print-scale-error", type=float, default=None, metavar="REL",
                                help="dual arm: the spread of each marker sheet's print scale (default 0.003: an "
                                     "office printer's; 0: printed exactly; docs/ARM.md)")
            parser.add_argument("--stance-seed", type=int, default=None, metavar="K",
                                help="dual arm: another session of the seed's robot (its errors, sensors and print "
                                     "the seed's; stances, noise and outliers drawn for K): new data for "
                                     "`naocal verify` (docs/ARM.md)")
            parser.add_argument("--hidden", default="joint_offsets,link_lengths",
                                help="arm: the hidden errors (default joint_offsets,link_lengths)")

    def identify(self, args) -> int:
        from naocal.kinds.arm.verbs import run_identify

        return run_identify(args)

    def diagnose(self, args) -> int:
        from naocal.kinds.arm.verbs import run_diagnose

        return run_diagnose(args)

    def verify(self, args) -> int:
        from naocal.kinds.arm.verbs import run_verify

        return run_verify(args)

    def simulate(self, args) -> int:
        from naocal.kinds.arm.verbs import run_simulate

        return run_simulate(args)

    def offsets(self, args, action: str, out) -> int:
        from naocal.kinds.arm import offsets

        if action == "show":
            from naocal.kinds.arm.verbs import format_calibration

            out.write(format_calibration(args.file))
            return 0
        return {"diff": offsets.run_diff, "validate": offsets.run_validate, "export": offsets.run_export,
                "apply": offsets.run_apply}[action](args, out)


KIND = ArmKind()
