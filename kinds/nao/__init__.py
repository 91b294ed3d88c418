"""The NAO (its legs and cameras, the paper's model) as a robot kind: naocal.dataset/1-2 directories (or a
`naocal calibrate --out` run holding one), naocal.offsets/1-2 files and the simulator's naocal.truth files. The
bodies live in kinds/nao/<verb>.py, its options in kinds/nao/options.py."""

from __future__ import annotations

import argparse
from pathlib import Path

from naocal.kinds import json_schema
from naocal.kinds.nao import options


class NaoKind:
    name = "nao"
    rank = 1000  # asked last, so the default kind: it reads what no other kind claims and names what is wrong
    export_formats = ("bhuman", "hulks", "naodevils", "urdf", "json")  # tools/export/
    calibrate_backends = {"mock": "the simulated NAO in this process", "bridge": "a NAO behind `naocal bridge serve`"}
    # the robots `naocal bridge serve --robot nao --driver D` serves (kinds.nao.bridge.open_served)
    served_drivers = {"mock": "the simulated NAO", "naoqi": "a NAO through NAOqi (stock image)",
                      "lola": "a NAO V6 through LoLA (team images)"}
    data_help = "a naocal.dataset/2 (or /1) directory, or a `naocal calibrate --out` run (its dataset/)"
    calibration_help = "a naocal.offsets/2 (or /1) file"
    model_help = ("the paper's 21 parameters (12 leg joint offsets, camera roll/pitch/yaw, board rot_z/x/y per leg) "
                  "on the pixel error of the board vertices")
    diagnose_help = """\
compare  RMS overall, per leg, per head posture and the worst stances, against the noise floor: detector noise
         (the dataset's pixel_noise_px, else estimated from what no rigid board motion and no camera term can
         explain) combined with the error of quantised joint readings (step found in the data).
locate   worst images; the rigid (kinematic) and non-rigid (camera, board) parts of the residuals; left against
         right board; the regressors (joint angles, gravity torques, approach directions, velocities, capture
         time, image position) a board motion proportional to which would explain most of the misfit.
names    every effect not yet in the model (score test), ranked by the misfit it would explain beyond what its
         parameters would fit of pure noise, with the RMS predicted after adding it, a significance test
         clustered by stance (images of one stance share their errors; Bonferroni over the candidates,
         family-wise level 0.001) and its uniqueness (share of its signature the model cannot already produce;
         near 0: these data can hardly tell it apart, whatever its p-value). The default model's assumptions
         are candidates too, each dropped by its candidate: untie_shared_motors (the HipYawPitch pair's one
         offset; dropped by --no-tie-hip-yaw-pitch) and rigid_board (each board flat and as printed; no model
         drops it: the verdict says what to measure). With --angles X, the other angle hypotheses are fitted
         too and a better one is named ("assumption contradicted").
Add the top significant candidate with `naocal identify DATASET --effects NAME --out offsets.json` (its cv_rms_px
shows the error on stances the fit did not see), then diagnose again with --effects NAME; the verdict prints both
commands, ready to paste (with --fix for the candidate's parameters these data cannot tell from the model)."""
    diagnose_json_help = '{"rms_px": [x, y], "noise_px": f, "candidates": [...], "verdict": {...}, ...}'

    @property
    def effects_help(self) -> str:
        """The effects of the registry the NAO's model can add (those with `parameters(setup)`, not its base)."""
        from naocal.solver.effects import EXTRA_EFFECTS

        return ", ".join(EXTRA_EFFECTS)

    def claims(self, source) -> bool:
        if isinstance(source, argparse.Namespace):  # no option is the NAO's alone: it is the default kind
            return False
        from naocal.solver.dataset import SCHEMAS as DATASET_SCHEMAS
        from naocal.solver.offsets import SCHEMA_V1, SCHEMA_V2, TRUTH_SCHEMAS

        path = Path(source)
        if path.is_dir():  # a dataset, or a `naocal calibrate --out` run holding one
            return any(json_schema(d / "dataset.json") in DATASET_SCHEMAS for d in (path, path / "dataset"))
        return json_schema(path) in (SCHEMA_V1, SCHEMA_V2, *TRUTH_SCHEMAS)

    def add_options(self, parser, verb: str) -> None:
        options.add_options(parser, verb)

    def identify(self, args) -> int:
        from naocal.kinds.nao.identify import run

        return run(args)

    def diagnose(self, args) -> int:
        from naocal.kinds.nao.diagnose import run

        return run(args)

    def verify(self, args) -> int:
        from naocal.kinds.nao.verify import run

        return run(args)

    def simulate(self, args) -> int:
        from naocal.kinds.nao.simulate import run

        return run(args, self)

    def offsets(self, args, action: str, out) -> int:
        from naocal.kinds.nao import offsets

        if action == "export" and args.format not in self.export_formats:
            from naocal.solver.errors import NaocalError

            raise NaocalError(f"--format {args.format}: a NAO's offsets file exports to "
                              f"{', '.join(self.export_formats)}")
        return {"show": offsets.run_show, "diff": offsets.run_diff, "validate": offsets.run_validate,
                "export": offsets.run_export, "apply": offsets.run_apply}[action](args, out)

    def open_served(self, args):
        """The NAO `naocal bridge serve` serves (--driver mock|naoqi|lola): (backend, clock, state_persists)."""
        from naocal.kinds.nao.bridge import open_served

        return open_served(args)

    def calibrate(self, args) -> int:
        from naocal.kinds.nao.calibrate import run

        return run(args, self.calibrate_backends)


KIND = NaoKind()
