"""Verification: is a calibration still good? The residuals of new data under the calibration's fixed values.

Nothing is refitted. The residuals are compared with the calibration's own RMS (the offsets file's `fit.rms_px`)
and with the new data's noise floor (solver.diagnostics.compare); when they exceed both by DRIFT_RATIO the
calibration has drifted, and one linearised Gauss-Newton step from the calibration's values (the change of each
calibrated parameter that would best explain the new residuals) names what moved: a joint, a camera or a board.
Pure functions of (ModelData, Offsets); docs/DIAGNOSTICS.md, "Is yesterday's calibration still good?".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from solver.diagnostics import compare, locate
from solver.errors import DataError
from solver.image_check import check_images, without_images
from solver.model import Model, ModelData
from solver.registry import Registry

# The new data's RMS may exceed max(calibration RMS, noise floor) by this factor and still be "good": new data of
# the same robot with the same noise give a ratio near 1.0 (1.00 to 1.05 on the mock and synthetic data); a
# 0.5 deg joint offset change gives tens (tests/test_verify.py).
DRIFT_RATIO = 1.5
# A parameter is named as moved when its apparent change is this many standard deviations ...
DRIFT_Z = 5.0
# ... and at least this share of its typical size (the registry's scale: 0.057 deg for a joint offset).
DRIFT_MIN_SCALE = 0.1
# Images whose RMS exceeds the reference by DRIFT_RATIO are listed (at most this many).
WORST_IMAGES = 5


@dataclass
class FixedFit:
    """The calibration's values on new data, shaped like an IdentificationResult where the diagnostics read one."""

    model: Model
    registry: Registry
    values: np.ndarray  # full parameter vector (the calibration's)
    residuals_px: np.ndarray  # (N, 2) predicted - detected

    @property
    def rms_px(self) -> tuple[float, float]:
        rms = np.sqrt(np.mean(self.residuals_px ** 2, axis=0))
        return float(rms[0]), float(rms[1])

    @property
    def sigma_px(self) -> float:
        """Nothing was fitted: sqrt(RSS / n)."""
        return float(np.sqrt(np.mean(self.residuals_px ** 2)))


@dataclass
class Verdict:
    """The verdict and the numbers behind it. RMS values in px over both coordinates unless they say (x, y)."""

    good: bool
    verdict: str
    overall: dict  # residual_statistics of all vertices
    per_camera: dict  # camera -> residual_statistics
    per_target: dict  # target -> residual_statistics
    per_image: list  # [{"image", "camera", "target", "stance", "head_posture", **residual_statistics}]
    calibration_rms_px: float | None  # the fit's own RMS (offsets file), over both coordinates
    noise_floor_px: float  # of the new data (solver.diagnostics.Comparison.noise_px)
    noise_source: str  # 'dataset' (its pixel_noise_px) or 'estimated'
    reference_px: float  # max(calibration_rms_px, noise_floor_px)
    ratio: float  # overall RMS / reference_px
    moved: list  # [{"parameter", "group", "change", "std", "z", "display": [value, unit], ...}], largest first
    suspects: list  # joints, cameras, targets the moved parameters belong to, most moved first
    worst_images: list  # images beyond DRIFT_RATIO x reference, worst first
    board_summary: str  # solver.diagnostics.locate's comparison of the boards
    uncalibrated: list  # parameters of the model the offsets file has no value for (taken as 0)
    warnings: list = field(default_factory=list)
    images_set_aside: list = field(default_factory=list)  # [solver.image_check.SetAsideImage]: no view of a board

    def as_dict(self) -> dict:
        return {
            "good": self.good, "verdict": self.verdict, "overall": self.overall, "per_camera": self.per_camera,
            "per_target": self.per_target, "per_image": self.per_image,
            "calibration_rms_px": self.calibration_rms_px, "noise_floor_px": self.noise_floor_px,
            "noise_source": self.noise_source, "reference_px": self.reference_px, "ratio": self.ratio,
            "drift_ratio": DRIFT_RATIO, "moved": self.moved, "suspects": self.suspects,
            "worst_images": self.worst_images, "board_summary": self.board_summary,
            "uncalibrated": self.uncalibrated, "warnings": self.warnings,
            "images_set_aside": [s.as_dict() for s in self.images_set_aside],
        }


def residual_statistics(residuals_px: np.ndarray) -> dict:
    """{"n_vertices", "rms_px" (both coordinates), "rms_xy_px", "median_px", "p95_px", "max_px"}: RMS as everywhere
    in naocal (sqrt(RSS / 2N)); median, 95th percentile and maximum of each vertex's error distance |(du, dv)|."""
    r = np.asarray(residuals_px, dtype=float).reshape(-1, 2)
    if not len(r):
        return {"n_vertices": 0, "rms_px": None, "rms_xy_px": None, "median_px": None, "p95_px": None,
                "max_px": None}
    distance = np.hypot(r[:, 0], r[:, 1])
    return {"n_vertices": int(len(r)), "rms_px": float(np.sqrt(np.mean(r ** 2))),
            "rms_xy_px": np.sqrt(np.mean(r ** 2, axis=0)).tolist(), "median_px": float(np.median(distance)),
            "p95_px": float(np.percentile(distance, 95)), "max_px": float(distance.max())}


def calibration_values(offsets, registry: Registry) -> tuple[np.ndarray, list[str]]:
    """The full parameter vector an offsets file (solver.offsets.Offsets) stands for, and the registry's parameters
    it has no value for (0 then). model.parameters first (every fitted parameter by its registry name); for files
    without them, the base model's sections (joint_offsets_rad, camera_rotation_rad, board_mount)."""
    from solver.effects.board_mount import FILE_KEYS

    stored = {name: float(entry["value"]) for name, entry in offsets.model.get("parameters", {}).items()}
    values, missing = registry.zeros(), []
    for i, p in enumerate(registry.parameters):
        value = stored.get(p.name)
        if value is None and p.effect == "joint_offsets":
            value = offsets.joint_offsets_rad.get(p.joint)
        elif value is None and p.effect == "camera_rotation":
            value = offsets.camera_rotation_rad.get(p.camera, {}).get(p.component)
        elif value is None and p.effect == "board_mount":
            value = offsets.board_mount.get(p.target, {}).get(FILE_KEYS[p.component])
        if value is None:
            missing.append(p.name)
        else:
            values[i] = float(value)
    return values, missing


def check_same_robot(offsets, offsets_path, dataset_meta: dict, robot) -> None:
    """DataError unless the offsets are of the dataset's robot: its description, and its body and head where both
    files name them ('unknown' and absent names are not compared)."""
    description = offsets.robot.get("description") or "nao"
    if description != robot.name:
        raise DataError(offsets_path, f"the offsets are of robot description {description!r}, the dataset of "
                                      f"{robot.name!r}", field="robot.description")
    meta = dataset_meta.get("robot", {})
    for key in ("body_id", "head_id"):
        ours, theirs = offsets.robot.get(key), meta.get(key, meta.get("id"))
        if ours in (None, "unknown") or theirs in (None, "unknown"):
            continue
        if str(ours) != str(theirs):
            part = key.split("_")[0]
            raise DataError(offsets_path, f"the offsets are of {part} {ours!r}, the dataset of {part} {theirs!r}: "
                                          "another robot's calibration", field=f"robot.{key}")


def apparent_changes(model: Model, registry: Registry, values: np.ndarray):
    """One Gauss-Newton step from `values` on the registry's free parameters: (change (free,), std (free,),
    residual RSS after the step). The std is s (J^T J)^-1/2 with s from the linearised residual after the step;
    directions the data cannot determine get change 0 and std inf."""
    from solver.identify import UNIDENTIFIABLE_RATIO, normal_equations

    A, g, rss, n = normal_equations(model, registry, values)
    scales = registry.scales[registry.free_index]
    As = A * np.outer(scales, scales)
    eigenvalues, vectors = np.linalg.eigh(As)
    usable = eigenvalues > UNIDENTIFIABLE_RATIO ** 2 * max(eigenvalues.max(initial=0.0), 1e-300)
    inverse = (vectors * np.where(usable, 1.0 / np.where(usable, eigenvalues, 1.0), 0.0)) @ vectors.T
    step_s = -inverse @ (g * scales)
    rss_after = max(rss + float(step_s @ (g * scales)), 0.0)  # linear least squares: RSS - g^T A^-1 g
    s2 = rss_after / max(n - int(usable.sum()), 1)
    variance = np.diag(inverse) * s2
    blind = np.abs(vectors[:, ~usable]).max(axis=1, initial=0.0) > 0.05  # in an unidentifiable direction
    std = np.where(blind, np.inf, np.sqrt(np.maximum(variance, 0.0))) * scales
    return step_s * scales, std, rss_after


def _group(p) -> str:
    if p.joint:
        return f"joint {p.joint}"
    if p.camera:
        return f"camera {p.camera}"
    if p.target:
        return f"board {p.target}"
    return p.effect


def moved_text(entry: dict) -> str:
    """One `moved` entry as verify prints it (the NAO's and the arm's)."""
    return (f"moved: {entry['parameter']} {entry['display'][0]:+.4f} {entry['display'][1]} "
            f"({entry['z']:.0f} standard deviations)")


def verdict_text(good: bool, head: str, moved: list, suspects: list, unexplained: str) -> str:
    """The one-line verdict (the NAO's and the arm's): still good, drifted with what moved, or drifted unexplained."""
    if good:
        return f"still good: {head}"
    if moved:
        listed = "; ".join(f"{e['parameter']} {e['display'][0]:+.3f} {e['display'][1]}" for e in moved[:4])
        return f"drifted: {head}; the pattern points to {', '.join(suspects[:3])} ({listed})"
    return f"drifted: {head}; no calibrated parameter explains it ({unexplained}: run naocal diagnose)"


def verify(data: ModelData, offsets, *, pixel_noise_px: float | None = None) -> Verdict:
    """The residuals of `data` under the calibration `offsets`, compared with the calibration's RMS and the data's
    noise floor, and the verdict (see the module's docstring). Images no view of a flat board explains are set
    aside first, as the fit sets them aside (solver.image_check): a mis-detected image is no evidence of drift."""
    check = check_images(data)
    data = without_images(data, {s.image for s in check.set_aside}, check)
    effects = tuple(offsets.model.get("effects", ()))
    registry = Registry.for_data(data, effects)
    values, missing = calibration_values(offsets, registry)
    model = Model(data, registry)
    fit = FixedFit(model, registry, values, model.residuals(values))
    data = model.data  # sorted by target
    r = fit.residuals_px

    comparison = compare(fit, pixel_noise_px=pixel_noise_px)
    rms_xy = offsets.fit.get("rms_px")
    calibration_rms = float(math.sqrt((rms_xy[0] ** 2 + rms_xy[1] ** 2) / 2)) if rms_xy else None
    reference = max(calibration_rms or 0.0, comparison.noise_px)
    overall = residual_statistics(r)
    ratio = overall["rms_px"] / reference if reference > 0 else math.inf
    good = bool(ratio <= DRIFT_RATIO)

    row_camera, row_target = data.camera[data.image_of_row], data.target[data.image_of_row]
    per_camera = {c: residual_statistics(r[row_camera == c]) for c in dict.fromkeys(data.camera.tolist())}
    per_target = {t: residual_statistics(r[row_target == t]) for t in dict.fromkeys(data.target.tolist())}
    starts = np.searchsorted(data.image_of_row, np.arange(data.n_images + 1))
    per_image = [{"image": int(data.image_id[m]), "camera": str(data.camera[m]), "target": str(data.target[m]),
                  "stance": int(data.stance[m]), "head_posture": int(data.head_posture[m]),
                  **residual_statistics(r[starts[m]:starts[m + 1]])} for m in range(data.n_images)]
    per_image.sort(key=lambda e: e["image"])
    worst = sorted((e for e in per_image if e["rms_px"] > DRIFT_RATIO * reference), key=lambda e: -e["rms_px"])

    change, std, _ = apparent_changes(model, registry, values)
    moved = []
    for k, name in enumerate(registry.free_names):
        p = registry.parameter(name)
        z = abs(change[k]) / std[k] if std[k] > 0 else math.inf
        if z >= DRIFT_Z and abs(change[k]) >= DRIFT_MIN_SCALE * p.scale:
            shown, unit = registry.display(name, change[k])
            moved.append({"parameter": name, "group": _group(p), "change": float(change[k]), "std": float(std[k]),
                          "z": float(z), "unit": p.unit, "display": [float(shown), unit],
                          "size": float(abs(change[k]) / p.scale)})
    moved.sort(key=lambda e: -e["size"])
    suspects = list(dict.fromkeys(e["group"] for e in moved))
    board_summary = locate(fit, worst=0).board_summary if not good else ""

    warnings = []
    if missing:
        warnings.append(f"the offsets have no value for {len(missing)} parameter(s) of these data "
                        f"({', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}): taken as 0 (nominal)")
    against = (f"calibration {calibration_rms:.3f} px, " if calibration_rms is not None else "") + \
        f"noise floor {comparison.noise_px:.3f} px"
    head = f"RMS {overall['rms_px']:.3f} px over {overall['n_vertices']} vertices ({against}; ratio {ratio:.2f})"
    verdict = verdict_text(good, head, moved, suspects, "an effect the calibration lacks, or bad detections")
    return Verdict(
        good=good, verdict=verdict, overall=overall, per_camera=per_camera, per_target=per_target,
        per_image=per_image, calibration_rms_px=calibration_rms, noise_floor_px=comparison.noise_px,
        noise_source=comparison.noise_source, reference_px=reference, ratio=float(ratio), moved=moved,
        suspects=suspects, worst_images=worst[:WORST_IMAGES], board_summary=board_summary, uncalibrated=missing,
        warnings=warnings, images_set_aside=check.set_aside)
