"""Diagnostics: compare the fitted model with the measurements, locate where it fails, name the missing effect.

Pure functions of a fitted `IdentificationResult` (its model, data, values and residuals); nothing is written.
The method is docs/DIAGNOSTICS.md; the statistics live in solver.scoretest,
the noise floor in solver.noisefloor:

- compare: RMS overall, per leg, stance, head posture and image, against the noise floor;
- locate: the worst images and stances, the rigid / non-rigid split of every image's residual, left against right
  board, and how much of the misfit a board motion proportional to each candidate regressor would explain;
- names: a score (Lagrange multiplier) test for every effect not yet in the model, with its predicted RMS,
  predicted parameter values, a significance test clustered by stance and a uniqueness measure.

Residuals are predicted - detected, px. "RMS" without an axis is the RMS over both pixel coordinates,
sqrt(RSS / (2 N)) for N vertices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from naocal.solver.effects import EFFECTS, EXTRA_EFFECTS, owner_of
from naocal.solver.model import Model, ModelData
from naocal.solver.noisefloor import RigidSplit, encoder_noise_px, noise_floor_estimate
from naocal.solver.quantisation import reading_resolution
from naocal.solver.registry import Registry
from naocal.solver.scoretest import (RANK_TOLERANCE, orthonormal_basis, per_image_sum, project_off, rms, score_test,
                              stance_clusters)

# Family-wise false-positive rate of the candidate ranking: a candidate is significant when its p-value is below
# FAMILY_ALPHA / (number of candidates tested) (Bonferroni). 0.001: a still robot with a complete model should
# almost never be told to add a term.
FAMILY_ALPHA = 1e-3
# Physically plausible size of each candidate's parameters (absolute value, SI; each effect's `plausible_limit`,
# and its sign: `plausible_min`, Effect.implausibility): beyond it a significant candidate is probably standing in
# for something else.
PLAUSIBLE_LIMITS = {name: e.plausible_limit for name, e in EFFECTS.items() if not e.base}
# Below this uniqueness the data can hardly tell a candidate from what the model already has.
LOW_UNIQUENESS = 0.05
# A candidate of low uniqueness that explains less than this share of the misfit is a stand-in: the little of
# its signature the model cannot already produce correlates with some misfit no candidate models (a hidden knee
# axis tilt of 1.5 deg made camera_translation "significant" for 14 % of the misfit; a real hidden camera
# translation, intrinsics or head offset explains nearly all of it).
STAND_IN_SHARE = 0.5
# A predicted value is implausible only when it is beyond the effect's range by more than this many of its
# standard deviations: the one-step prediction of a weakly excited parameter (an ankle roll's compliance, which
# feels little torque) swings far while a large misfit remains, without saying anything about its size.
PLAUSIBLE_Z = 3.0


# --------------------------------------------------------------------------------------------- compare


@dataclass
class Comparison:
    """How well the model fits, by group, against the noise floor. RMS values in px."""

    rms_px: tuple[float, float]  # (x, y)
    rms_total_px: float  # over both coordinates
    sigma_fit_px: float  # s = sqrt(RSS / (n - p))
    noise_px: float  # the noise floor: sqrt(detector_noise_px^2 + encoder_noise_px^2)
    noise_source: str  # of the detector noise: 'dataset' (its pixel_noise_px) or 'estimated'
    noise_estimate_px: float  # detector noise from the non-rigid part of the residuals (`noise_floor_estimate`)
    detector_noise_px: float  # the dataset's pixel_noise_px, else noise_estimate_px
    encoder_resolution_rad: float  # quantisation step of the joint readings (0: not quantised; the largest step)
    encoder_noise_px: float  # pixel error the quantised readings cause (`encoder_noise_px`), both coordinates
    noise_xy_px: tuple  # the floor per coordinate (x, y): quantisation moves boards more in one direction
    ratio_to_noise: float  # rms_total_px / noise_px
    per_target: dict  # target -> {"rms_px": [x, y], "n_images"}
    per_head_posture: dict  # posture -> {"rms_px": [x, y], "n_images"}
    per_stance: list  # [{"target", "stance", "rms_px": [x, y], "n_images"}]
    per_image: list  # [{"image", "target", "stance", "head_posture", "rms_px": [x, y], "rms_total_px"}]


def _group_rms(residuals, image_of_row, keys):
    """{key: (rms_x, rms_y, n_images)} over the images whose key (per image) is `key`."""
    out = {}
    row_keys = keys[image_of_row]
    for key in dict.fromkeys(keys.tolist()):
        rows = row_keys == key
        out[key] = (rms(residuals[rows, 0]), rms(residuals[rows, 1]), int(np.sum(keys == key)))
    return out


def compare(result, *, pixel_noise_px: float | None = None, split: RigidSplit | None = None) -> Comparison:
    """Fit quality overall and by group, and the noise floor.

    The floor is what a correct model leaves: detector noise (the dataset's `pixel_noise_px` if given, else
    estimated from what no rigid board motion or camera term explains) combined with the error of quantised joint
    readings (their step found in the data), which moves whole boards and so is invisible to the estimate.
    """
    model, r = result.model, result.residuals_px
    data = model.data
    registry = result.registry
    n_nonrigid = sum(1 for n in registry.free_names if EFFECTS[registry.parameter(n).effect].non_rigid)
    estimate = noise_floor_estimate(model, result.values, r, n_nonrigid, split)
    if pixel_noise_px is not None and pixel_noise_px > 0:
        detector, source = float(pixel_noise_px), "dataset"
    else:
        detector, source = estimate, "estimated"
    still = np.ones(data.n_images, bool) if data.velocity is None else np.all(data.velocity == 0, axis=1)
    step, share = getattr(result, "reading_step_rad", None), getattr(result, "quantisation_share", float("nan"))
    if step is not None and np.any(step > 0) and np.isfinite(share):
        # the readings' step (whatever angles the fit chose) and the share of its full error the rigid residuals
        # show (solver.identify.quantisation_covariance): a servo standing at its step or at its command leaves
        # none, one anywhere in its step all of it; never more than the full error
        resolution = step
    else:
        resolution, share = reading_resolution(data.theta[still]), 1.0  # moving captures' angles: interpolated
    encoder_xy = encoder_noise_px(model, result.values, resolution) * math.sqrt(share)
    encoder = float(np.sqrt(np.mean(encoder_xy ** 2)))
    resolution = float(resolution.max())
    noise = float(math.hypot(detector, encoder))
    noise_xy = tuple(float(math.hypot(detector, e)) for e in encoder_xy)
    total = rms(r)
    per_image_rms = np.sqrt(per_image_sum(r ** 2, data.image_of_row, data.n_images)
                            / np.bincount(data.image_of_row, minlength=data.n_images)[:, None])
    stance_keys = np.array([f"{t}{s}" for t, s in zip(data.target, data.stance)])
    return Comparison(
        rms_px=tuple(float(v) for v in result.rms_px), rms_total_px=total, sigma_fit_px=result.sigma_px,
        noise_px=noise, noise_source=source, noise_estimate_px=estimate, detector_noise_px=detector,
        encoder_resolution_rad=resolution, encoder_noise_px=encoder, noise_xy_px=noise_xy,
        ratio_to_noise=total / noise if noise > 0 else float("inf"),
        per_target={t: {"rms_px": [x, y], "n_images": n}
                    for t, (x, y, n) in _group_rms(r, data.image_of_row, data.target).items()},
        per_head_posture={int(p): {"rms_px": [x, y], "n_images": n}
                          for p, (x, y, n) in sorted(_group_rms(r, data.image_of_row, data.head_posture).items())},
        per_stance=[{"target": str(data.target[m]), "stance": int(data.stance[m]), "rms_px": [x, y], "n_images": n}
                    for key, (x, y, n) in _group_rms(r, data.image_of_row, stance_keys).items()
                    for m in [int(np.flatnonzero(stance_keys == key)[0])]],
        per_image=[{"image": int(data.image_id[m]), "target": str(data.target[m]), "stance": int(data.stance[m]),
                    "head_posture": int(data.head_posture[m]), "rms_px": per_image_rms[m].tolist(),
                    "rms_total_px": float(np.sqrt(np.mean(per_image_rms[m] ** 2)))} for m in range(data.n_images)],
    )


# --------------------------------------------------------------------------------------------- names


@dataclass
class Candidate:
    """One candidate effect, scored against a fitted model. RMS values in px over both coordinates.

    predicted_values: parameter name -> predicted value (SI units of the registry) if the effect were added.
    uniqueness: |J~_k|^2 / |J_k|^2 over the effect's parameters (columns at their typical scale): the share of
    its signature the fitted model cannot already produce. 1: unique; near 0: indistinguishable with these data.
    """

    effect: str
    testable: bool
    reason: str = ""
    parameters: tuple = ()
    dof: int = 0
    delta_rss_px2: float = 0.0
    excess_rss_px2: float = float("nan")  # delta_rss_px2 minus what its parameters would fit of pure noise
    predicted_rms_px: float = float("nan")
    predicted_rms_xy_px: tuple = (float("nan"), float("nan"))
    predicted_values: dict = field(default_factory=dict)
    statistic: float = float("nan")
    p_value: float = float("nan")
    significant: bool = False
    uniqueness: float = float("nan")
    parameter_uniqueness: dict = field(default_factory=dict)
    plausible: bool = True
    implausible: list = field(default_factory=list)
    stand_in: bool = False  # low uniqueness and little of the misfit explained (STAND_IN_SHARE): not named
    no_signal: list = field(default_factory=list)  # parameters the data do not excite at all
    inside_model: list = field(default_factory=list)  # parameters the fitted model already contains (uniqueness 0)
    assumption: str = ""  # not an effect to add: an assumption of the model the candidate drops (ASSUMPTIONS)
    remedy: str = ""  # what to do when no model can drop the assumption (no command then); '' when a model can

    def as_dict(self) -> dict:
        return {
            "effect": self.effect, "predicted_rms_px": self.predicted_rms_px, "p_value": self.p_value,
            "significant": self.significant, "uniqueness": self.uniqueness, "testable": self.testable,
            "reason": self.reason, "dof": self.dof, "delta_rss_px2": self.delta_rss_px2,
            "excess_rss_px2": self.excess_rss_px2,
            "predicted_rms_xy_px": list(self.predicted_rms_xy_px), "statistic": self.statistic,
            "plausible": self.plausible, "implausible": self.implausible, "stand_in": self.stand_in,
            "no_signal": self.no_signal,
            "inside_model": self.inside_model, "assumption": self.assumption or None, "remedy": self.remedy or None,
            "predicted_values": self.predicted_values, "parameter_uniqueness": self.parameter_uniqueness,
        }


def candidate_effects(registry: Registry) -> tuple[str, ...]:
    """The effects the diagnostics can add to a model with `registry`."""
    return tuple(e for e in EXTRA_EFFECTS if e not in registry.effects)


def extended_registry(registry: Registry, effects) -> Registry:
    """`registry` plus `effects`, keeping its setup, ties and fixed parameters."""
    return registry.extended(effects)


def untestable_reason(effect: str, data: ModelData) -> str:
    """Why an effect cannot be tested on these data ('' if it can): the effect's own word."""
    return EFFECTS[effect].untestable_reason(data)


class _Extension:
    """The fitted model's Jacobian extended by candidate effects at zero, and its projection machinery."""

    def __init__(self, result, effects, clusters=None):
        base = result.registry
        self.registry = registry = extended_registry(base, effects)
        values = registry.from_dict(base.as_dict(result.values))
        model = Model(result.model.data, registry)
        r, J = model.evaluate(values)
        self.residual = r.reshape(-1)
        self.data = data = model.data
        self.clusters = clusters(data) if clusters else stance_clusters(data)
        self.scales = registry.scales[registry.free_index]
        self.J = registry.free_jacobian(J.reshape(len(self.residual), -1)) * self.scales  # scaled free columns
        effect_of = [registry.parameters[registry.index[n]].effect for n in registry.free_names]
        self.columns = {e: [i for i, x in enumerate(effect_of) if x == e] for e in registry.effects}
        base_columns = [i for i, n in enumerate(registry.free_names) if n in set(base.free_names)]
        self.Q = orthonormal_basis(self.J[:, base_columns])
        self.model, self.values = model, values


def rank_candidates(result, candidates=None, *, family_alpha: float = FAMILY_ALPHA,
                    clusters=stance_clusters) -> list[Candidate]:
    """Score test of every candidate effect not yet in the fitted model, best first.

    For candidate k with parameters beta_k (zero = absent): J_k = d r / d beta_k at the fit, J~_k = J_k with
    the fitted model's column space projected off (pivoted QR), dRSS_k = r^T J~_k (J~_k^T J~_k)^+ J~_k^T r,
    predicted beta_k = -(J~_k^T J~_k)^+ J~_k^T r (the other parameters re-adjust), predicted RMS =
    sqrt((RSS - dRSS_k) / n). Significance: `score_test` (per-image clustered, Hotelling T^2 / F) with a
    Bonferroni correction: significant when p < family_alpha / (number of candidates tested).
    Ranked by the misfit each would explain beyond what its parameters would fit of pure noise (dRSS_k minus the
    trace of its score's clustered variance): raw dRSS favours many-parameter candidates, which always fit some
    noise (12 elasticity parameters outran a real 40 ms time lag seen in 6 moving images of 137). Best first;
    candidates that cannot be tested come last, with the reason.
    """
    data = result.model.data
    if candidates is None:
        candidates = candidate_effects(result.registry) + candidate_assumptions(result.registry)
    candidates = tuple(candidates)
    assumptions = [c for c in candidates if c in ASSUMPTIONS]
    candidates = tuple(c for c in candidates if c not in ASSUMPTIONS)
    reasons = {e: untestable_reason(e, data) for e in candidates}
    testable = [e for e in candidates if not reasons[e]]
    out = [Candidate(e, False, reason=reasons[e]) for e in candidates if reasons[e]]
    ext = _Extension(result, testable, clusters)
    r = ext.residual
    rss = float(r @ r)
    free_names = ext.registry.free_names
    J_tilde = project_off(ext.Q, ext.J[:, [i for e in testable for i in ext.columns[e]]])
    offset = 0
    scored = []
    for effect in testable:
        cols = ext.columns[effect]
        Jk, Jt = ext.J[:, cols], J_tilde[:, offset:offset + len(cols)]
        offset += len(cols)
        candidate = _scored(Candidate(effect, True), [free_names[i] for i in cols], Jk, Jt, ext.scales[cols], ext,
                            rss)
        (scored if candidate.testable else out).append(candidate)
    for name in assumptions:
        candidate = ASSUMPTIONS[name].score(result, ext, rss)
        (scored if candidate.testable else out).append(candidate)
    threshold = family_alpha / max(len(scored), 1)
    for c in scored:
        c.significant = bool(np.isfinite(c.p_value) and c.p_value < threshold)
    scored.sort(key=lambda c: -c.excess_rss_px2)
    return scored + out


def _scored(candidate: Candidate, names, Jk, Jt, scales, ext, rss: float) -> Candidate:
    """`candidate` scored: the score test of the block Jk (its columns at their scales `scales`, named `names`),
    Jt the block projected off the fitted model (ext.Q), against the fit's residuals (ext.residual)."""
    r, n = ext.residual, len(ext.residual)
    effect = candidate.effect
    norm2, left2 = np.sum(Jk ** 2, axis=0), np.sum(Jt ** 2, axis=0)
    excited = norm2 > 1e-24 * max(norm2.max(initial=0.0), 1e-300)
    # A column the fitted model already contains (e.g. backlash of a joint always approached from one side
    # is a joint offset) leaves only rounding error after the projection: no information, not tested.
    live = excited & (left2 > RANK_TOLERANCE * norm2)
    candidate.parameters = tuple(names)
    candidate.no_signal = [nm for nm, ok in zip(names, excited) if not ok]
    candidate.inside_model = [nm for nm, e, ok in zip(names, excited, live) if e and not ok]
    if not np.any(live):
        candidate.testable = False
        candidate.reason = ("no signal in these data (" + _no_signal_hint(effect) + ")" if not np.any(excited)
                            else "these data cannot tell it from the model's parameters (uniqueness 0)")
        return candidate
    test = score_test(Jt[:, live], r, ext.clusters, Q=ext.Q)
    live_names = [nm for nm, ok in zip(names, live) if ok]
    live_scales = np.asarray(scales)[live]
    r_after = r + Jt[:, live] @ test.step
    candidate.dof = test.dof
    candidate.delta_rss_px2 = test.delta_rss
    candidate.excess_rss_px2 = test.delta_rss - test.noise_rss if np.isfinite(test.noise_rss) else test.delta_rss
    candidate.predicted_rms_px = float(np.sqrt(max(rss - test.delta_rss, 0.0) / n))
    candidate.predicted_rms_xy_px = (rms(r_after[0::2]), rms(r_after[1::2]))
    candidate.predicted_values = {nm: float(v) for nm, v in zip(live_names, test.step * live_scales)}
    candidate.statistic, candidate.p_value = test.statistic, test.p_value
    candidate.uniqueness = float(left2[excited].sum() / norm2[excited].sum())
    candidate.parameter_uniqueness = {nm: float(a / b) for nm, a, b in zip(live_names, left2[live], norm2[live])}
    std = np.nan_to_num(test.step_std * live_scales, nan=0.0) if test.step_std is not None else 0 * live_scales
    candidate.implausible = [nm for nm, v, sd in zip(live_names, test.step * live_scales, std)
                             if _implausible_value(candidate, nm, float(v), float(sd), ext.registry.setup)]
    candidate.stand_in = bool(candidate.uniqueness < LOW_UNIQUENESS and candidate.excess_rss_px2 < STAND_IN_SHARE * rss)
    candidate.plausible = not candidate.implausible and not candidate.stand_in
    return candidate


def _implausible_value(candidate: Candidate, name: str, value: float, std: float, setup) -> str:
    """Why a candidate's predicted value is not physics: its effect's word (an assumption's: the effect that owns
    the parameter it frees)."""
    effect = EFFECTS.get(candidate.effect) or owner_of(name, setup)
    return effect.implausibility(value, std, PLAUSIBLE_Z) if effect is not None else ""


# --------------------------------------------------------------------------------------------- assumptions


class SharedMotorTie:
    """The assumption that joints on one motor take one offset (the NAO's LHipYawPitch and RHipYawPitch: one
    motor, one sensor; Registry(tie_shared_motors=True), the default). Tested as a candidate that unties them: the
    block is d r / d (each follower's own offset) at the fit, the same score test as every effect's; significant
    means the data want the two offsets apart (a worn coupling, a team's separate calibration values)."""

    name = "untie_shared_motors"
    words = "joints on one motor take one offset"

    def applies(self, registry) -> bool:
        return registry.tie_shared_motors and any(p.tied_to for p in registry.parameters)

    def registry(self, registry) -> Registry:
        """The model without the assumption: every joint its own offset."""
        return registry.untied()

    def score(self, result, ext, rss: float) -> Candidate:
        base = result.registry
        untied = self.registry(base)
        values = untied.from_dict(base.as_dict(result.values))
        r, J = Model(result.model.data, untied).evaluate(values)
        followers = [p.name for p in base.parameters if p.tied_to]
        cols = [untied.free_names.index(n) for n in followers]
        scales = untied.scales[untied.free_index][cols]
        Jk = untied.free_jacobian(J.reshape(len(ext.residual), -1))[:, cols] * scales
        return _scored(Candidate(self.name, True, assumption=self.words), followers, Jk, project_off(ext.Q, Jk),
                       scales, ext, rss)


class RigidBoard:
    """The assumption that each board is flat and as printed: its vertices where the dataset's nominal positions
    (square size, layout) put them, in every image. Tested as a candidate that lets each board's shape change the
    same way in every image: stretched along each of its axes (a square size or a printer's scale off) and bowed
    out of its plane (a sandal bent, quadratic in the board's coordinates: along each side, twisted), 5 parameters
    per board, each the displacement (m) at the board's edge. The block is d r / d shape at the fit: the model's
    pixels per vertex displacement (differences of the model itself) times each shape's displacement field. Nothing
    in the model can take it up: the verdict names the board and what to measure."""

    name = "rigid_board"
    words = "each board is flat and as printed"
    SHAPES = ("stretch_long", "stretch_short", "bow_long", "bow_short", "twist")  # along its longer, shorter side
    SCALE_M = 1e-3  # a typical deformation at the board's edge
    # Below this at the board's edge no shape is worth acting on: a laser print's scale (0.1 %) and a square size
    # measured with callipers (0.1 mm) move a sandal's edge by about as much. Smaller shapes can still be
    # significant on many images (the realistic mock's exact boards show 0.04-0.07 mm: its renderer and detector
    # leave that much), so they are reported but do not make the verdict.
    MIN_ACTIONABLE_M = 2e-4
    STEP_M = 1e-6  # the difference step of the vertex positions

    def applies(self, registry) -> bool:
        return True

    def registry(self, registry) -> Registry:
        raise ValueError("no model parameter frees a board's shape")

    def score(self, result, ext, rss: float) -> Candidate:
        import copy

        data, registry = result.model.data, result.registry
        base = result.model.residuals(result.values)
        pixels_per_m = []  # (N, 2) per metre of vertex displacement along each axis of the frame it is attached to
        for axis in range(3):
            moved = copy.copy(data)
            moved.p_mount = data.p_mount + self.STEP_M * np.eye(3)[axis]
            pixels_per_m.append((Model(moved, registry).residuals(result.values) - base) / self.STEP_M)
        target_of_row = data.target[data.image_of_row]
        columns, names = [], []
        for target in dict.fromkeys(data.target.tolist()):
            rows = target_of_row == target
            fields = self._fields(data, rows)
            for shape, field_m in zip(self.SHAPES, fields):
                column = np.zeros_like(base)
                column[rows] = sum(pixels_per_m[k][rows] * field_m[:, k:k + 1] for k in range(3))
                columns.append(column.reshape(-1))
                names.append(f"board_shape.{target}.{shape}")
        scales = np.full(len(names), self.SCALE_M)
        Jk = np.column_stack(columns) * scales
        candidate = Candidate(self.name, True, assumption=self.words, remedy=self.REMEDY)
        candidate = _scored(candidate, names, Jk, project_off(ext.Q, Jk), scales, ext, rss)
        largest = max((abs(v) for v in candidate.predicted_values.values()), default=0.0)
        if candidate.testable and largest < self.MIN_ACTIONABLE_M:
            candidate.implausible = [f"too small to act on (every shape under {self.MIN_ACTIONABLE_M * 1e3:.1f} mm at "
                                     f"the board's edge: a print's or a measurement's tolerance)"]
            candidate.plausible = False
        return candidate

    REMEDY = ("measure the board: a stretch is its square size off (dataset.json targets.<target>.square_m), a bow "
              "a bent board (flatten or replace it); no model parameter takes it up")

    @staticmethod
    def _fields(data, rows) -> list:
        """(N_rows, 3) displacement of each row's vertex per metre of each shape at the board's edge, in the frame
        the target is attached to: the board's axes from its own vertices (principal axes; the normal the third)."""
        points = data.p_mount[rows]
        _, first = np.unique(data.vertex[rows], return_index=True)
        corners = points[first]
        centre = corners.mean(axis=0)
        _, _, axes = np.linalg.svd(corners - centre)
        e1, e2, normal = axes
        a, b = (points - centre) @ e1, (points - centre) @ e2
        a, b = a / max(np.abs(a).max(), 1e-9), b / max(np.abs(b).max(), 1e-9)  # -1..1 across the board
        return [a[:, None] * e1, b[:, None] * e2, (a ** 2)[:, None] * normal, (b ** 2)[:, None] * normal,
                (a * b)[:, None] * normal]


ASSUMPTIONS = {a.name: a for a in (SharedMotorTie(), RigidBoard())}


def candidate_assumptions(registry: Registry) -> tuple[str, ...]:
    """The assumptions of a model with `registry` that the diagnostics test (each as a candidate that drops it)."""
    return tuple(name for name, a in ASSUMPTIONS.items() if a.applies(registry))


def implausibility(result, name: str) -> str:
    """Why a fitted parameter's value is not physics ('' if it may be): its effect's word (a negative compliance, a
    play beyond any servo's), beyond PLAUSIBLE_Z of its standard deviations (Effect.implausibility)."""
    p = result.registry.parameter(name)
    std = float(result.std[result.registry.index[name]])
    return EFFECTS[p.effect].implausibility(result.value(name), std, PLAUSIBLE_Z)


def _no_signal_hint(effect: str) -> str:
    if effect in ASSUMPTIONS:  # e.g. the tie when only one leg's board was seen
        return "the data do not excite the parameters dropping it frees"
    return EFFECTS[effect].no_signal_hint


def significance_threshold(candidates, family_alpha: float = FAMILY_ALPHA) -> float:
    """The per-candidate p-value below which a candidate counts as significant."""
    return family_alpha / max(sum(1 for c in candidates if c.testable), 1)


# --------------------------------------------------------------------------------------------- locate


@dataclass
class Location:
    """Where the model fails. RMS values in px over both coordinates unless they say (x, y)."""

    worst_images: list  # [{"image", "target", "stance", "head_posture", "rms_total_px", "rigid_rms_px", ...}]
    worst_stances: list  # [{"target", "stance", "rms_total_px", "n_images"}]
    rigid_rms_px: float  # RMS of the rigid part of all residuals
    nonrigid_rms_px: float
    rigid_share: float  # share of the residual sum of squares that is rigid board motion
    per_image_split: list  # [{"image", "rigid_rms_px", "nonrigid_rms_px"}]
    boards: dict  # target -> {"rms_px": [x, y], "rigid_rms_px", "nonrigid_rms_px", "mean_px": [x, y], "share"}
    board_summary: str
    regressors: list  # [{"regressor", "kind", "explained_share", "p_value", "dof"}], most explaining first


def _regressor_blocks(data: ModelData, L_flat: np.ndarray, capture_time_s=None):
    """(name, kind, block (2N, d)) for every candidate regressor.

    Per-image regressors z (joint angle, gravity torque, approach direction, velocity, capture time) enter as a
    rigid board motion proportional to z (6 columns L_m z_m): what any joint-level error driven by z would do.
    A joint on the chains to some targets acts only on the images of those targets (a leg joint on its own
    board); a joint on a camera's chain on every image. Per-vertex regressors (image position, radius) enter as a
    residual proportional to the position (x with u, y with v) or a radial pattern.
    """
    image = np.repeat(data.image_of_row, 2)
    blocks = []
    robot = data.robot
    targets_of_joint = {}
    for t in np.unique(data.target):
        for joint in robot.target_chain(t).joint_names:
            targets_of_joint.setdefault(joint, set()).add(t)
    on_cameras = {j for c in np.unique(data.camera) for j in robot.camera_chain(c).joint_names}

    def per_image(name, z, own=None):
        z = np.asarray(z, dtype=float).copy()
        if own is not None:
            z[~np.isin(data.target, list(own))] = 0.0
        if np.ptp(z) > 0:
            blocks.append((name, "image", L_flat * z[image][:, None]))

    for c, joint in enumerate(data.joints):
        own = None if joint in on_cameras else targets_of_joint.get(joint)
        if own is None and joint not in on_cameras:
            continue  # on no chain of these data: it moves nothing
        per_image(f"angle {joint}", data.theta[:, c], own)
        if own is not None:
            per_image(f"gravity torque {joint}", data.tau[:, c], own)
        per_image(f"approach direction {joint}", data.direction[:, c], own)
        if data.velocity is not None:
            per_image(f"velocity {joint}", data.velocity[:, c], own)
    times = np.asarray(capture_time_s if capture_time_s is not None else data.image_id, dtype=float)
    per_image("capture time" if capture_time_s is not None else "capture order", times - times.min())

    camera_of_row = data.camera[data.image_of_row]
    prior = {c: data.cameras[c] for c in np.unique(data.camera)}
    of_row = lambda key: np.array([prior[c][key] for c in camera_of_row], dtype=float)  # noqa: E731
    du = data.uv_px[:, 0] - of_row("cx_px")
    dv = data.uv_px[:, 1] - of_row("cy_px")
    zeros = np.zeros_like(du)
    for name, d in (("image position u", du), ("image position v", dv)):
        blocks.append((name, "vertex", np.column_stack([np.column_stack([d, zeros]).reshape(-1),
                                                        np.column_stack([zeros, d]).reshape(-1)])))
    rho2 = (du / of_row("fx_px")) ** 2 + (dv / of_row("fy_px")) ** 2
    blocks.append(("image radius", "vertex", np.column_stack([du * rho2, dv * rho2]).reshape(-1, 1)))
    return blocks


def locate(result, *, capture_time_s=None, worst: int = 5, split: RigidSplit | None = None) -> Location:
    """The worst images and stances, rigid / non-rigid split, left against right board, regressor scan.

    capture_time_s : (M,) capture time of each image of `result.model.data` (default: the capture order).
    The regressor scan reports, for each regressor, the share of the residual sum of squares that a board motion
    proportional to it would remove beyond the fitted model and a constant board motion per leg, with the p-value
    of the same clustered test the candidate ranking uses (no multiple-test correction: a map, not a verdict).
    """
    model, r = result.model, result.residuals_px
    data = model.data
    split = split or RigidSplit(model, result.values)
    rigid, nonrigid = split(r)
    counts = np.bincount(data.image_of_row, minlength=data.n_images)
    ms = lambda a: per_image_sum(np.sum(a ** 2, axis=1), data.image_of_row, data.n_images) / (2 * counts)  # noqa
    total_ms, rigid_ms, nonrigid_ms = ms(r), ms(rigid), ms(nonrigid)
    per_image = [{"image": int(data.image_id[m]), "target": str(data.target[m]), "stance": int(data.stance[m]),
                  "head_posture": int(data.head_posture[m]), "rms_total_px": float(np.sqrt(total_ms[m])),
                  "rigid_rms_px": float(np.sqrt(rigid_ms[m])), "nonrigid_rms_px": float(np.sqrt(nonrigid_ms[m]))}
                 for m in range(data.n_images)]
    stances = {}
    for m, entry in enumerate(per_image):
        s = stances.setdefault((entry["target"], entry["stance"]), [0.0, 0])
        s[0] += total_ms[m] * counts[m]
        s[1] += counts[m]
    stance_rows = [{"target": t, "stance": st, "rms_total_px": float(np.sqrt(a / n)),
                    "n_images": int(sum(1 for e in per_image if (e["target"], e["stance"]) == (t, st)))}
                   for (t, st), (a, n) in stances.items()]
    rss = float(np.sum(r ** 2))
    boards = {}
    for target in dict.fromkeys(data.target.tolist()):
        rows = np.isin(data.image_of_row, np.flatnonzero(data.target == target))
        if rows.any():
            boards[target] = {"rms_px": [rms(r[rows, 0]), rms(r[rows, 1])], "rms_total_px": rms(r[rows]),
                           "rigid_rms_px": rms(rigid[rows]), "nonrigid_rms_px": rms(nonrigid[rows]),
                           "mean_px": r[rows].mean(axis=0).tolist(),
                           "share": float(np.sum(r[rows] ** 2) / rss) if rss > 0 else 0.0}
    return Location(
        worst_images=sorted(per_image, key=lambda e: -e["rms_total_px"])[:worst],
        worst_stances=sorted(stance_rows, key=lambda e: -e["rms_total_px"])[:worst],
        rigid_rms_px=rms(rigid), nonrigid_rms_px=rms(nonrigid),
        rigid_share=float(np.sum(rigid ** 2) / rss) if rss > 0 else 0.0,
        per_image_split=[{k: e[k] for k in ("image", "rigid_rms_px", "nonrigid_rms_px")} for e in per_image],
        boards=boards, board_summary=_board_summary(boards),
        regressors=regressor_scan(result, split, capture_time_s),
    )


def _board_summary(boards: dict) -> str:
    if len(boards) < 2:
        return "only one board in the data: boards cannot be compared"
    ranked = sorted(boards.items(), key=lambda kv: -kv[1]["rms_total_px"])
    (a, ea), (_, eb) = ranked[0], ranked[-1]
    if ea["rms_total_px"] > 1.5 * eb["rms_total_px"]:
        return (f"the {a} board fits worse ({ea['rms_total_px']:.2f} px against {eb['rms_total_px']:.2f} px): "
                f"look at the chain that carries it (its joints, play, elasticity, link lengths, board mount)")
    listed = ", ".join(f"{e['rms_total_px']:.2f} px {t}" for t, e in boards.items())
    alike = "both boards" if len(boards) == 2 else "the boards"
    return (f"{alike} fit alike ({listed}): a common cause (head, camera, time lag) or an effect present on every "
            "chain")


def regressor_scan(result, split: RigidSplit, capture_time_s=None) -> list[dict]:
    """Share of the misfit explained by a board motion proportional to each regressor (see `locate`)."""
    data = result.model.data
    r = result.residuals_px.reshape(-1)
    rss = float(r @ r)
    registry = result.registry
    J = registry.free_jacobian(result.model.evaluate(result.values)[1].reshape(len(r), -1))
    J = J * registry.scales[registry.free_index]
    L_flat = split.twist_columns.reshape(len(r), 6)
    constant = [L_flat * np.repeat((data.target == t)[data.image_of_row], 2)[:, None] for t in np.unique(data.target)]
    Q = orthonormal_basis(np.hstack([J] + constant))
    clusters = stance_clusters(data)
    out = []
    for name, kind, block in _regressor_blocks(data, L_flat, capture_time_s):
        test = score_test(project_off(Q, block), r, clusters, Q=Q)
        if test.dof == 0:
            continue
        out.append({"regressor": name, "kind": kind, "explained_share": test.delta_rss / rss if rss > 0 else 0.0,
                    "p_value": test.p_value, "dof": test.dof})
    out.sort(key=lambda e: -e["explained_share"])
    return out


def apparent_errors(result, names, residuals=None) -> np.ndarray:
    """(M, len(names)): the value of each parameter that best explains each image's residual on its own.

    `names` are parameter names of the fitted model or of any effect it could add (e.g. 'joint_offset.RKneePitch',
    'head_offset.HeadYaw', 'link_length.L.thigh'); residuals default to the fit's. Images the parameter does not
    affect get NaN. Plotted against a regressor (a joint's gravity torque, approach direction or velocity) the
    apparent joint offset shows a missing joint-level effect as a line or two clusters.
    """
    data = result.model.data
    setup = result.registry.setup
    owners = []
    for name in names:
        owner = owner_of(name, setup)
        if owner is None:
            raise ValueError(f"no effect has a parameter {name!r} for these data")
        owners.append(owner.name)
    ext_registry = result.registry.extended(tuple(dict.fromkeys(owners)))
    J = Model(data, ext_registry).evaluate(ext_registry.from_dict(result.registry.as_dict(result.values)))[1]
    r = result.residuals_px if residuals is None else residuals
    out = np.full((data.n_images, len(names)), np.nan)
    for k, name in enumerate(names):
        column = J[:, :, ext_registry.index[name]]
        num = per_image_sum(np.sum(column * r, axis=1), data.image_of_row, data.n_images)
        den = per_image_sum(np.sum(column ** 2, axis=1), data.image_of_row, data.n_images)
        ok = den > 1e-12 * max(den.max(initial=0.0), 1e-300)
        out[ok, k] = -num[ok] / den[ok]  # residual = predicted - detected: the change that removes it
    return out


def partial_residuals(result, names) -> np.ndarray:
    """(N, 2) px: residuals of the fitted model with the parameters `names` (or a whole effect) set to zero.

    What those parameters explain plus what nothing explains: the partial-residual view of one model term.
    Switch off one joint's parameter at a time to see that joint's term alone.
    """
    names = [names] if isinstance(names, str) else list(names)
    values = result.values.copy()
    for p in result.registry.parameters:
        if p.name in names or p.effect in names:
            values[result.registry.index[p.name]] = 0.0
    return result.model.residuals(values)


# --------------------------------------------------------------------------------------------- the loop


@dataclass
class Diagnosis:
    """compare + locate + names for one fitted model."""

    result: object  # IdentificationResult
    comparison: Comparison
    location: Location
    candidates: list  # [Candidate], best first
    threshold: float  # p-value below which a candidate is significant

    def as_dict(self) -> dict:
        c, loc, res = self.comparison, self.location, self.result
        return {
            "rms_px": list(c.rms_px), "noise_px": c.noise_px,
            "candidates": [cand.as_dict() for cand in self.candidates],
            "effects": list(res.registry.extra_effects()),
            "rms_total_px": c.rms_total_px, "sigma_fit_px": c.sigma_fit_px, "noise_source": c.noise_source,
            "noise_estimate_px": c.noise_estimate_px, "detector_noise_px": c.detector_noise_px,
            "encoder_resolution_rad": c.encoder_resolution_rad, "encoder_noise_px": c.encoder_noise_px,
            "noise_xy_px": list(c.noise_xy_px),
            "ratio_to_noise": c.ratio_to_noise,
            "significance_threshold": self.threshold, "n_vertices": int(res.model.data.n_rows),
            "n_images": int(res.model.data.n_images),
            "compare": {"per_target": c.per_target,
                        "per_head_posture": {str(k): v for k, v in c.per_head_posture.items()},
                        "per_stance": c.per_stance, "per_image": c.per_image},
            "locate": {"worst_images": loc.worst_images, "worst_stances": loc.worst_stances,
                       "rigid_rms_px": loc.rigid_rms_px, "nonrigid_rms_px": loc.nonrigid_rms_px,
                       "rigid_share": loc.rigid_share, "boards": loc.boards, "board_summary": loc.board_summary,
                       "regressors": loc.regressors, "per_image_split": loc.per_image_split},
            "parameters": res.parameters_dict(), "warnings": list(res.warnings),
        }


def diagnose_result(result, *, pixel_noise_px=None, capture_time_s=None,
                    family_alpha: float = FAMILY_ALPHA) -> Diagnosis:
    """compare, locate and names for a fitted model."""
    split = RigidSplit(result.model, result.values)
    candidates = rank_candidates(result, family_alpha=family_alpha)
    return Diagnosis(result, compare(result, pixel_noise_px=pixel_noise_px, split=split),
                     locate(result, capture_time_s=capture_time_s, split=split), candidates,
                     significance_threshold(candidates, family_alpha))


@dataclass
class SelectionStep:
    """One step of forward selection: the model, its fit, its cross-validated RMS and the ranking it leaves."""

    effects: tuple  # extra effects in the model
    result: object  # IdentificationResult
    cv_rms_px: tuple | None  # (x, y) held-out RMS, whole stances held out
    candidates: list  # [Candidate] ranked against this fit
    added: str | None = None  # the effect added to reach this step
    notes: list = field(default_factory=list)


def forward_selection(data: ModelData, registry: Registry | None = None, *, max_steps: int = 4,
                      family_alpha: float = FAMILY_ALPHA, cv_folds: int = 5, seed: int = 0) -> list[SelectionStep]:
    """Stepwise forward selection: add the best significant, plausible candidate, refit, rank again.

    After each addition, every effect added earlier is tested for removal (the same score test, on the model
    without it): when two effects are missing, a many-parameter effect can first stand in for both and become
    superfluous once they are in; it is then dropped. Stops when no candidate is significant and plausible,
    after `max_steps` additions, or when an addition does not lower the cross-validated RMS (whole stances held
    out; that addition is then reported, not kept). Each step notes new parameters that are not clearly
    determined (|value| / std < 3) or correlate with another parameter above 0.95.
    """
    from naocal.solver.crossval import grouped_cv_rms
    from naocal.solver.identify import identify

    registry = registry or Registry.for_data(data)
    given = _extra(registry)
    cv = (lambda reg: grouped_cv_rms(data, reg, cv_folds, seed)) if cv_folds and cv_folds > 1 else (lambda reg: None)
    result = identify(data, registry)
    steps = [SelectionStep(_extra(registry), result, cv(registry), rank_candidates(result, family_alpha=family_alpha))]
    tried = set()
    for _ in range(max_steps):
        last = steps[-1]
        choice = next((c for c in last.candidates if c.significant and c.plausible and not c.remedy
                       and c.effect not in tried), None)
        if choice is None:
            last.notes.append("no significant, plausible candidate left: stop")
            break
        tried.add(choice.effect)
        new_registry = registry_with(registry, choice)
        result = identify(data, new_registry)
        if not result.success:
            last.notes.append(f"adding {choice.effect}: the solve did not converge ({result.message}): stop")
            break
        notes = new_parameter_notes(result, choice.effect)
        for earlier in [e for e in _extra(new_registry) if e not in given and e != choice.effect]:
            without = _without(new_registry, earlier)
            reduced = identify(data, without)
            test = rank_candidates(reduced, [earlier], family_alpha=family_alpha)[0]
            if reduced.success and not test.significant:
                notes.append(f"dropped {earlier}: with {choice.effect} in the model it no longer explains anything "
                             f"significant (p = {test.p_value:.2g})")
                new_registry, result = without, reduced
        cv_rms = cv(new_registry)
        if cv_rms is not None and last.cv_rms_px is not None and rms(cv_rms) >= rms(last.cv_rms_px):
            last.notes.append(f"adding {choice.effect} does not lower the cross-validated RMS "
                              f"({rms(cv_rms):.3f} px against {rms(last.cv_rms_px):.3f} px): not kept; stop")
            break
        registry = new_registry
        steps.append(SelectionStep(_extra(registry), result, cv_rms,
                                   rank_candidates(result, family_alpha=family_alpha), added=choice.effect,
                                   notes=notes))
    return steps


def _without(registry: Registry, effect: str) -> Registry:
    return registry.without(effect)


def registry_with(registry: Registry, candidate: Candidate) -> Registry:
    """`registry` plus the candidate's effect, its parameters that the data cannot tell from the model fixed (an
    assumption's candidate: the model without the assumption)."""
    if candidate.effect in ASSUMPTIONS:
        return ASSUMPTIONS[candidate.effect].registry(registry)
    extended = registry.extended((candidate.effect,))
    return extended.with_fixed(candidate.inside_model) if candidate.inside_model else extended


def _extra(registry: Registry) -> tuple:
    return registry.extra_effects()


def new_parameter_notes(result, effect: str, min_ratio: float = 3.0, max_correlation: float = 0.95) -> list[str]:
    """Warnings about an added effect's parameters: poorly determined, or tied up with another parameter."""
    registry = result.registry
    notes = []
    free = list(registry.free_names)
    C = np.nan_to_num(result.correlation)
    for p in registry.parameters:
        if p.effect != effect or p.name not in registry.free_names:
            continue
        value, std = result.value(p.name), float(result.std[registry.index[p.name]])
        if std > 0 and abs(value) / std < min_ratio:
            notes.append(f"{p.name} = {value:.4g} {p.unit} is within {min_ratio:g} std ({std:.2g}) of zero")
        i = free.index(p.name)
        j = int(np.argmax(np.where(np.arange(len(free)) == i, 0.0, np.abs(C[i]))))
        if abs(C[i, j]) > max_correlation:
            notes.append(f"{p.name} correlates {C[i, j]:+.3f} with {free[j]}: these data hardly tell them apart")
    return notes
