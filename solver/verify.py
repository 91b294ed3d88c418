"""Verification: is a calibration still good? The residuals of new data under the calibration's fixed values.

What identify sets aside is set aside first, by its own rule (solver.fit.set_aside_mis_detections, decided against
a refit so that a drift is never set aside). The residuals at the calibration's values are compared with the
calibration's own RMS (the offsets file's `fit.rms_px`) and with the new data's noise floor
(solver.diagnostics.compare); the calibration has drifted when they exceed both by DRIFT_RATIO, or when a calibrated
parameter has moved: forward score tests from the calibration's values (`apparent_changes`) name what moved, a
joint, a camera or a board. Pure functions of (ModelData or Dataset, Offsets); docs/DIAGNOSTICS.md, "Is yesterday's
calibration still good?".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from naocal.solver.diagnostics import compare, locate
from naocal.solver.errors import DataError
from naocal.solver.fit import GLS_MIN_SIGMA_PX, describe_angles, moving_handled, set_aside_mis_detections
from naocal.solver.model import Model, ModelData
from naocal.solver.quantisation import reading_resolution
from naocal.solver.registry import Registry

# The new data's RMS may exceed max(calibration RMS, noise floor) by this factor and still be "good": new data of
# the same robot with the same noise give a ratio near 1.0 (1.00 to 1.05 on the mock and synthetic data; 1.04 on a
# second realistic-mock run of seed 1); a 1 deg knee gives 6.3 (docs/DIAGNOSTICS.md).
DRIFT_RATIO = 1.5
# A parameter is named as moved (and the calibration drifted) when its apparent change is this many standard
# deviations ...
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
    reading_step_rad: np.ndarray | None = None  # (J,) the readings' encoder steps (`reading_step`)
    quantisation_share = 1.0  # the readings' whole quantisation error shows (solver.diagnostics.compare)

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
    images_set_aside: list = field(default_factory=list)  # [solver.image_check.SetAsideImage], as identify's
    outliers: list = field(default_factory=list)  # [solver.fit.Outlier]: corners set aside, as identify's
    robust_scale_px: float = float("nan")  # of the non-rigid residual (solver.fit)
    all_corners: dict = field(default_factory=dict)  # residual_statistics before anything was set aside
    n_moving_set_aside: int = 0  # captures taken while moving (the calibration has no time_lag)
    angles: str = ""  # which joint angles were used, and why (verify_dataset; '' for ModelData given)

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
            "outliers": [{"image": o.image, "vertex": o.vertex, "size_px": o.size_px} for o in self.outliers],
            "robust_scale_px": self.robust_scale_px, "all_corners": self.all_corners,
            "moving_captures_set_aside": self.n_moving_set_aside, "angles": self.angles,
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


def reading_step(data: ModelData) -> np.ndarray:
    """(J,) the encoder step of the still captures' joint readings (solver.quantisation.reading_resolution); on a
    few images, where no joint has the distinct readings that needs, the readings of all joints pooled: one kind of
    encoder, every reading on its grid (4 held-out images of the realistic mock: 0.0879 deg, 2 pi / 4096)."""
    still = np.ones(data.n_images, bool) if data.velocity is None else np.all(data.velocity == 0.0, axis=1)
    step = reading_resolution(data.theta[still])
    if not np.any(step > 0):
        step = np.full(len(data.joints), reading_resolution(data.theta[still].reshape(-1, 1))[0])
    return step


def calibration_values(offsets, registry: Registry) -> tuple[np.ndarray, list[str]]:
    """The full parameter vector an offsets file (solver.offsets.Offsets) stands for, and the registry's parameters
    it has no value for (0 then). model.parameters first (every fitted parameter by its registry name); for files
    without them, the base model's sections (joint_offsets_rad, camera_rotation_rad, board_mount)."""
    from naocal.solver.effects.board_mount import FILE_KEYS

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


def apparent_changes(model: Model, registry: Registry, values: np.ndarray, step_rad=None, sigma_px: float = 0.0):
    """What moved, by forward selection from `values`: [(free index, change, std, z)], the most telling first.

    Each round asks of every calibrated parameter not yet chosen: alone (with those chosen so far refitted), by how
    many standard deviations would its change explain the new residuals (the score test of that parameter)? The
    best is refitted with the chosen ones and kept while its change is at least DRIFT_Z standard deviations as
    identify reckons them (solver.identify.parameter_covariance: cluster-robust over the stances, at least the
    classic s^2 (J^T W J)^-1). One parameter at a time, not all at once: the leg's pitch joints, the camera's pitch
    and the intrinsics are so correlated that a knee changed by 0.12 deg (3 of its standard deviations, realistic
    mock seed 1) is 5 standard deviations when the others are held, and 2.5 when all are refitted, which then also
    share it out among the others. Cluster-robust: a few images' readings' errors move their boards as a change
    would, which the classic estimate, pixels taken as independent, cannot see (4 held-out images of the realistic
    mock claimed the L board 0.2 mm off at 19 standard deviations).
    step_rad : (J,) the readings' encoder steps. When some are quantised, W is the inverse covariance of the
        calibration's own fit (solver.gls, detector noise `sigma_px`): the images of one held command share its
        reading's error, which moves whole boards as a changed offset would; weighted as if independent (W = I)
        those shared errors pass for a change (realistic mock seed 1, the run's own data under its own offsets:
        LHipRoll +0.06 deg at 5.0 standard deviations; with W nothing above 0.5)."""
    from naocal.solver.identify import NormalEquations
    from naocal.solver.scoretest import stance_cluster_of_image

    if step_rad is not None and np.any(np.asarray(step_rad) > 0):
        from naocal.solver.gls import GLSProblem

        normal_at = GLSProblem(model.data, registry, values, step_rad, sigma_px)
        equations = normal_at.equations
    else:
        normal_at = equations = NormalEquations(model.data, registry, values)
    return forward_changes(normal_at, equations.scales, registry.pack(values), 2 * model.data.n_rows,
                           stance_cluster_of_image(equations.model.data))


def forward_changes(normal_at, scales, free, n: int, cluster, refitted=()) -> list:
    """apparent_changes' forward selection, of any model's normal equations (the NAO's, the arm's
    kinds.arm.identify.ArmEquations): [(free index, change, std, z)], the most telling first.

    normal_at(free) : solver.identify.Normal at a free vector (scaled variables); scales : the free parameters';
    n : the residual components; cluster : each score row's cluster (stance, pose); refitted : free indices refitted
    with every candidate and never named (the arm's sensors' frames and nuisances, found from the new data)."""
    from naocal.solver.identify import identifiability, parameter_covariance

    normal = normal_at(free)
    A, g, chi2 = normal.A, normal.g, 2.0 * normal.cost  # scaled units
    eigenvalues, vectors = np.linalg.eigh(A)
    usable = eigenvalues > 1e-12 * max(eigenvalues.max(initial=0.0), 1e-300)
    blind = np.abs(vectors[:, ~usable]).max(axis=1, initial=0.0) > 0.05  # in an unidentifiable direction
    refitted = list(refitted)
    chosen, found = list(refitted), []
    while len(chosen) < len(g):
        C_inverse = np.linalg.pinv(A[np.ix_(chosen, chosen)]) if chosen else np.zeros((0, 0))
        left = max(chi2 - float(g[chosen] @ C_inverse @ g[chosen]), 0.0)
        rest_g = g - A[:, chosen] @ (C_inverse @ g[chosen])  # the gradient once the chosen ones are refitted
        rest_a = np.diag(A) - np.einsum("ij,jk,ki->i", A[:, chosen], C_inverse, A[chosen, :])
        with np.errstate(divide="ignore", invalid="ignore"):
            score = np.where((rest_a > 1e-9 * np.diag(A)) & ~blind,
                             np.abs(rest_g) / np.sqrt(left / max(n - len(chosen), 1) * rest_a), 0.0)
        score[chosen] = 0.0
        best = int(np.argmax(score))
        if not score[best] >= DRIFT_Z:
            break
        trial = chosen + [best]
        step = np.zeros(len(g))
        step[trial] = -np.linalg.lstsq(A[np.ix_(trial, trial)], g[trial], rcond=None)[0]
        after = normal_at(free + step * scales)  # its residuals and each image's score after the refit
        _, sv, Vt = identifiability(A[np.ix_(trial, trial)])
        rss = 2.0 * after.cost
        covariance = parameter_covariance(A[np.ix_(trial, trial)], rss, after.image_scores[:, trial], sv, Vt,
                                          scales[trial], cluster, n, max(n - len(trial), 1))[0]
        std = np.sqrt(np.diag(covariance))
        change = step[trial] * scales[trial]
        if not abs(change[-1]) >= DRIFT_Z * std[-1]:
            break
        chosen, found = trial, list(zip(trial, change, std))
    return [(k, float(c), float(sd), float(abs(c) / sd)) for k, c, sd in found if k not in refitted]


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


def still_good(ratio: float, moved: list) -> bool:
    """The verdict's rule (the NAO's and the arm's): drifted when the RMS is beyond DRIFT_RATIO times the reference,
    or when a calibrated value has moved (the new data place it DRIFT_Z standard deviations away: a 0.1 deg knee adds
    0.07 px to a 0.33 px RMS, far inside DRIFT_RATIO, but is 5-10 standard deviations)."""
    return bool(ratio <= DRIFT_RATIO) and not moved


def verdict_text(good: bool, head: str, moved: list, suspects: list, unexplained: str) -> str:
    """The one-line verdict (the NAO's and the arm's): still good, drifted with what moved, or drifted unexplained."""
    if good:
        return f"still good: {head}"
    if moved:
        listed = "; ".join(f"{e['parameter']} {e['display'][0]:+.3f} {e['display'][1]}" for e in moved[:4])
        return f"drifted: {head}; the pattern points to {', '.join(suspects[:3])} ({listed})"
    return f"drifted: {head}; no calibrated parameter explains it ({unexplained}: run naocal diagnose)"


def refit_from(registry: Registry):
    """refit(data, x0) for solver.fit.robust_fit under a fixed calibration: identify's least squares from x0 (the
    calibration's values; without its identifiability check: a small dataset's undetermined directions just stay
    where the calibration put them). The mis-detections are decided against this refit, as identify decides them
    against its fit: a joint that moved moves its boards, the refit follows it, and so a drift is never set aside
    as mis-detected corners or far-off images. The verdict stays on the calibration's values."""
    from naocal.solver.identify import identify

    def refit(data: ModelData, x0):
        return identify(data, registry, x0=x0, check=False)

    return refit


@dataclass
class _SetAside:
    """New data as verify evaluates them: what identify would set aside, set aside (`_set_aside`)."""

    data: ModelData  # every still capture (or every capture, when the calibration models motion)
    n_moving: int  # captures set aside as taken while moving
    registry: Registry
    values: np.ndarray  # the calibration's
    missing: list  # parameters the offsets file has no value for
    aside: object  # solver.fit.SetAside


def _set_aside(data: ModelData, offsets) -> _SetAside:
    effects = tuple(offsets.model.get("effects", ()))
    still, n_moving = moving_handled(data, effects, "auto")
    registry = Registry.for_data(still, effects)
    values, missing = calibration_values(offsets, registry)
    return _SetAside(still, n_moving, registry, values, missing,
                     set_aside_mis_detections(still, refit_from(registry), values))


def verify_dataset(dataset, offsets, *, angles: str = "auto", pixel_noise_px: float | None = None) -> Verdict:
    """verify() of a read dataset (solver.dataset.Dataset). angles 'auto': as identify chooses them, each hypothesis
    (solver.fit.ANGLE_HYPOTHESES) is tried and the one whose refit explains the images best is used (the offsets
    file does not say which the calibration used; the calibration's own data choose the same)."""
    from naocal.solver.adapter import model_data_from_dataset
    from naocal.solver.fit import ANGLE_HYPOTHESES, choose_angles

    tried, seen = {}, []
    for mode in (ANGLE_HYPOTHESES if angles == "auto" else (angles,)):
        data = model_data_from_dataset(dataset, angles=mode)
        if any(np.array_equal(data.theta, other) for other in seen):
            continue  # the same angles as a hypothesis already tried (unquantised readings: cell = measured)
        seen.append(data.theta)
        tried[mode] = _set_aside(data, offsets)
    chosen, hypotheses = choose_angles({mode: (t.aside.data, t.aside.fit, t.aside.outliers, t.aside.robust_scale_px,
                                               t.aside.images) for mode, t in tried.items()})
    return _verdict(tried[chosen], offsets, pixel_noise_px, (chosen, hypotheses))


def verify(data: ModelData, offsets, *, pixel_noise_px: float | None = None) -> Verdict:
    """The residuals of `data` under the calibration `offsets`, compared with the calibration's RMS and the data's
    noise floor, and the verdict (see the module's docstring). What identify sets aside is set aside first, by the
    same rule (solver.fit.set_aside_mis_detections): captures taken while moving (unless the calibration models
    them), images no view of a flat board explains, corners no rigid motion of their board explains: a
    mis-detection is no evidence of drift, and left in, it raises the noise floor over any drift (realistic mock
    seed 1: 2.4 px against the calibration's 0.33 px, and +1 deg on LKneePitch passed as still good)."""
    return _verdict(_set_aside(data, offsets), offsets, pixel_noise_px, None)


def _verdict(new: _SetAside, offsets, pixel_noise_px, angles) -> Verdict:
    registry, values, aside = new.registry, new.values, new.aside
    all_corners = residual_statistics(Model(new.data, registry).residuals(values))
    model = Model(aside.data, registry)
    fit = FixedFit(model, registry, values, model.residuals(values), reading_step(aside.data))
    data = model.data  # sorted by target
    r = fit.residuals_px
    missing = new.missing

    comparison = compare(fit, pixel_noise_px=pixel_noise_px)
    rms_xy = offsets.fit.get("rms_px")
    calibration_rms = float(math.sqrt((rms_xy[0] ** 2 + rms_xy[1] ** 2) / 2)) if rms_xy else None
    reference = max(calibration_rms or 0.0, comparison.noise_px)
    overall = residual_statistics(r)
    ratio = overall["rms_px"] / reference if reference > 0 else math.inf

    row_camera, row_target = data.camera[data.image_of_row], data.target[data.image_of_row]
    per_camera = {c: residual_statistics(r[row_camera == c]) for c in dict.fromkeys(data.camera.tolist())}
    per_target = {t: residual_statistics(r[row_target == t]) for t in dict.fromkeys(data.target.tolist())}
    starts = np.searchsorted(data.image_of_row, np.arange(data.n_images + 1))
    per_image = [{"image": int(data.image_id[m]), "camera": str(data.camera[m]), "target": str(data.target[m]),
                  "stance": int(data.stance[m]), "head_posture": int(data.head_posture[m]),
                  **residual_statistics(r[starts[m]:starts[m + 1]])} for m in range(data.n_images)]
    per_image.sort(key=lambda e: e["image"])
    worst = sorted((e for e in per_image if e["rms_px"] > DRIFT_RATIO * reference), key=lambda e: -e["rms_px"])

    moved = []
    for k, change, std, z in apparent_changes(model, registry, values, fit.reading_step_rad,
                                              max(aside.robust_scale_px, GLS_MIN_SIGMA_PX)):
        name = registry.free_names[k]
        p = registry.parameter(name)
        if abs(change) >= DRIFT_MIN_SCALE * p.scale:
            shown, unit = registry.display(name, change)
            moved.append({"parameter": name, "group": _group(p), "change": change, "std": std, "z": z,
                          "unit": p.unit, "display": [float(shown), unit], "size": float(abs(change) / p.scale)})
    suspects = list(dict.fromkeys(e["group"] for e in moved))
    good = still_good(ratio, moved)
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
        warnings=warnings, images_set_aside=aside.images, outliers=aside.outliers,
        robust_scale_px=aside.robust_scale_px, all_corners=all_corners, n_moving_set_aside=new.n_moving,
        angles=describe_angles(*angles, float(np.max(fit.reading_step_rad, initial=0.0)))
        if angles else "")
