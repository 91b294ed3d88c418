"""Verification: re-measure held-out stances without and with compensation, and compare the errors.

For each verification stance (not used in the fit), the robot is sent there twice: through the raw backend, then
through the CompensatedBackend. In both images the detected vertices are compared with the identified camera and
board model evaluated with NOMINAL joints (no joint offsets) at
- the joint readings (raw readings before, corrected readings after): does reading - c tell the true angle?
- the commanded angles (the same requested stance both times): does command + c put the joint where asked?
Before compensation both errors show the joint offsets; after it both should drop to the detection noise.
The corners and images identify would set aside as mis-detections are set aside here by the same rule
(solver.fit.set_aside_mis_detections, decided per phase against a local refit of the identified model at the
readings, so that an offset still in the data is not taken for a mis-detection), and the errors are given with
and without them. RMS as everywhere in naocal: over both coordinates, sqrt(RSS / 2N), as the fit's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from naocal.agent.estimate import FULL, RunningEstimate
from naocal.agent.record import CaptureRecord
from naocal.agent.robot import Robot
from naocal.solver.errors import SafetyError
from naocal.solver.joints import JOINTS, LEGS

log = logging.getLogger(__name__)


@dataclass
class VerificationReport:
    """RMS errors (px, over both coordinates as the fit's) per leg and phase ("before", "after") for reading- and
    command-based predictions, without the corners set aside as mis-detections (`all_...`: with them);
    `captures` holds the per-capture numbers."""

    per_leg: dict = field(default_factory=dict)
    captures: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    set_aside: dict = field(default_factory=dict)  # phase -> {"n_corners", "of_corners", "description"}

    def to_dict(self) -> dict:
        return {"per_leg": self.per_leg, "captures": self.captures, "skipped": self.skipped,
                "set_aside": self.set_aside}


def _rms(residual) -> float:
    """RMS over both coordinates, sqrt(RSS / 2N), as the fit's."""
    residual = np.asarray(residual, dtype=float)
    return float(np.sqrt(np.mean(residual ** 2))) if residual.size else float("nan")


def identified_intrinsics(prior: dict, identification, camera: str | None = None) -> dict:
    """The camera's prior intrinsics (dict of fx_px, fy_px, cx_px, cy_px, ...) with the identification's corrections
    added when it fitted them (the GLS fit frees them: solver.effects.intrinsics). Without them the held-out
    captures are predicted with another camera than the fit's (realistic mock seed 1, mis-detections set aside: the
    error after compensation at the readings 1.42 / 1.00 px for legs L / R; with them 0.29 / 0.34 px, the fit's
    RMS 0.33 px)."""
    camera = camera or FULL.setup.cameras[0]
    names = identification.registry.index
    return {**prior, **{f"{k}_px": prior[f"{k}_px"] + identification.value(f"intrinsics.{camera}.{k}")
                        for k in ("fx", "fy", "cx", "cy") if f"intrinsics.{camera}.{k}" in names}}


def _set_aside(captures, values, intrinsics):
    """(kept (K, 24) bool per capture and vertex, solver.fit.SetAside) of one phase's captures [(leg, stance,
    theta, uv)]: what identify would set aside, decided on the identified model at the readings `theta`."""
    from naocal.solver.adapter import make_model_data
    from naocal.solver.fit import set_aside_mis_detections
    from naocal.solver.verify import refit_from

    data = make_model_data(np.array([c[2] for c in captures]), np.array([c[0] for c in captures]),
                           np.array([c[1] for c in captures]), np.zeros(len(captures), dtype=int),
                           intrinsics=intrinsics)
    data.uv_px = np.concatenate([c[3] for c in captures])
    aside = set_aside_mis_detections(data, refit_from(FULL), values)
    kept = np.zeros((len(captures), len(captures[0][3])), dtype=bool)
    kept[aside.data.image_id[aside.data.image_of_row], aside.data.vertex] = True
    return kept, aside


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
    captures = {"before": [], "after": []}  # [(leg, stance, theta, uv, r_read, r_cmd)]
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
            captures[phase].append((stance.leg, stance.stance, np.asarray(theta, dtype=float), uv, r_read, r_cmd,
                                    len(report.captures)))
            result[phase] = {"reading_rms_px": _rms(r_read), "command_rms_px": _rms(r_cmd)}
            if stores:
                store = stores.get("raw" if phase == "before" else "compensated")
                if store is not None:
                    store.save(CaptureRecord(stance.image, stance.leg, stance.stance, 0, uv, theta,
                                             robot.commanded.copy(), robot.direction.copy(), np.zeros(len(JOINTS)),
                                             float(image.t_exposure_s), float(t_joints)), image.pixels, 0.0)
        report.captures.append(result)
    kept, report.set_aside = {}, {}
    for phase, phase_values in (("before", with_offsets.values), ("after", values)):
        if captures[phase]:
            kept[phase], aside = _set_aside(captures[phase], phase_values, intrinsics)
            report.set_aside[phase] = {"n_corners": int(kept[phase].size - kept[phase].sum()),
                                       "of_corners": int(kept[phase].size), "description": aside.describe()}
            for c, keep in zip(captures[phase], kept[phase]):
                report.captures[c[6]][phase].update(reading_rms_px=_rms(c[4][keep]), command_rms_px=_rms(c[5][keep]),
                                                    all_reading_rms_px=_rms(c[4]), all_command_rms_px=_rms(c[5]))
    for leg in LEGS:
        summary = {}
        for phase in ("before", "after"):
            mine = [(c, k) for c, k in zip(captures[phase], kept.get(phase, ())) if c[0] == leg]
            summary[phase] = {}
            for kind, column in (("reading", 4), ("command", 5)):
                summary[phase][f"{kind}_rms_px"] = _rms(np.concatenate([c[column][k] for c, k in mine])) \
                    if mine else float("nan")
                summary[phase][f"all_{kind}_rms_px"] = _rms(np.concatenate([c[column] for c, _ in mine])) \
                    if mine else float("nan")
        summary["n_stances"] = sum(1 for c in captures["after"] if c[0] == leg)
        report.per_leg[leg] = summary
    return report
