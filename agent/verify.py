"""Verification: re-measure held-out stances without and with compensation, and compare the errors.

For each verification stance (not used in the fit), the robot is sent there twice: through the raw backend, then
through the CompensatedBackend. In both images the detected vertices are compared with the identified camera and
board model evaluated with NOMINAL joints (no joint offsets) at
- the joint readings (raw readings before, corrected readings after): does reading - c tell the true angle?
- the commanded angles (the same requested stance both times): does command + c put the joint where asked?
Before compensation both errors show the joint offsets; after it both should drop to the detection noise.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from agent.estimate import FULL, RunningEstimate
from agent.record import CaptureRecord
from agent.robot import Robot
from solver.errors import SafetyError
from solver.joints import JOINTS, LEGS

log = logging.getLogger(__name__)


@dataclass
class VerificationReport:
    """RMS errors (px, over x and y together) per leg and phase ("before", "after") for reading- and
    command-based predictions; `captures` holds the per-capture numbers."""

    per_leg: dict = field(default_factory=dict)
    captures: list = field(default_factory=list)
    skipped: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"per_leg": self.per_leg, "captures": self.captures, "skipped": self.skipped}


def _rms(residual) -> float:
    residual = np.asarray(residual, dtype=float)
    return float(np.sqrt(np.mean(np.sum(residual ** 2, axis=-1)))) if residual.size else float("nan")


def verify(raw: Robot, compensated: Robot, stances, identified_values, intrinsics, detector, offset14, *,
           search_margin_px=40.0, stores: dict | None = None) -> VerificationReport:
    """Measure each verification stance (plan Still entries) raw, then compensated; see the module docstring.

    identified_values : full parameter vector of the identified model (registry agent.estimate.FULL).
    offset14 : (14,) the stored offsets c (rad): raw commands = compensated commands + c.
    stores : optional {"raw": CaptureStore, "compensated": CaptureStore} to keep the captures as datasets.
    """
    with_offsets = RunningEstimate(intrinsics)
    with_offsets.set_values(identified_values, "identified")
    nominal_joints = RunningEstimate(intrinsics)
    values = np.asarray(identified_values, dtype=float).copy()
    for j in JOINTS:
        name = f"joint_offset.{j}"
        if name in FULL.index:
            values[FULL.index[name]] = 0.0
    nominal_joints.set_values(values, "identified camera and boards, nominal joints")

    report = VerificationReport()
    errors = {leg: {"before": {"reading": [], "command": []}, "after": {"reading": [], "command": []}}
              for leg in LEGS}
    for stance in stances:
        target = stance.angles()
        result = {"leg": stance.leg, "stance": stance.stance}
        for phase, robot, predictor in (("before", raw, with_offsets), ("after", compensated, nominal_joints)):
            # Both handles drive one robot: each starts from where the other left it (paths, directions).
            if robot is raw:
                raw.commanded = compensated.commanded + offset14
            else:
                compensated.commanded = raw.commanded - offset14
            try:
                rest = robot.move(target)
            except SafetyError as err:
                report.skipped.append({"stance": stance.stance, "leg": stance.leg, "phase": phase, "reason": str(err)})
                break
            image = robot.wait_image(rest.t_still_s + robot.timing.exposure_guard_s)
            t_joints, theta = robot.read()
            detection = detector(image, predictor.predict(stance.leg, theta), stance.leg, search_margin_px)
            if not detection.ok:
                report.skipped.append({"stance": stance.stance, "leg": stance.leg, "phase": phase,
                                       "reason": f"{detection.reason} ({detection.detail})"})
                break
            uv = np.asarray(detection.vertices_px, dtype=float)
            r_read = nominal_joints.predict(stance.leg, theta) - uv
            r_cmd = nominal_joints.predict(stance.leg, robot.commanded) - uv
            errors[stance.leg][phase]["reading"].append(r_read)
            errors[stance.leg][phase]["command"].append(r_cmd)
            result[phase] = {"reading_rms_px": _rms(r_read), "command_rms_px": _rms(r_cmd)}
            if stores:
                store = stores.get("raw" if phase == "before" else "compensated")
                if store is not None:
                    store.save(CaptureRecord(stance.image, stance.leg, stance.stance, 0, uv, theta,
                                             robot.commanded.copy(), robot.direction.copy(), np.zeros(len(JOINTS)),
                                             float(image.t_exposure_s), float(t_joints)), image.pixels, 0.0)
        report.captures.append(result)
    for leg in LEGS:
        summary = {}
        for phase in ("before", "after"):
            summary[phase] = {f"{kind}_rms_px": _rms(np.concatenate(v)) if v else float("nan")
                              for kind, v in errors[leg][phase].items()}
        summary["n_stances"] = len(errors[leg]["after"]["reading"])
        report.per_leg[leg] = summary
    return report
