"""The mission's loop on the Duckiebot (issue 23): compare the joint fit with the drive, see where it fails, name the
missing effect, add it, watch the error fall. The engine of `naocal diagnose LOG` for a drive log (the verb:
kinds.duckiebot.diagnose).

- compare: the fit's corner RMS against the noise floor (what the detector's noise alone leaves: the corners'
  expected noise, identify.py's model), whitened (1 at the floor) and in pixels;
- locate: the RMS of the frames by the drive phase before them (turning or straight, by duty);
- name: a score test per wheel effect not in the model (fit.EFFECTS: the registry's, solver/effects/), the one engine of
  solver.scoretest: the effect's Jacobian columns at the fit, projected off the fitted model's, against the
  whitened residuals, the variance clustered by frame (what a frame's corners share: its pose), leverage-corrected;
  significant below solver.diagnostics.FAMILY_ALPHA over the number of tests (Bonferroni); the significant ones
  ranked by what they explain beyond what they would fit of noise alone. The lens is judged by the lens fits
  (kinds.duckiebot.intrinsics: held-out board error per model): a lens model whose held-out error is below the
  model in use by more than LENS_RATIO names "the wrong lens model", and comes first (a camera that is wrong bends
  every marker, and every wheel test with it). Duckietown's wheel driver (fit.PWM_DRIVER: the motors get the
  floored PWM, not the duty logged) has no parameter to score: it is judged by its refit, a likelihood ratio of
  the two models (driver_test);
- add: the named effect (or lens) refitted, the RMS before and after.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from naocal.kinds.duckiebot.fit import (ALL_EFFECTS, EFFECT_START, EFFECTS, KINEMATIC, PWM_DRIVER, Drive,
                                        DriveEquations, DriveFit, fit_drive, parameter_scales)
from naocal.solver.diagnostics import FAMILY_ALPHA
from naocal.solver.errors import NaocalError, SolveError
from naocal.solver.scoretest import orthonormal_basis, project_off, score_test

# The lens in use is wrong when another model's held-out board error is below its own by this factor or more: a
# model that fits the lens leaves the detector's noise on views it was not fitted to, one that cannot follow it
# leaves its shape error too (a plumb_bob on a 150-degree fisheye: 3-10 x; on a plumb_bob lens the richer models'
# held-out errors are within 20 % of plumb_bob's, as their extra terms fit noise: docs/DUCKIEBOT.md).
LENS_RATIO = 1.5
# Far from the floor (whitened RMS above this) the base fit can be far from any true model (a hidden slip of 0.3
# s/m on seed 3's robot: baseline 0.057 m, RMS 10.8 px) and a score test, local, can miss the effect or rank a
# stand-in first: every candidate is then refitted, and one whose refit divides the RSS by FAR_RSS_RATIO or more is
# named (a likelihood-ratio decision; a clean log never gets here).
FAR_FROM_FLOOR = 3.0
FAR_RSS_RATIO = 4.0
DUTY_BINS = (0.0, 0.2, 0.35, 1.0)  # the locate table's duty classes (|duty| of the faster wheel)


@dataclass
class EffectTest:
    """One candidate effect's score test against the fitted model (whitened residuals: 1 = the expected noise)."""

    effect: str
    parameters: tuple
    dof: int = 0
    delta_rss: float = 0.0  # predicted drop of the whitened RSS
    excess_rss: float = float("nan")  # delta_rss less what its parameters would fit of noise alone
    statistic: float = float("nan")  # Hotelling T^2 of the cluster-robust test
    p_value: float = 1.0
    significant: bool = False
    uniqueness: float = float("nan")  # share of its signature the fitted model cannot already produce
    predicted_rms_px: float = float("nan")
    predicted_values: dict = field(default_factory=dict)
    refit_rms_px: float = float("nan")  # the RMS the model with it leaves (significant ones, when refitted)
    refit_whitened_rss: float = float("nan")  # the same refit's whitened RSS (the ranking's: rank_key)
    confirmed_by_refit: bool = False  # far from the floor, named by its refit (FAR_FROM_FLOOR), not its score
    refit_error: str = ""  # why its refit could not be made (undetermined, or did not converge): not a remedy

    def as_dict(self) -> dict:
        return dict(self.__dict__, parameters=list(self.parameters))


@dataclass
class LensVerdict:
    in_use: str
    best: str
    held_out_rms_px: dict  # model -> held-out board RMS, px
    ratio: float  # in use / best
    wrong: bool

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class EncoderEvidence:
    """Each wheel's turn from encoders.csv against the fitted model's ground travel of that wheel (encoder_evidence),
    by phase: {"straight"|"curving"|"in place": {"segments", "encoder_rad": [l, r], "model_rad": [l, r], "ratio": [l, r],
    "both": f, "tolerance": f}}; `slip` (the wheels turn more than the ground moves in turns than straight) and
    `radius_ratio` (straight: encoder over model, both wheels; None without straight drives) decide `verdict`."""

    phases: dict
    slip: bool
    radius_ratio: float | None
    radius_off: bool
    verdict: str

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class DriveDiagnosis:
    effects: tuple  # in the model
    lens: str  # the lens model the corners were rectified with
    fit: DriveFit | None  # None: the model in use cannot be fitted (fit_error), only the lens is judged
    rms_px: float
    floor_px: float  # the corners' expected noise, RMS
    whitened_rms: float  # residual / expected noise, RMS: 1 at the floor
    phases: list  # [{"phase", "frames", "corners", "rms_px"}]
    tests: list  # [EffectTest], best first
    threshold: float
    lens_verdict: LensVerdict | None = None
    after: dict | None = None  # refit_summary of the refit with the named one added
    fit_error: str = ""  # why the model in use could not be fitted (then fit is None)
    encoders: EncoderEvidence | None = None  # None: the log has no encoders.csv (or no fit)

    @property
    def named(self) -> str | None:
        """What to add: 'lens=<model>' for the wrong lens model, else the best significant effect, else None."""
        if self.lens_verdict is not None and self.lens_verdict.wrong:
            return f"lens={self.lens_verdict.best}"
        return next((t.effect for t in self.tests if t.significant), None)

    def as_dict(self) -> dict:
        return {"effects": list(self.effects), "lens": self.lens, "rms_px": self.rms_px, "floor_px": self.floor_px,
                "whitened_rms": self.whitened_rms, "phases": self.phases,
                "tests": [t.as_dict() for t in self.tests], "threshold": self.threshold,
                "lens_verdict": None if self.lens_verdict is None else self.lens_verdict.as_dict(),
                "named": self.named, "after": self.after, "fit_error": self.fit_error,
                "encoders": None if self.encoders is None else self.encoders.as_dict(),
                "parameters": None if self.fit is None else self.fit.parameters_dict()}


def floor_and_whitened(fit: DriveFit) -> tuple[float, float]:
    """(the corners' expected noise RMS px, the whitened residual RMS) of a fit."""
    sigma = fit.sightings.sigma_px
    return (float(np.sqrt(np.mean(sigma ** 2))),
            float(np.sqrt(np.mean((fit.residuals_px / sigma[:, None]) ** 2))))


def score_effects(drive: Drive, fit: DriveFit, K, marker_size_m: float, candidates) -> list[EffectTest]:
    """A score test (solver.scoretest.score_test) per candidate effect of fit.EFFECTS not in the fit, clustered by
    frame."""
    drive = replace(drive, pwm_driver=fit.pwm_driver)  # the model fitted
    extra = [n for e in candidates for n in EFFECTS[e] if n not in fit.names]
    names = list(fit.names) + extra
    # each taken where a fit of it starts (fit.EFFECT_START: a wheel lag's signature vanishes at 0); any fixed
    # direction is a valid test of "no such effect"
    x = np.concatenate([fit.x, [EFFECT_START.get(n, 0.0) for n in extra]])
    free = np.concatenate([fit.free, np.zeros(len(extra), bool)])
    equations = DriveEquations(drive, fit.sightings, K, marker_size_m, fit.reference_marker, names, x, free)
    uv, Jx = equations.predict(x)
    w = equations.inverse_sigma
    base_uv = uv
    if extra:  # the residuals at the fit itself (a start value off 0 moves the prediction)
        base_uv, _ = equations.predict(np.concatenate([fit.x, np.zeros(len(extra))]), jacobian=False)
    r = ((base_uv - fit.sightings.uv_px) * w[:, None]).reshape(-1)
    scales = parameter_scales(names)
    J = (Jx * w[:, None, None] * scales).reshape(-1, len(names))
    Q = orthonormal_basis(J[:, free])
    element_frame = np.repeat(equations.row_frame, 2)
    order = np.argsort(element_frame, kind="stable")
    clusters = np.split(order, np.flatnonzero(np.diff(element_frame[order])) + 1)
    sigma_flat = np.repeat(fit.sightings.sigma_px, 2)
    tests = []
    for effect in candidates:
        cols = [names.index(n) for n in EFFECTS[effect]]
        Jk = J[:, cols]
        Jt = project_off(Q, Jk)
        total = float(np.sum(Jk ** 2))
        test = EffectTest(effect, EFFECTS[effect], uniqueness=float(np.sum(Jt ** 2) / total) if total > 0 else 0.0)
        st = score_test(Jt, r, clusters, Q)
        if st.dof > 0 and np.isfinite(st.p_value):
            step = np.linalg.lstsq(Jt, r, rcond=None)[0]
            after = (r - Jt @ step) * sigma_flat
            test.dof, test.delta_rss, test.statistic, test.p_value = st.dof, st.delta_rss, st.statistic, st.p_value
            test.excess_rss = st.delta_rss - st.noise_rss
            test.predicted_rms_px = float(np.sqrt(np.mean(after ** 2)))
            if not any(EFFECT_START.get(n) for n in EFFECTS[effect]):  # else a step from the start, not a value
                test.predicted_values = {n: float(-s * scales[c]) for n, s, c in zip(EFFECTS[effect], step, cols)}
        tests.append(test)
    threshold = FAMILY_ALPHA / max(1, sum(1 for t in tests if t.dof > 0))
    for t in tests:
        t.significant = t.dof > 0 and t.p_value < threshold
    tests.sort(key=lambda t: (not t.significant, -(t.excess_rss if np.isfinite(t.excess_rss) else -np.inf)))
    return tests, threshold


def whitened_rss(fit: DriveFit) -> float:
    return float(np.sum((fit.residuals_px / fit.sightings.sigma_px[:, None]) ** 2))


def rank_key(t: EffectTest):
    """Significant tests first, by their refit's Akaike criterion (whitened RSS + 2 per parameter added: the
    driver, which adds none, is preferred to a dead zone that fits the same offset no better), then the others."""
    return (not t.significant, t.refit_whitened_rss + 2 * len(t.parameters) if t.significant else 0.0)


def driver_test(fit: DriveFit, with_driver: DriveFit) -> EffectTest:
    """Duckietown's wheel driver (fit.PWM_DRIVER) judged by its refit `with_driver`, both models with the same
    parameters: the drop of the whitened RSS, over the refit's residual variance (at least 1: the expected noise,
    so that a fit above the floor, e.g. a rendered log's detector bias, needs a larger drop), against chi-square
    with 1 dof (the choice counted as a parameter: conservative). A drive without the driver's floor fits worse
    with it (the floor moves every duty off the one sent), so the drop is negative there."""
    from scipy.stats import chi2

    before, after = whitened_rss(fit), whitened_rss(with_driver)
    variance = max(1.0, after / max(1, with_driver.residuals_px.size - int(with_driver.free.sum())))
    statistic = (before - after) / variance
    return EffectTest(PWM_DRIVER, (), dof=1, delta_rss=before - after, excess_rss=statistic - 1.0,
                      statistic=statistic, p_value=float(chi2.sf(statistic, 1)) if statistic > 0 else 1.0,
                      uniqueness=1.0, predicted_rms_px=with_driver.rms_px, refit_rms_px=with_driver.rms_px,
                      refit_whitened_rss=after)


def phase_table(drive: Drive, fit: DriveFit) -> list[dict]:
    """The fit's corner RMS (px) by the phase of the drive before each frame: the last command that moved the robot
    (turning: the wheels' duties differ; straight: alike), by the faster wheel's |duty| (DUTY_BINS)."""
    obs, residual = fit.sightings, fit.residuals_px
    groups = {}
    for frame in np.unique(obs.frame):
        t = drive.frame_t_s[frame]
        rows = np.flatnonzero((drive.wheel_t_s < t) & ((drive.left_duty != 0) | (drive.right_duty != 0)))
        if not len(rows):
            key = "before any motion"
        else:
            u_l, u_r = drive.left_duty[rows[-1]], drive.right_duty[rows[-1]]
            duty = max(abs(u_l), abs(u_r))
            b = int(np.clip(np.searchsorted(DUTY_BINS, duty, side="right") - 1, 0, len(DUTY_BINS) - 2))
            kind = "straight" if u_l == u_r else "turning"
            key = f"{kind}, |duty| {DUTY_BINS[b]:.2f}-{DUTY_BINS[b + 1]:.2f}"
        groups.setdefault(key, []).append(frame)
    table = []
    for key, frames in sorted(groups.items()):
        rows = np.isin(obs.frame, frames)
        table.append({"phase": key, "frames": len(frames), "corners": int(rows.sum()),
                      "rms_px": float(np.sqrt(np.mean(residual[rows] ** 2)))})
    return table


def lens_verdict(lens_fits: dict, in_use: str) -> LensVerdict:
    """Whether the lens model in use is the wrong one: another's held-out error below it by LENS_RATIO."""
    held = {m: float(f.held_out_rms_px) for m, f in lens_fits.items()}
    best = min(held, key=held.get)
    ratio = held[in_use] / held[best] if held[best] > 0 else float("inf")
    return LensVerdict(in_use, best, held, ratio, best != in_use and ratio >= LENS_RATIO)


def diagnose_fit(drive: Drive, fit: DriveFit, K, marker_size_m: float, effects=(), lens: str = "",
                 lens_fits: dict | None = None, refit=None) -> DriveDiagnosis:
    """Compare, locate and name (module docstring) for a fitted model with `effects`. `refit(effects)`: the fit
    with other effects (a DriveFit); given, each significant candidate is refitted and they are ranked by what
    their refits leave (rank_key; the score test screens, the refit confirms: far from the floor a one-step prediction can
    rank a stand-in first), and the best's refit is DriveDiagnosis.after."""
    effects = tuple(effects)
    candidates = [e for e in EFFECTS if e not in effects]
    tests, threshold = score_effects(drive, fit, K, marker_size_m, candidates)
    refits = {}
    if refit is not None and PWM_DRIVER not in effects:  # no score without a parameter: judged by its refit
        try:
            refits[PWM_DRIVER] = refit(tuple(e for e in ALL_EFFECTS if e in effects + (PWM_DRIVER,)))
        except SolveError:
            pass
        if PWM_DRIVER in refits and refits[PWM_DRIVER].success:
            tests.append(driver_test(fit, refits[PWM_DRIVER]))
            threshold = FAMILY_ALPHA / sum(1 for t in tests if t.dof > 0)
            for t in tests:
                t.significant = t.dof > 0 and t.p_value < threshold
    floor, whitened = floor_and_whitened(fit)
    verdict = lens_verdict(lens_fits, lens) if lens_fits and lens in lens_fits else None
    diagnosis = DriveDiagnosis(effects, lens, fit, fit.rms_px, floor, whitened, phase_table(drive, fit), tests,
                               threshold, verdict)
    if refit is None or (verdict is not None and verdict.wrong):
        return diagnosis
    far = whitened > FAR_FROM_FLOOR
    for t in tests:
        if t.effect in refits or not (t.significant or (far and t.dof > 0)):
            continue
        try:
            result = refit(tuple(e for e in ALL_EFFECTS if e in effects + (t.effect,)))
            t.refit_error = refit_failure(result)
        except SolveError as err:  # the data cannot determine it beside the model: not a remedy
            t.refit_error = str(err)
        if t.refit_error:
            t.significant = False
            continue
        refits[t.effect], t.refit_rms_px, t.refit_whitened_rss = result, result.rms_px, whitened_rss(result)
        if far and not t.significant and (fit.rms_px / result.rms_px) ** 2 >= FAR_RSS_RATIO:
            t.significant, t.confirmed_by_refit = True, True
    tests.sort(key=rank_key)
    if diagnosis.named is not None:
        diagnosis.after = refit_summary(refits[diagnosis.named], effects + (diagnosis.named,))
    return diagnosis


def refit_failure(fit: DriveFit) -> str:
    """Why a fit is no model to compare ('' when it converged)."""
    return "" if fit.success else (f"did not converge ({fit.message}; RMS {fit.rms_px:.3f} px after "
                                   f"{fit.iterations} Jacobians)")


def refit_summary(refit: DriveFit, effects) -> dict:
    """The refit with `effects` (the named one added): its RMS, floor and the added parameters' values; only
    {"added", "error"} when it did not converge (an RMS it stopped at is no error level to compare)."""
    if refit_failure(refit):
        return {"added": list(effects), "error": refit_failure(refit)}
    floor, whitened = floor_and_whitened(refit)
    return {"added": [e for e in effects], "rms_px": refit.rms_px, "whitened_rms": whitened, "floor_px": floor,
            "values": {n: {"value": refit.value(n), "std": refit.stdev(n)} for e in effects for n in EFFECTS.get(e, ())}}


# ------------------------------------------------------------------------------------------------ encoders

# The wheels' turn from the encoders and the model's ground travel agree within this share on a sound robot: the
# model's own error (gain and trim to about 1 %) and the axle, which the in-place turns' travel is taken with
# (log.json's baseline: Duckietown's 0.1 m; a real wheel's contact is a 2 cm wide tyre, and the independent
# generator's robot has 0.102 m: 2 %); the counts' rounding (a tick a segment) is added.
ENCODER_TOLERANCE = 0.05
STRAIGHT_DUTY_SHARE = 0.1  # a command drives straight when its duties differ by at most this share of the larger
MIN_PHASE_RAD = 2 * np.pi  # a phase whose wheels turned less than a revolution in all is not judged


def encoder_evidence(log, drive: Drive, values: dict) -> EncoderEvidence | None:
    """Each wheel's turned angle from encoders.csv against the fitted model's: the model's trajectory (fit.trajectory
    with the fitted `values`: gain, trim, baseline_m and any effect's parameters) between consecutive encoder rows
    within the frames' span, as the wheel's ground travel with log.json's radius and baseline (the arc length
    ds -+ dtheta b / 2, over r; segment by segment where the log has breaks), summed over runs of one command: straight (STRAIGHT_DUTY_SHARE), curving, or
    turning in place (the duties of opposite signs).
    A wheel that slips turns more than the ground moves: the encoder's angle over the model's is above 1, in turns
    (the camera-only fit hides it in a larger baseline) beyond what it is straight; a wrong radius (or tick count)
    is one ratio in every phase. None without encoders."""
    from naocal.kinds.duckiebot.fit import trajectory

    if log.encoder_t_s is None:
        return None
    t = log.encoder_t_s
    inside = np.flatnonzero((t >= drive.frame_t_s[0]) & (t <= drive.frame_t_s[-1]))
    if len(inside) < 2:
        return None
    t = t[inside]
    ticks = np.column_stack([log.left_ticks[inside], log.right_ticks[inside]]).astype(float)
    tick_rad = 2 * np.pi / log.wheels.ticks_per_revolution
    encoder = np.diff(ticks, axis=0) * tick_rad
    effects = {n: float(values[n]) for e in EFFECTS for n in EFFECTS[e] if n in values}
    b, r = log.wheels.baseline_m, log.wheels.radius_m
    # the model's wheel angles segment by segment (a break in the log: the robot carried, each segment driven from
    # rest by its own commands, fit.Drive.segment); an interval across a break is left out (NaN)
    model = np.full((len(t) - 1, 2), np.nan)
    part = drive.segment_of(t)
    for s in np.unique(part):
        rows = np.flatnonzero(part == s)  # consecutive: t increases
        if len(rows) < 2:
            continue
        poses, _ = trajectory(drive.segment(int(s)), values["gain"], values["trim"], values["baseline_m"],
                              np.zeros(3), float(t[rows[0]]), t[rows], effects)
        turn = np.diff(poses[:, 2])
        chord = np.diff(poses[:, :2], axis=0)
        mid = poses[:-1, 2] + turn / 2
        half = turn / 2
        arc = np.where(np.abs(half) > 1e-9, half / np.sin(np.where(np.abs(half) > 1e-9, half, 1.0)), 1.0)
        ds = (chord[:, 0] * np.cos(mid) + chord[:, 1] * np.sin(mid)) * arc
        model[rows[:-1]] = np.column_stack([ds - turn * b / 2, ds + turn * b / 2]) / r
    # the command at each interval's start; runs of one command (republished rows included)
    row = np.searchsorted(drive.wheel_t_s, t[:-1], side="right") - 1
    u_l = np.where(row >= 0, drive.left_duty[np.maximum(row, 0)], 0.0)
    u_r = np.where(row >= 0, drive.right_duty[np.maximum(row, 0)], 0.0)
    moving = ((u_l != 0) | (u_r != 0)) & np.isfinite(model).all(axis=1)
    straight = np.abs(u_r - u_l) <= STRAIGHT_DUTY_SHARE * np.maximum(np.abs(u_l), np.abs(u_r))
    starts = np.concatenate([[True], (u_l[1:] != u_l[:-1]) | (u_r[1:] != u_r[:-1])])
    run = np.cumsum(starts) - 1
    in_place = u_l * u_r < 0  # the wheels turning opposite ways: the ground travel is all turning
    phases = {}
    for name, chosen in (("straight", moving & straight), ("curving", moving & ~straight & ~in_place),
                         ("in place", moving & in_place)):
        ids = np.unique(run[chosen])
        if not len(ids):
            continue
        enc = np.abs(np.array([encoder[(run == i) & chosen].sum(axis=0) for i in ids])).sum(axis=0)
        mod = np.abs(np.array([model[(run == i) & chosen].sum(axis=0) for i in ids])).sum(axis=0)
        if mod.sum() < MIN_PHASE_RAD:
            continue
        phases[name] = {"segments": int(len(ids)), "encoder_rad": enc.tolist(), "model_rad": mod.tolist(),
                        "ratio": (enc / np.maximum(mod, 1e-12)).tolist(), "both": float(enc.sum() / mod.sum()),
                        "tolerance": ENCODER_TOLERANCE + 2 * len(ids) * tick_rad / float(mod.sum())}
    if not phases:
        return None
    straight_phase = phases.get("straight")
    turns = {name: phase for name, phase in phases.items() if name != "straight"}
    radius_ratio = None if straight_phase is None else straight_phase["both"]
    radius_off = radius_ratio is not None and abs(radius_ratio - 1) > straight_phase["tolerance"]
    slipping = [] if straight_phase is None else [
        name for name, phase in turns.items()
        if phase["both"] - straight_phase["both"] > max(straight_phase["tolerance"], phase["tolerance"])]
    # the other way round: no slip does that; encoders missing counts, or a model that turns more than the robot did
    short = [] if straight_phase is None else [
        name for name, phase in turns.items()
        if straight_phase["both"] - phase["both"] > max(straight_phase["tolerance"], phase["tolerance"])]
    words = []
    if slipping:
        worst = max(slipping, key=lambda name: turns[name]["both"])
        words.append(f"slip in turns: {worst}, the wheels turned {100 * (turns[worst]['both'] - 1):.0f} % more than "
                     f"the ground moved under them (straight: {100 * (straight_phase['both'] - 1):+.0f} %; the "
                     f"fitted baseline {values['baseline_m'] * 1e3:.1f} mm takes it up, log.json's {b * 1e3:g} mm)")
    if radius_off:
        words.append(f"one ratio {radius_ratio:.3f} straight: the wheels' radius is {r / radius_ratio * 1e3:.2f} mm, "
                     f"not log.json's {r * 1e3:g} mm (or the encoders count other than "
                     f"{log.wheels.ticks_per_revolution} a revolution)")
    if short:
        worst = min(short, key=lambda name: turns[name]["both"])
        words.append(f"{worst}: the wheels turned {100 * (1 - turns[worst]['both']):.0f} % less than the model's ground "
                     f"travel (straight: {100 * (straight_phase['both'] - 1):+.0f} %): the encoders miss counts there, "
                     "or the model turns more than the robot did")
    if straight_phase is None and any(abs(phase["both"] - 1) > phase["tolerance"] for phase in turns.values()):
        words.append("the wheels' turn and the ground travel differ in turns: slip or a wrong radius (no straight "
                     "drive to tell them apart)")
    slip = bool(slipping)
    verdict = "; ".join(words) or ("the encoders agree with the model in every phase: no slip, the radius as "
                                   "log.json's")
    return EncoderEvidence(phases, slip, radius_ratio, radius_off, verdict)


def add_encoder_evidence(diagnosis: DriveDiagnosis, log, drive: Drive) -> DriveDiagnosis:
    """The encoders' evidence (encoder_evidence) on the diagnosis's fit (through its model of the wheel driver),
    in place; the fit and what is named stay as they are."""
    if diagnosis.fit is not None:
        diagnosis.encoders = encoder_evidence(log, replace(drive, pwm_driver=diagnosis.fit.pwm_driver),
                                              dict(zip(diagnosis.fit.names, diagnosis.fit.x)))
    return diagnosis


# ------------------------------------------------------------------------------------------------ a drive log

@dataclass
class LogFit:
    """What the verb fits from a log: its drive, detections and lens fits, for refits with other models."""

    log: object
    drive: Drive
    detections: object
    lens_fits: dict

    def fit(self, lens: str, effects=(), start=None) -> tuple[DriveFit, np.ndarray]:
        from naocal.kinds.duckiebot.identify import rectified_sightings
        from naocal.kinds.duckiebot.robot import nominal_for

        camera = self.lens_fits[lens].camera
        sightings = rectified_sightings(self.detections, camera)
        fit = fit_drive(self.drive, sightings, camera.K, self.log.marker_size_m,
                        nominal_for(self.log.model).T_base_camera, effects=effects, start=start)
        return fit, camera.K


def diagnose_log(log_dir, effects=(), lens: str = "plumb_bob") -> DriveDiagnosis:
    """Read, detect, fit the lens models, then diagnose_lenses with the log's joint fits (corners rectified with
    each lens model)."""
    from naocal.kinds.duckiebot.drive_log import read_drive_log
    from naocal.kinds.duckiebot.identify import detect_log, fit_intrinsics

    log = read_drive_log(log_dir)
    detections = detect_log(log)
    _, lens_fits = fit_intrinsics(log, detections)
    if lens not in lens_fits:
        raise NaocalError(f"{log_dir}: the {lens} lens model could not be fitted to the board views")
    source = LogFit(log, Drive.of_log(log), detections, lens_fits)
    diagnosis = diagnose_lenses(source.drive, source.fit, log.marker_size_m, effects, lens, lens_fits)
    return add_encoder_evidence(diagnosis, log, source.drive)


def diagnose_lenses(drive: Drive, fit_with, marker_size_m: float, effects=(), lens: str = "plumb_bob",
                    lens_fits: dict | None = None) -> DriveDiagnosis:
    """The joint fit with `effects` through `lens` (fit_with(lens, effects, start=None) -> (DriveFit, K): the
    corners rectified with that lens model), diagnosed (diagnose_fit, with refits), and refitted with what is named
    (DriveDiagnosis.after). The lens is judged by the board views alone (lens_verdict), so a joint fit that the wrong
    lens leaves undetermined does not stop it: a badly fitted plumb_bob on a 150-degree lens (seed 3: cy 335 px for
    219) puts the first marker's rays above the horizon, its start 60 km away, and the fit cannot be made; the
    diagnosis then says so (fit_error), names the lens, and tries the refit with the right one. Without a wrong lens
    to name, a model that cannot be fitted is the SolveError it raised."""
    effects = tuple(effects)
    verdict = lens_verdict(lens_fits, lens) if lens_fits and lens in lens_fits else None
    try:
        fit, K = fit_with(lens, effects)
    except SolveError as err:
        if verdict is None or not verdict.wrong:
            raise
        fit, nan = None, float("nan")
        diagnosis = DriveDiagnosis(effects, lens, None, nan, nan, nan, [], [], nan, verdict, fit_error=str(err))
    else:
        diagnosis = diagnose_fit(drive, fit, K, marker_size_m, effects, lens, lens_fits,
                                 refit=lambda with_effects: fit_with(lens, with_effects)[0])
    if diagnosis.named is not None and diagnosis.named.startswith("lens="):
        # from the fit's kinematics, which another lens does not change: from the detections' start (their rays
        # through a wide lens reach 67 deg off the axis) an earlier render of seed 3's log ended at 98.7 px, from
        # these at 0.56 px; without a fit, from the detections' (docs/DUCKIEBOT.md: where that fails)
        start = None if fit is None else {n: fit.value(n) for n in KINEMATIC}
        try:
            diagnosis.after = refit_summary(fit_with(diagnosis.lens_verdict.best, effects, start)[0], effects)
        except SolveError as err:  # e.g. a marker seen once, far, that the other lens leaves undetermined
            diagnosis.after = {"added": list(effects), "error": str(err)}
    return diagnosis


def add_command(log_label, diagnosis: DriveDiagnosis) -> str:
    """The command that adds what is named."""
    named = diagnosis.named
    if named.startswith("lens="):
        effects = ",".join(diagnosis.effects)
        return (f"naocal diagnose {log_label} --lens {named.split('=')[1]}"
                + (f" --effects {effects}" if effects else ""))
    return f"naocal diagnose {log_label} --effects {','.join(diagnosis.effects + (named,))}" + (
        f" --lens {diagnosis.lens}" if diagnosis.lens != "plumb_bob" else "")


def verdict(t: EffectTest) -> str:
    return ("refit" if t.confirmed_by_refit else "yes") if t.significant else "no"


def format_diagnosis(d: DriveDiagnosis, log_label="LOG") -> str:
    fit = d.fit
    model = f"model: Duckietown's kinematics + {' + '.join(d.effects) or 'no wheel effect'}; lens {d.lens}"
    if fit is None:
        lines = [f"{model}: the joint fit cannot be made: {d.fit_error}", "", "COMPARE, LOCATE, NAMES: none "
                 "without a fit (the wheel effects are judged once the lens is right)"]
    else:
        lines = [f"{model}; {len(fit.sightings.frame)} marker corners in {len(np.unique(fit.sightings.frame))} "
                 "frames", "", "COMPARE",
                 f"  RMS {d.rms_px:.3f} px; noise floor {d.floor_px:.3f} px (the corners' expected detection "
                 f"noise); whitened RMS {d.whitened_rms:.2f} (1 at the floor)", "",
                 "LOCATE (corner RMS of the frames by the drive phase before them)"]
    for row in d.phases:
        lines.append(f"  {row['phase']:28s} {row['frames']:4d} frames {row['corners']:5d} corners  "
                     f"RMS {row['rms_px']:.3f} px")
    if d.lens_verdict is not None:
        v = d.lens_verdict
        lines += ["", "LENS (held-out board RMS per lens model)",
                  "  " + "; ".join(f"{m} {r:.3f} px" for m, r in v.held_out_rms_px.items())
                  + f"; in use {v.in_use}: {v.ratio:.2f} x the best ({v.best})"
                  + (f" >= {LENS_RATIO}: the wrong lens model" if v.wrong else "")]
    if fit is not None:
        lines += ["", f"NAMES (score test per wheel effect, clustered by frame; significant: p < {d.threshold:.1e})"]
    for t in d.tests:
        values = ", ".join(f"{n} {v:+.4g}" for n, v in t.predicted_values.items())
        lines.append(f"  {t.effect:11s} dof {t.dof}  dRSS {t.delta_rss:9.1f}  T2 {t.statistic:9.1f}  p {t.p_value:8.1e}"
                     f"  {verdict(t):5s}  uniqueness {t.uniqueness:.3f}  "
                     f"predicted RMS {t.predicted_rms_px:.3f} px"
                     + (f", refitted {t.refit_rms_px:.3f} px" if np.isfinite(t.refit_rms_px) else "")
                     + (f"; its refit cannot be made: {t.refit_error}" if t.refit_error else "")
                     + (f"; {values}" if t.significant and values else ""))
    if d.encoders is not None:
        lines += ["", "ENCODERS (each wheel's turn from encoders.csv over the fitted model's ground travel of it, with "
                      "log.json's radius and baseline)"]
        for name, phase in d.encoders.phases.items():
            lines.append(f"  {name:9s} {phase['segments']:4d} segments: left {phase['ratio'][0]:.3f}, right "
                         f"{phase['ratio'][1]:.3f} ({phase['encoder_rad'][0]:.1f} / {phase['model_rad'][0]:.1f} and "
                         f"{phase['encoder_rad'][1]:.1f} / {phase['model_rad'][1]:.1f} rad); both {phase['both']:.3f}, "
                         f"agreement within {phase['tolerance']:.3f}")
        lines.append(f"  evidence: {d.encoders.verdict}")
    lines.append("")
    if d.named is None:
        lines.append("VERDICT: no missing effect: the model explains the drive to the noise floor's test")
    else:
        what = (f"the wrong lens model: {d.lens_verdict.best} instead of {d.lens}" if d.named.startswith("lens=")
                else f"{d.named} ({', '.join(EFFECTS[d.named])})" if d.named in EFFECTS
                else f"{d.named} (Duckietown's wheel driver: the motors get the floored PWM, not the duty logged)")
        lines.append(f"VERDICT: missing {what}")
        lines.append(f"  add it: {add_command(log_label, d)}")
        if d.after is not None and "error" in d.after:
            lines.append(f"  with it: the refit failed: {d.after['error']}")
        elif d.after is not None and d.fit is None:
            lines.append(f"  with it: RMS {d.after['rms_px']:.3f} px (floor {d.after['floor_px']:.3f} px; whitened "
                         f"{d.after['whitened_rms']:.2f}); without it the fit could not be made")
        elif d.after is not None:
            values = ", ".join(f"{n} {v['value']:+.4g} +- {v['std']:.2g}" for n, v in d.after["values"].items())
            lines.append(f"  with it: RMS {d.rms_px:.3f} -> {d.after['rms_px']:.3f} px (floor "
                         f"{d.after['floor_px']:.3f} px; whitened {d.whitened_rms:.2f} -> "
                         f"{d.after['whitened_rms']:.2f})" + (f"; {values}" if values else ""))
    return "\n".join(lines)
