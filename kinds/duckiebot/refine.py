"""Online refinement of a Duckiebot's trim (issue 23; the seed paper's section 5.2): from a drive log of the robot
passing a marked straight lane section in normal operation (floor markers at unknown positions, no boards), refine
trim (and gain, where the pass determines it) from a given calibration, with a bounded step and a stated
uncertainty, or refuse.

The fit is kinds.duckiebot.fit's joint fit, with the camera (its lens: the calibration's, through which the
corners are rectified; its pose on the body: `fixed`) and the baseline held at the calibration: a straight pass
has no turns to tell the baseline from trim, and its markers seen from one side only pin the camera's pose poorly.
Free: gain, trim, the robot's pose at the first frame with a marker, the markers' poses, the corners' bias.

Gain and trim are fitted in the log's k and wheel radius (as every fit is) and converted to the calibration's: the
speed is r u k / (gain +- trim), so (gain, trim) scale with k r.

`refined_document` makes the calibration file (naocal.duckiebot_calibration/1) of a refinement: the input file's
document with the new gain and trim (and their stds); `naocal identify LOG --refine CAL.json --out NEW.json`
(kinds/duckiebot/verbs.py) writes it.

Refused (RefinementRefused, exit 3 on the command line, nothing returned): fewer than MIN_MARKER_FRAMES frames with a marker; a fit that
cannot determine trim (SolveError) or does not converge; a trim std above MAX_TRIM_STD (0.001: the issue's
tolerance on trim). The step is bounded by `max_step` (the new trim moves at most that far towards the estimate,
and says so): a pass is one stretch of floor, so a large change is more likely a bad pass than a changed robot.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from naocal.kinds.duckiebot.drive_log import read_drive_log
from naocal.kinds.duckiebot.calibration import CalibrationFile
from naocal.kinds.duckiebot.fit import CAMERA, Drive, fit_drive
from naocal.kinds.duckiebot.identify import detect_log, rectified_sightings
from naocal.kinds.duckiebot.robot import Kinematics
from naocal.solver.errors import SolveError

MIN_MARKER_FRAMES = 8  # frames with at least one marker: fewer leave trim's curvature to a handful of poses
MAX_TRIM_STD = 0.001  # the tolerance on trim: a refinement less certain than this is refused
MAX_STEP = 0.02  # default bound on one refinement's change of trim (the real robots' trim sd is 0.068)
MAX_GAIN_STD = 0.005  # gain is refined only when known this well (relative: 0.5 % of speed); else kept


class RefinementRefused(SolveError):
    """The pass does not carry the evidence to refine trim: no new value (exit 3, as a fit that cannot be
    trusted)."""


@dataclass(frozen=True)
class Refinement:
    """A refined calibration's kinematics (the calibration's k) and the evidence for it."""

    kinematics: Kinematics  # the calibration's, with the new trim (and gain, if `gain_refined`)
    trim_before: float
    trim_estimate: float  # what the pass says (at the new gain), before the bound on the step
    trim_std: float  # cluster-robust (clusters: fit.sighting_runs)
    step_bounded: bool  # the estimate was farther than max_step: trim moved max_step towards it
    gain_before: float
    gain_estimate: float
    gain_std: float
    gain_refined: bool  # the pass determined gain within MAX_GAIN_STD (relative); else gain is the calibration's
    marker_frames: int
    corners: int
    rms_px: float

    @property
    def trim(self) -> float:
        return self.kinematics.trim

    def describe(self) -> str:
        bounded = f" (bounded: the pass says {self.trim_estimate:+.4f})" if self.step_bounded else ""
        gain = (f"gain {self.gain_before:.4f} -> {self.kinematics.gain:.4f} +- {self.gain_std:.4f}"
                if self.gain_refined else f"gain kept at {self.gain_before:.4f} (the pass says {self.gain_estimate:.4f}"
                                          f" +- {self.gain_std:.4f})")
        return (f"trim {self.trim_before:+.4f} -> {self.trim:+.4f} +- {self.trim_std:.4f}{bounded}; {gain}; "
                f"{self.marker_frames} frames with markers, {self.corners} corners, {self.rms_px:.2f} px RMS")


def refine_trim(log_dir, calibration: CalibrationFile, *, max_step: float = MAX_STEP) -> Refinement:
    """Refine `calibration`'s (a calibration file read: kinds.duckiebot.calibration) trim (and gain) from the lane
    pass at `log_dir` (module docstring). DataError for a bad log; RefinementRefused when the pass cannot refine
    trim well enough."""
    if not max_step > 0:
        raise ValueError(f"max_step must be positive, got {max_step!r}")
    log = read_drive_log(log_dir)
    detections = detect_log(log, boards=False)
    marker_frames = sum(1 for markers in detections.markers if markers)
    if marker_frames < MIN_MARKER_FRAMES:
        raise RefinementRefused(f"{log.path}: {marker_frames} frames with a marker in view, at least "
                                f"{MIN_MARKER_FRAMES} are needed to refine trim: trim is unchanged")
    kin = calibration.kinematics
    # (gain, trim) in the calibration's k and radius -> the log's: the speed is r u k / (gain +- trim)
    to_log = (log.wheels.k * log.wheels.radius_m) / (kin.k * kin.radius_m)
    # through the calibration's model of the wheel driver: the trim it refines is that model's
    drive = dataclasses.replace(Drive.of_log(log, pwm_driver=calibration.pwm_driver), baseline_m=kin.baseline_m)
    sightings = rectified_sightings(detections, calibration.lens)
    try:
        fit = fit_drive(drive, sightings, calibration.lens.K, log.marker_size_m, calibration.T_base_camera,
                        fixed=CAMERA + ("baseline_m",), start={"gain": kin.gain * to_log, "trim": kin.trim * to_log})
    except SolveError as err:
        raise RefinementRefused(f"{log.path}: the pass cannot refine trim ({err}): trim is unchanged") from None
    if not fit.success:
        raise RefinementRefused(f"{log.path}: the refinement did not converge ({fit.message}): trim is unchanged")
    trim_estimate, trim_std = fit.value("trim") / to_log, fit.stdev("trim") / to_log
    gain_estimate, gain_std = fit.value("gain") / to_log, fit.stdev("gain") / to_log
    if not trim_std <= MAX_TRIM_STD:
        raise RefinementRefused(f"{log.path}: the pass determines trim only to +-{trim_std:.4f} (at most "
                                f"{MAX_TRIM_STD} is needed; the pass says {trim_estimate:+.4f}): trim is unchanged")
    gain_refined = gain_std <= MAX_GAIN_STD * abs(gain_estimate)
    if not gain_refined:  # what drives straight is trim / gain: keep that ratio with the calibration's gain
        trim_estimate, trim_std = trim_estimate * kin.gain / gain_estimate, trim_std * abs(kin.gain / gain_estimate)
    step = float(np.clip(trim_estimate - kin.trim, -max_step, max_step))
    new = dataclasses.replace(kin, trim=kin.trim + step, gain=gain_estimate if gain_refined else kin.gain)
    return Refinement(new, kin.trim, trim_estimate, trim_std, abs(trim_estimate - kin.trim) > max_step, kin.gain,
                      gain_estimate, gain_std, bool(gain_refined), marker_frames, int(len(fit.sightings.frame)),
                      fit.rms_px)


def refined_document(doc: dict, refinement: Refinement, source: str) -> dict:
    """The calibration file's document `doc` (as read; not changed) with the refinement's gain and trim in
    `kinematics` and `parameters` (trim's std the pass's; gain's only where the pass refined it), `source` and the
    time of creation: every other field (lens, camera pose, baseline, the calibration's fit) is the calibration's.
    The caller checks it with the reader before writing (calibration.checked_document's rule)."""
    import copy
    import time

    new = copy.deepcopy(doc)
    changed = {"trim": (refinement.trim, refinement.trim_std)}
    if refinement.gain_refined:
        changed["gain"] = (refinement.kinematics.gain, refinement.gain_std)
    for name, (value, std) in changed.items():
        new["kinematics"][name] = float(value)
        # the pass's std has no parts (calibration's std_parts: the calibration's own fit's)
        kept = {k: v for k, v in new["parameters"][name].items() if k != "std_parts"}
        new["parameters"][name] = {**kept, "value": float(value), "std": float(std)}
    new["source"], new["created"] = source, time.strftime("%Y-%m-%dT%H:%M:%S%z")
    return new
