"""Diagnostics of an arm's fit (docs/ARM.md): compare it with the noise, locate the misfit on the joints and links,
and name the effects that are missing, each judged by a score test on the fitted model's residuals.

For a group of parameters not in the model (an effect, or every parameter of one joint or link) the model's
whitened residual r is regressed on the group's Jacobian columns with the model's own columns projected out; the
drop in the residual sum of squares is dRSS. Its significance is judged per pose, not per measurement: a real arm's
errors are correlated within a pose (its repeatability, a tracker's drift, what no model holds), so the
observations of one pose are one cluster and the score's variance is the clustered sandwich over poses
(solver.scoretest.score_test, the NAO's per-stance test: Hotelling T^2 with G poses, F(k, G - k)). Counting every
measurement as independent would name a candidate whenever the misfit is above the stated noise. An effect is
named when its p-value is below 0.001 divided by the number of candidates (Bonferroni: one false alarm in 1000
datasets at most); the significant ones are ranked by dRSS - (1 + log M) n, n what the group would remove from the
errors alone (k for independent errors, more when they are correlated within poses; BIC's k log M), so that
of two effects that explain the misfit alike the one with fewer parameters comes first. A group with as many
directions as poses less one cannot be tested (p-value 1).

A significant effect may still be no property of the arm: link lengths soak up a camera's wrong focal length or
markers glued off their nominal spot, and the pixels improve while the arm gets worse. So each significant
candidate is also judged on data its fit did not see and the pixels cannot fool (`physical_checks`): the other
sensor (the arm fitted from the cameras alone, with and without it, then held while the 3-D sensors' frames, and
their reflectors if the model has points, are refitted as verify --refit does; the other way round, the cameras
judging the 3-D sensors' arm; and each of two or more cameras judging the others' arm) and other sessions (leave
one session of observations.csv's session column out, or without one a block of consecutive poses). The judged
sensors' nuisances (their reflectors, a camera's intrinsics) are those of the fitted model, with and without the
candidate alike. A candidate that makes any of them worse by more than HELDOUT_TOLERANCE, and beyond what its own
estimation noise does to the judged sensor (`chance_rise`, `session_chance`, CHANCE_Z), fits the pixels only and is
not recommended. Not worse is not better: a candidate is confirmed only when a check of the most independent kind it
has (CONFIRMING) is better beyond chance, the same band's other side; one that is not is said so ('not confirmed by
tracker: no better, ...') and proposed after a confirmed one; the verdict is the best candidate that is physical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import ndtri

from naocal.kinds.arm.model import ArmModel
from naocal.kinds.arm.identify import (ArmFit, fit as fit_arm, heldout_residuals, heldout_rms, sensor_rms, shown_rms,
                                       whitened)
from naocal.solver.effects import ARM_EFFECTS
from naocal.solver.diagnostics import FAMILY_ALPHA
from naocal.solver.identify import UNIDENTIFIABLE_RATIO
from naocal.solver.scoretest import score_test

RANK_TOLERANCE = 1e-6
# A held-out RMS more than this share above the model's without the candidate is worse: the candidate fits the
# pixels only. Set from benchmarks/bench_arm_physical.py (simulated dual arm, seeds 1-4, docs/ARM.md): effects the
# robot has raised a held-out RMS by up to 8.9 % (a camera alone judging link lengths; two more by 16 and 26 %),
# effects it lacks that absorb a camera's 1 % focal error by 14.4 % at least: at 2 % 5 of the 8 physical candidates
# were refuted, at 10 % those 2, and no fooled one passed at either.
HELDOUT_TOLERANCE = 0.10
# ... and only when the rise of its whitened sum of squares is beyond chance: the candidate's parameters, fitted
# from the other sensors, carry their estimation noise to the judged sensor even where the arm has none of it (one
# camera at 60 poses judging elasticity moved the other camera by 13 %, 1.5 sd of that noise: a false alarm).
# Beyond CHANCE_Z sds of that noise (`chance_rise`), at diagnose's family level one-sided.
CHANCE_Z = float(-ndtri(FAMILY_ALPHA))  # 3.09 (scipy.special: scipy.stats is slow to import)
# A candidate is confirmed when held-out data its pixels cannot fool are better with it beyond chance; the checks
# asked, most independent first: another sensor (the tracker judging the cameras' arm, or the other way round), the
# cameras one another, other sessions (which a sensor-model error fools alike in every session).
CONFIRMING = (("sensor", "reverse"), ("camera",), ("session",))
SESSIONS = 5  # blocks of consecutive poses standing in for sessions when the dataset has no session column


@dataclass
class Test:
    label: str  # an effect name, or 'joint <J>' / 'link <L>'
    k: int  # degrees of freedom (rank of the group beyond the model)
    drss: float  # drop of the whitened RSS
    p_value: float
    uniqueness: float  # share of the group's signature the model cannot already produce
    predicted_rms: dict  # sensor -> RMS after adding the group (m or px)
    values: dict  # parameter name -> predicted value (SI)
    significant: bool = False
    noise_rss: float = float("nan")  # what the group removes from the residuals' own errors on average (per pose)
    testable: bool = True  # False: too few poses for its directions (k >= poses - 1): p-value 1, not named
    inert: tuple = ()  # its parameters no pose moves (solver.identify.UNIDENTIFIABLE_RATIO): to be fixed with it
    checks: list = field(default_factory=list)  # [HeldOutCheck]: judged on data its fit did not see (significant only)
    pixels: dict = field(default_factory=dict)  # judged ones: camera (or every) sensor -> [RMS now, with it]

    @property
    def physical(self):
        """False if a held-out check is worse with it, True if every one is not, None if none was made."""
        return None if not self.checks else not any(c.worse for c in self.checks)

    @property
    def deciding(self) -> list:
        """The checks that confirm it or not: those of the first of CONFIRMING present (another sensor's before the
        cameras' one another's before other sessions')."""
        for kinds in CONFIRMING:
            checks = [c for c in self.checks if c.kind in kinds]
            if checks:
                return checks
        return []

    @property
    def confirmed(self):
        """True: not refuted, and a deciding check better beyond chance; False: refuted, or none is; None: not
        judged."""
        if not self.checks:
            return None
        return self.physical and any(c.better for c in self.deciding)

    @property
    def not_confirmed_by(self) -> list:
        """[(check, sensor)] of the deciding checks' sensors that are neither better nor worse (a worse one is the
        refutation) when none is better: what the report says 'not confirmed by' (of a refuted one too)."""
        if any(c.better for c in self.deciding):
            return []
        return [(c, s) for c in self.deciding for s in c.with_effect if c.word(s) in ("no better", "within chance")]

    @property
    def standing(self) -> int:
        """The order the judged candidates are proposed in: 0 confirmed, 1 not judged or not confirmed, 2 refuted."""
        return 2 if self.physical is False else 0 if self.confirmed else 1

    @property
    def refutation(self) -> str:
        """Why it is not recommended ('' if it is not refuted): the other sensor worse, or only other sessions."""
        worse = {c.kind for c in self.checks if c.worse}
        if "sensor" in worse:
            if any(after < before for before, after in self.pixels.values()):
                return "fits the pixels only (absorbs camera/marker-model error)"
            return "makes the other sensor worse (takes up another effect's misfit)"
        if "camera" in worse:
            return "fits one camera only (absorbs that camera's model error)"
        if "reverse" in worse:
            return "fits the 3-D sensor only (the cameras, with the arm fitted from it alone, are worse)"
        return "predicts other sessions worse (fits these poses only)" if worse else ""

    def as_dict(self):
        return {"label": self.label, "dof": self.k, "drss": self.drss, "noise_rss": self.noise_rss,
                "p_value": self.p_value,
                "uniqueness": self.uniqueness, "predicted_rms": self.predicted_rms, "values": self.values,
                "significant": self.significant, "testable": self.testable, "inert": list(self.inert),
                "checks": [c.as_dict() for c in self.checks], "physical": self.physical,
                "refutation": self.refutation or None, "pixels": self.pixels, "confirmed": self.confirmed,
                "confirmed_by": sorted({s for c in self.deciding for s in c.better}) if self.confirmed else [],
                "not_confirmed_by": [{"sensor": s, "check": c.kind, "word": c.word(s), "without": c.without[s],
                                      "with": c.with_effect[s]} for c, s in self.not_confirmed_by]}


@dataclass
class HeldOutCheck:
    """The RMS of data a fit did not see, per sensor (m or px), without and with a candidate effect."""

    kind: str  # 'sensor': the 3-D sensors, the arm fitted from the cameras; 'reverse': the cameras, the arm fitted
    # from the 3-D sensors; 'camera': one camera, the arm fitted from the others; 'session': blocks of poses held out
    how: str  # one phrase for the report
    without: dict
    with_effect: dict
    # judged sensor -> {"rise": its whitened sum of squares with less without the candidate, "mean", "sd": that
    # rise's under chance alone (`chance_rise`, `session_chance`)}; empty: not known (the fits' rows differ)
    chance: dict = field(default_factory=dict)

    def within_chance(self, sensor) -> bool:
        c = self.chance.get(sensor)
        return c is not None and c["rise"] <= c["mean"] + CHANCE_Z * c["sd"]

    def better_beyond_chance(self, sensor) -> bool:
        """Its whitened sum of squares fell, and below the same band's other side: mean - CHANCE_Z sd of what the
        candidate's estimation noise alone would do to it (one null, the candidate is nothing but noise, rejected
        on either side at diagnose's family level one-sided). Not a paired test of the rows with and without: both
        fits share the same data, and the rows' differences are correlated through the one estimate d that moves
        them all; the band counts that (without it any fall by chance was 'better'). Unknown chance (the rows differ): fallen by more than
        the tolerance, the same test 'worse' falls back on."""
        with_it, without = self.with_effect[sensor], self.without[sensor]
        c = self.chance.get(sensor)
        if c is None:
            return with_it * (1.0 + HELDOUT_TOLERANCE) < without
        # a band of 0: the candidate cannot reach these rows (a camera's intrinsics, the arm fitted from the tracker):
        # a fall there is the solver's rounding, nothing to confirm
        return c["sd"] > 0.0 and c["rise"] < min(0.0, c["mean"] - CHANCE_Z * c["sd"])

    def word(self, sensor) -> str:
        """'worse', 'within chance' (worse beyond the tolerance, not beyond chance), 'better' (beyond chance) or
        'no better' (a fall within chance, or a rise within the tolerance)."""
        if self.with_effect[sensor] > (1.0 + HELDOUT_TOLERANCE) * self.without[sensor]:
            return "within chance" if self.within_chance(sensor) else "worse"
        return "better" if self.better_beyond_chance(sensor) else "no better"

    @property
    def worse(self) -> list:
        return [s for s in self.with_effect if self.word(s) == "worse"]

    @property
    def better(self) -> list:
        return [s for s in self.with_effect if self.word(s) == "better"]

    def as_dict(self):
        return {"kind": self.kind, "how": self.how, "without": self.without, "with": self.with_effect,
                "worse": self.worse, "better": self.better, "words": {s: self.word(s) for s in self.with_effect},
                "chance": self.chance}


def extended(fit: ArmFit, effects=ARM_EFFECTS):
    """(model with every effect, its x at the fit, free mask of the fit's free parameters)."""
    m = fit.model
    big = _model_like(m, effects, range(len(m.sensors)))
    values = dict(zip(m.names, fit.x))
    free_names = set(fit.free_names)
    x = np.array([values.get(n, 0.0) for n in big.names])
    free = np.array([n in free_names for n in big.names])
    return big, x, free


def score_tests(fit: ArmFit, groups: dict) -> list[Test]:
    """One Test per {label: [parameter names]} (names of solver.effects.ARM_EFFECTS parameters not in the fit)."""
    big, x, free = extended(fit)
    obs = fit.obs
    r, J = whitened(big, obs, x, fit.sigma, jacobian=True)
    J = J * big.scales
    Q, _ = np.linalg.qr(J[:, free])
    index = {n: i for i, n in enumerate(big.names)}
    mask = big.component_mask(obs)
    sigma_rows = np.broadcast_to(fit.sigma[obs.sensor][:, None], mask.shape)[mask]
    sensor_rows = np.broadcast_to(obs.sensor[:, None], mask.shape)[mask]
    pose_rows = np.broadcast_to(obs.pose[:, None], mask.shape)[mask]
    clusters = [np.flatnonzero(pose_rows == pose) for pose in np.unique(obs.pose)]
    column_norms = np.linalg.norm(J, axis=0)
    floor = UNIDENTIFIABLE_RATIO * column_norms[free].max(initial=0.0)  # the fit would stop on such a column
    tests = []
    for label, names in groups.items():
        cols = [index[n] for n in names if n in index and not free[index[n]]]
        if not cols:
            continue
        C = J[:, cols]
        inert = tuple(big.names[c] for c in cols if 0.0 < column_norms[c] < floor)
        Cp = C - Q @ (Q.T @ C)
        total = float(np.sum(C ** 2))
        uniqueness = float(np.sum(Cp ** 2) / total) if total > 0 else 0.0
        U, sv, Vt = np.linalg.svd(Cp, full_matrices=False)
        ref = max(float(np.linalg.norm(C, axis=0).max()), 1e-300)
        k = int(np.sum(sv > RANK_TOLERANCE * ref))
        if k == 0:
            tests.append(Test(label, 0, 0.0, 1.0, uniqueness, {}, {}, noise_rss=0.0, inert=inert))
            continue
        Uk = U[:, :k]
        proj = Uk.T @ r
        drss = float(proj @ proj)
        clustered = score_test(Uk, r, clusters, Q=Q)  # per pose (the module's docstring), on its k directions
        p_value = clustered.p_value if np.isfinite(clustered.p_value) else 1.0
        r_new = (r - Uk @ proj) * sigma_rows
        predicted = {}
        for s, sensor in enumerate(big.sensors):
            e = r_new[sensor_rows == s]
            predicted[sensor.name] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
        delta = -(Vt[:k].T @ (proj / sv[:k]))  # in scaled units, on the group's columns
        values = {big.names[c]: float(d * big.scales[c]) for c, d in zip(cols, delta)}
        tests.append(Test(label, k, drss, p_value, uniqueness, predicted, values,
                          noise_rss=clustered.noise_rss if np.isfinite(clustered.noise_rss) else float(k),
                          testable=bool(np.isfinite(clustered.p_value)), inert=inert))
    return tests


def candidate_groups(fit: ArmFit) -> dict:
    """Every effect not in the model (and, for those in it, the parameters the fit has fixed are not retested)."""
    big, _, _ = extended(fit)
    in_model = set(fit.model.effects)
    return {e: [p.name for _, p in big.params(e)] for e in ARM_EFFECTS if e not in in_model and big.params(e)}


def location_groups(fit: ArmFit) -> dict:
    """Per joint (offset, elasticity, the rotation of its origin) and per link (length, the translation of its
    origin; the tip link also its points): every parameter of it the model does not have."""
    big, _, _ = extended(fit)
    groups = {}
    origin = {key: o for o, key in enumerate(big.origin_keys)}  # every chain's joint origins, shared by name
    for joint in big.joint_names:
        groups[f"joint {joint}"] = [f"joint_offset.{joint}", f"elasticity.{joint}"] + [
            f"link_pose.{big.origin_names[origin[('joint', joint)]]}.{q}" for q in ("rx", "ry", "rz")]
    for (kind, _), link in zip(big.origin_keys, big.origin_names):
        names = [f"link_length.{link}"]
        if kind == "joint":
            names += [f"link_pose.{link}.{q}" for q in ("x", "y", "z")]
        else:  # a chain's tip: the points on its tool
            names += [p.name for _, p in big.params("points")]
        groups[f"link {link}"] = names
    return groups


def _model_like(model: ArmModel, effects, sensors) -> ArmModel:
    """The model's arm with `effects` and only the sensors of indices `sensors` (their starting frames kept)."""
    out = ArmModel(model.chain, dict(zip(model.point_names, model.point_xyz)), [model.sensors[s] for s in sensors],
                   effects, model.gravity_mps2, model.load, model.link_names, markers=model.markers,
                   sheets=model.sheets)
    out.R0 = model.R0[list(sensors)].copy()
    return out


def _sensor_rows(obs, sensors):
    """The observations of the sensors of (sorted) indices `sensors`, their sensor indices into that list."""
    sub = obs.subset(np.isin(obs.sensor, sensors))
    sub.sensor = np.searchsorted(sensors, sub.sensor)
    return sub


def refit_with(fit: ArmFit, effects, sensors=None, held=()) -> ArmFit:
    """The fit's data (only the `sensors`' observations, default all) fitted with `effects`, from the fit's values,
    holding what it held (its gauges, the user's --fix) and `held`."""
    sensors = list(range(len(fit.model.sensors))) if sensors is None else list(sensors)
    model = _model_like(fit.model, effects, sensors)
    obs = fit.obs if len(sensors) == len(fit.model.sensors) else _sensor_rows(fit.obs, sensors)
    values = dict(zip(fit.model.names, fit.x))
    x0 = np.array([values.get(n, 0.0) for n in model.names])
    fixed = tuple(n for n, free in zip(fit.model.names, fit.free) if not free and n in values) + tuple(held)
    return fit_arm(model, obs, x0, fixed=fixed, loss=fit.loss, priors=fit.priors)


def sensor_groups(model: ArmModel):
    """(cameras, 3-D sensors) indices, or None unless the model has both: the arm is fitted from the cameras and
    judged on the 3-D sensors (a tracker), which no camera or marker model enters, and the other way round."""
    cameras = [s for s, sensor in enumerate(model.sensors) if sensor.kind == "camera"]
    trackers = [s for s, sensor in enumerate(model.sensors) if sensor.kind == "points"]
    return (cameras, trackers) if cameras and trackers else None


def cross_checks(model: ArmModel) -> list:
    """[(kind, sensors the arm is fitted from, sensors judged)]: the 3-D sensors judge the cameras' arm ('sensor')
    and the cameras the 3-D sensors' arm ('reverse': an effect that fits the tracker's reflector model only), and
    with two cameras or more each camera judges the arm of the others ('camera': one camera's model error)."""
    cameras = [s for s, sensor in enumerate(model.sensors) if sensor.kind == "camera"]
    groups = sensor_groups(model)
    out = [("sensor", *groups), ("reverse", groups[1], groups[0])] if groups else []
    if len(cameras) > 1:
        out += [("camera", [c for c in cameras if c != left_out], [left_out]) for left_out in cameras]
    return out


def cross_sensor_fits(fit: ArmFit, effects, held=(), fitted_from=None, judged=None):
    """(the arm fitted with `effects` from the `fitted_from` sensors alone (default: the cameras; judged: the 3-D
    sensors), the judged sensors' fit with that arm held): in the latter only the judged sensors' frames and their
    nuisances (kinds.arm.verify.NUISANCE_EFFECTS of the fit's own model: a tracker's reflectors the fitting sensors
    never saw, a judged camera's intrinsics) are refitted, kinds.arm.verify.nuisance_fit, what verify --refit does;
    a candidate's are never (it would give the judged sensor a freedom the comparison without it lacks). Only the
    judged rows of chains the fitting sensors saw count (a tracker on one arm says nothing of the other's); the
    nuisances the fit held stay held."""
    from naocal.kinds.arm.verify import NUISANCE_EFFECTS, nuisance_fit

    if fitted_from is None:
        fitted_from, judged = sensor_groups(fit.model)
    fitted_from, judged = sorted(fitted_from), sorted(judged)
    from_them = refit_with(fit, effects, fitted_from, held)
    arm = {n: v for n, v in zip(from_them.model.names, from_them.x) if not n.startswith("sensor.")}
    model = _model_like(fit.model, effects, judged)
    nuisances = tuple(e for e in NUISANCE_EFFECTS if e in fit.model.effects)
    held_nuisances = [n for n, free in zip(fit.model.names, fit.free)  # what the user holds stays held (--fix points)
                      if not free and fit.model.parameters[fit.model.names.index(n)].effect in nuisances]
    seen = np.isin(fit.obs.sensor, fitted_from)
    bodies = set(fit.model.point_body[np.unique(fit.obs.point[seen])].tolist())  # the markers and points they saw
    held_nuisances += [p.name for _, p in fit.model.params("points") if p.index in bodies]
    rows = np.isin(fit.obs.sensor, judged) & np.isin(fit.obs.chains(), np.unique(fit.obs.chains()[seen]))
    check = nuisance_fit(model, _sensor_rows(fit.obs.subset(rows), judged), arm, nuisances,
                         held=[n for n in dict.fromkeys(held_nuisances) if n in model.names], priors=fit.priors)
    return from_them, check


def _free_jacobian(fit_: ArmFit):
    """(the free parameters' indices, the whitened residuals' Jacobian in them, scaled as the solver sees them)."""
    index = np.flatnonzero(fit_.free)
    _, J = whitened(fit_.model, fit_.obs, fit_.x, fit_.sigma, jacobian=True)
    return index, J[:, index] * fit_.model.scales[index]


def chance_rise(without, from_them, with_it, label) -> dict:
    """{judged sensor: {"rise", "mean", "sd"}}: the rise of its whitened sum of squares from the judged fit
    `without` to `with_it` (cross_sensor_fits' second, without and with the candidate effect `label`; the same rows),
    and that rise's mean and sd if the candidate were nothing but noise: its parameters, fitted from the other
    sensors (`from_them`, with it), move the arm by d ~ N(0, S), S the spread of the difference the candidate makes
    to the estimates (`_candidate_spread`), seen by the judged sensor through its Jacobian G with its own frame and nuisances
    projected out (`_rise_under_chance`). Linear about the fits."""
    r0 = whitened(without.model, without.obs, without.x, without.sigma)
    r1, J1 = whitened(with_it.model, with_it.obs, with_it.x, with_it.sigma, jacobian=True)
    if not _same_rows(without.obs, with_it.obs):
        return {}
    m = from_them.model
    index, JF = _free_jacobian(from_them)
    root = _candidate_spread(m, index, JF.T @ JF, label, from_them.priors)
    judged = with_it.model
    column = {n: i for i, n in enumerate(judged.names)}
    shared = [j for j, i in enumerate(index) if m.names[i] in column and not with_it.free[column[m.names[i]]]]
    cols = [column[m.names[index[j]]] for j in shared]
    G = J1[:, cols] * judged.scales[cols]
    Q, _ = np.linalg.qr(J1[:, with_it.free] * judged.scales[with_it.free])
    G -= Q @ (Q.T @ G)
    return _rise_under_chance(G @ root[shared], r0, r1, _component_sensors(judged, with_it.obs), judged.sensors)


def _same_rows(a, b) -> bool:
    """Whether two fits' observations are the same rows (a refit may set other detections aside)."""
    return len(a) == len(b) and np.array_equal(a.pose, b.pose) and np.array_equal(a.sensor, b.sensor) and \
        np.array_equal(a.point, b.point)


def _candidate_spread(model, index, information, label, priors):
    """root (len(index), r), S = root root': the covariance of the difference between the fits with and without the
    candidate effect `label` of the free parameters `index` (scaled) under chance alone; `information` H = J'J of the
    scaled (whitened) free columns. Linear in the data's whitened noise e both estimates are A^-1 J'e, A = H + the
    priors' information as the fit adds it, and the one without the candidate the same on the other parameters
    (`rest`): the difference K J'e, K = A^-1 - pad(A_rest^-1), has covariance S = K H K'. Without priors that is
    Hausman's difference of the nested fits' covariances, A^-1 - pad(A_rest^-1); with them, not: A^-1 is the
    priors' spread where the data say nothing, which the estimates, held at the URDF there, do not have (link poses
    fitted from the cameras had a tracker's band of 340000 +- 390000 for actual rises of 100-700)."""
    from naocal.kinds.arm.identify import prior_sizes

    A = information.copy()
    if priors:
        size = prior_sizes(model)[index]
        A[np.diag_indices_from(A)] += np.where(size > 0, (model.scales[index] / np.where(size > 0, size, 1.0)) ** 2,
                                               0.0)
    rest = np.flatnonzero([model.parameters[i].effect != label for i in index])
    K = np.linalg.pinv(A)
    K[np.ix_(rest, rest)] -= np.linalg.pinv(A[np.ix_(rest, rest)])
    spread = K @ information @ K.T
    w, V = np.linalg.eigh((spread + spread.T) / 2)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _component_sensors(model, obs):
    """The sensor index of each measured component (whitened's rows)."""
    mask = model.component_mask(obs)
    return np.broadcast_to(obs.sensor[:, None], mask.shape)[mask]


def _rise_under_chance(B, r0, r1, sensor_rows, sensors) -> dict:
    """{sensor name: {"rise", "mean", "sd"}}: the rise |r1|^2 - |r0|^2 of each sensor's whitened residuals and its
    mean and sd when r1 = r0 + B z, z ~ N(0, I) (the candidate's estimation noise seen by the judged rows): the rise
    2 r0.B z + |B z|^2 has mean tr(B B') and variance 2 |B'B|^2 + 4 |B'r0|^2."""
    out = {}
    for s, sensor in enumerate(sensors):
        rows = sensor_rows == s
        Bs, a, b = B[rows], r0[rows], r1[rows]
        variance = 2.0 * float(np.sum((Bs.T @ Bs) ** 2)) + 4.0 * float(np.sum((Bs.T @ a) ** 2))
        out[sensor.name] = {"rise": float(b @ b - a @ a), "mean": float(np.sum(Bs ** 2)),
                            "sd": float(np.sqrt(variance))}
    return out


def session_chance(without, with_it, errors_without, errors_with, folds, label) -> dict:
    """chance_rise for the sessions' check: {sensor: {"rise", "mean", "sd"}} of the held-out sessions' whitened sum
    of squares from `without` to `with_it` (the fits on all the data; `errors_*` heldout_residuals over `folds` of
    their rows, the same rows). A fold's held-out rows are predicted by every free parameter fitted to the other
    rows, so the candidate's estimation noise reaches them through their whole Jacobian (nothing is refitted on
    them): per fold S from the training rows' information (linear about `with_it`'s fit on all the data), the rise's
    mean and sd as chance_rise's. The folds' training rows overlap (each shares all but two blocks with another), so
    their noises are correlated: the means add, and the sds are added too, the bound for fully correlated folds
    (the widest band, never narrower than the truth: no false refutation nor confirmation from assuming them
    independent)."""
    if not _same_rows(without.obs, with_it.obs):
        return {}
    model = with_it.model
    index, J = _free_jacobian(with_it)
    mask = model.component_mask(with_it.obs)
    w = 1.0 / with_it.sigma[with_it.obs.sensor][:, None]  # one noise for both: the rise is the residuals' alone
    r0, r1 = (errors_without * w)[mask], (errors_with * w)[mask]
    sensor_rows = _component_sensors(model, with_it.obs)
    out = {s.name: {"rise": 0.0, "mean": 0.0, "sd": 0.0} for s in model.sensors}
    for fold in folds:
        test = np.broadcast_to(fold[:, None], mask.shape)[mask]
        root = _candidate_spread(model, index, J[~test].T @ J[~test], label, with_it.priors)
        for name, c in _rise_under_chance(J[test] @ root, r0[test], r1[test], sensor_rows[test],
                                          model.sensors).items():
            for key in c:
                out[name][key] += c[key]
    return out


def session_folds(obs, n_blocks: int = SESSIONS) -> list:
    """Row masks of the sessions observations.csv names (its `session` column), each held out in turn; without
    one, of `n_blocks` blocks of consecutive poses in the file's order (a pose's place: its first row): sessions'
    stand-in, as a session's poses are measured together and share what drifts between sessions."""
    if obs.session is not None and len(np.unique(obs.session)) > 1:
        return [obs.session == k for k in np.unique(obs.session)]
    poses, first = np.unique(obs.pose, return_index=True)
    ordered = poses[np.argsort(first)]
    return [np.isin(obs.pose, block) for block in np.array_split(ordered, min(n_blocks, len(ordered)))]


def _unless_unfit(compute):
    """compute(), or None when its fit cannot be made (too few observations of a sensor or a fold, a combination
    the cameras alone leave undetermined): what the data cannot judge is not judged."""
    from naocal.solver.errors import DataError, SolveError

    try:
        return compute()
    except (DataError, SolveError):
        return None


def physical_checks(fit: ArmFit, candidates, sessions: int = SESSIONS) -> dict:
    """Fill each significant candidate's `checks` (HeldOutCheck: each of `cross_checks`, other sessions); returns
    {label: its fit on all the data} for the candidates judged."""
    model = fit.model
    judged = [c for c in candidates if c.significant]
    if not judged:
        return {}
    folds = session_folds(fit.obs, sessions) if sessions > 1 else []
    named = fit.obs.session is not None and len(np.unique(fit.obs.session)) > 1
    how_sessions = (f"{len(folds)} sessions (observations.csv's session column) held out in turn" if named else
                    f"{len(folds)} blocks of consecutive poses held out in turn (the dataset has no session column: "
                    "they stand in for sessions)")

    def session_errors(fit_):  # the blocks of fit_'s own rows: a refit may set other detections aside
        return heldout_residuals(fit_, session_folds(fit_.obs, sessions))

    names = [sensor.name for sensor in model.sensors]
    base_errors = _unless_unfit(lambda: session_errors(fit)) if len(folds) > 1 else None
    crosses = [(kind, a, b, _unless_unfit(lambda: cross_sensor_fits(fit, model.effects, (), a, b)))
               for kind, a, b in cross_checks(model)]
    fits = {}
    rms = fit.rms()
    shown = [s.name for s in model.sensors if s.kind == "camera"] or list(rms)
    reflectors = any(f for p, f in zip(model.parameters, fit.free) if p.effect == "points")
    intrinsics = "intrinsics" in model.effects
    for c in judged:
        c.pixels = {s: [rms[s], c.predicted_rms[s]] for s in shown}
        effects = model.effects + (c.label,)
        for kind, fitted_from, judged_by, without in crosses:
            with_it = without and _unless_unfit(lambda: cross_sensor_fits(fit, effects, c.inert, fitted_from,
                                                                          judged_by))
            if with_it:
                what = ({"sensor": " and reflectors", "reverse": " and markers"}.get(kind, "") if reflectors
                        else "") + (" and intrinsics" if intrinsics and kind != "sensor" else "")
                how = (f"{', '.join(names[s] for s in judged_by)} with the arm fitted from "
                       f"{', '.join(names[s] for s in fitted_from)} alone, then held (its frame{what} refitted)")
                c.checks.append(HeldOutCheck(kind, how, without[1].rms(), with_it[1].rms(),
                                             chance_rise(without[1], *with_it, c.label)))
        refit = None if base_errors is None else _unless_unfit(lambda: refit_with(fit, effects, held=c.inert))
        errors = _unless_unfit(lambda: session_errors(refit)) if refit else None
        if errors is None:
            continue
        # The refit may set aside more detections (a better model shows more outliers): the model without the
        # candidate is then held out on the refit's rows too, so both sides and the chance bound see the same rows.
        base, base_errors_here = ((fit, base_errors) if _same_rows(fit.obs, refit.obs) else
                                  (replace(fit, obs=refit.obs), None))
        if base_errors_here is None:
            base_errors_here = _unless_unfit(lambda: session_errors(base))
            if base_errors_here is None:
                continue
        fits[c.label] = refit
        c.checks.append(HeldOutCheck("session", how_sessions, sensor_rms(model, base.obs, base_errors_here),
                                     sensor_rms(refit.model, refit.obs, errors),
                                     session_chance(base, refit, base_errors_here, errors,
                                                    session_folds(refit.obs, sessions), c.label)))
    return fits


@dataclass
class ArmDiagnosis:
    fit: ArmFit
    rms: dict
    noise: dict
    noise_known: dict
    worst_poses: list
    location: list
    candidates: list
    threshold: float
    heldout: dict
    heldout_with: dict  # the best candidate's held-out RMS when added (empty if none)

    @property
    def best(self):
        """The best significant candidate the held-out checks do not refute (fits the pixels only): a confirmed one
        if there is one (the candidates' order)."""
        return next((c for c in self.candidates if c.significant and c.physical is not False), None)

    @property
    def refuted(self):
        """The significant candidates that fit the pixels only (a held-out check worse with them)."""
        return [c for c in self.candidates if c.significant and c.physical is False]

    def as_dict(self):
        return {"effects": list(self.fit.model.effects), "rms": self.rms, "noise": self.noise,
                "noise_known": self.noise_known, "worst_poses": self.worst_poses,
                "location": [t.as_dict() for t in self.location],
                "candidates": [t.as_dict() for t in self.candidates], "threshold": self.threshold,
                "heldout": self.heldout, "heldout_with_best": self.heldout_with,
                "verdict": None if self.best is None else self.best.label,
                "fits_the_pixels_only": [c.label for c in self.refuted],
                "verdict_confirmed": None if self.best is None else self.best.confirmed,
                "not_confirmed": {c.label: not_confirmed_text(c, self.fit.model)
                                  for c in self.candidates if c.not_confirmed_by},
                "fixed": self.fit.fixed_reasons}


def diagnose(fit: ArmFit, n_folds: int = 5, *, physical: bool = True, sessions: int = SESSIONS) -> ArmDiagnosis:
    """n_folds: the held-out poses' folds (0: none); physical: judge the significant candidates on held-out data
    (`physical_checks`; sessions: how many blocks of consecutive poses, 0: none)."""
    model, obs = fit.model, fit.obs
    candidates = score_tests(fit, candidate_groups(fit))
    threshold = FAMILY_ALPHA / max(1, sum(1 for c in candidates if c.k > 0))
    for c in candidates:
        c.significant = c.k > 0 and c.p_value < threshold
    # Ranked by what they explain less (1 + log M) times what they would take from the errors alone (BIC, with
    # the pose-correlated errors' share instead of 1 per parameter): of two that explain the misfit alike, the
    # smaller wins (link poses hold the link lengths and fit 13 more noise parameters on the panda).
    penalty = 1.0 + math.log(max(2, int(model.component_mask(obs).sum())))
    candidates.sort(key=lambda c: (not c.significant, not c.testable, -(c.drss - penalty * c.noise_rss)))
    location = score_tests(fit, location_groups(fit))
    location.sort(key=lambda t: (t.k == 0, -(t.drss - penalty * t.noise_rss)))
    # worst poses by whitened RMS
    r = (fit.residual / fit.sigma[obs.sensor][:, None]) ** 2
    mask = model.component_mask(obs)
    per_pose = []
    for pose in np.unique(obs.pose):
        rows = obs.pose == pose
        per_pose.append((float(np.sqrt(r[rows][mask[rows]].mean())), int(pose)))
    per_pose.sort(reverse=True)
    heldout = heldout_rms(fit, n_folds) if n_folds > 1 else {}
    fits = physical_checks(fit, candidates, sessions) if physical else {}
    # A confirmed candidate before one that is not, before a refuted one (stable: each in the order above).
    candidates.sort(key=lambda c: (not c.significant, c.standing))
    heldout_with = {}
    best = next((c for c in candidates if c.significant and c.physical is not False), None)
    if best is not None and n_folds > 1:
        bigger = fits.get(best.label) or refit_with(fit, model.effects + (best.label,), held=best.inert)
        heldout_with = heldout_rms(bigger, n_folds)
    return ArmDiagnosis(fit, fit.rms(), {s.name: float(fit.sigma[i]) for i, s in enumerate(model.sensors)},
                        {s.name: bool(fit.noise_known[i]) for i, s in enumerate(model.sensors)},
                        [{"pose": obs.pose_name(p), "rms_sigma": v} for v, p in per_pose[:5]], location, candidates, threshold,
                        heldout, heldout_with)


def _shown_value(name, value, units) -> str:
    from naocal.solver.effect import shown

    v, unit = shown(value, units.get(name, "1"))
    return f"{v:+.4g} {unit}".rstrip()


def _held_options(fit: ArmFit) -> str:
    """The options that reproduce what the fit held: the user's --fix (NAME, or NAME=VALUE in display units; not the
    gauges, which identify finds again) and --no-priors."""
    from naocal.solver.effect import shown

    out = ""
    for i, p in enumerate(fit.model.parameters):
        if not fit.free[i] and p.name not in fit.fixed_reasons:
            value = shown(fit.x[i], p.unit)[0]
            out += f" --fix {p.name}" + (f"={value:.6g}" if fit.x[i] != 0.0 else "")
    return out + ("" if fit.priors else " --no-priors")


def not_confirmed_text(c: Test, model) -> str:
    """'not confirmed by tracker: no better, 0.465 mm -> 0.468 mm; ...' ('' if nothing to say)."""
    kinds = {s.name: s.kind for s in model.sensors}
    said = [f"{s}{' (sessions held out)' if check.kind == 'session' else ''}: {check.word(s)}, "
            f"{shown_rms(check.without[s], kinds[s])} -> {shown_rms(check.with_effect[s], kinds[s])}"
            for check, s in c.not_confirmed_by]
    return "not confirmed by " + "; ".join(said) if said else ""


def format_diagnosis(d: ArmDiagnosis, dataset_label="DATASET") -> str:
    fit, model = d.fit, d.fit.model
    units = {p.name: p.unit for p in extended(fit)[0].parameters}
    kinds = {s.name: s.kind for s in model.sensors}
    lines = [f"model: sensor frames + {' + '.join(model.effects) or 'nothing'}; {len(fit.obs)} observations in "
             f"{len(np.unique(fit.obs.pose))} poses", "", "COMPARE"]
    for s in model.sensors:
        ratio = d.rms[s.name] / d.noise[s.name]
        source = "stated by the dataset" if d.noise_known[s.name] else "estimated from the fit"
        lines.append(f"  {s.name:10s} RMS {shown_rms(d.rms[s.name], s.kind)} per axis; noise "
                     f"{shown_rms(d.noise[s.name], s.kind)} ({source}); {ratio:.2f} x the noise")
    if d.heldout:
        lines.append("  held-out poses (5-fold, whole poses): " + "; ".join(
            f"{s} nominal {shown_rms(v['nominal'], kinds[s])} -> calibrated {shown_rms(v['calibrated'], kinds[s])}"
            for s, v in d.heldout.items()))
    lines.append("  worst poses: " + ", ".join(f"{w['pose']} ({w['rms_sigma']:.2f} sigma)" for w in d.worst_poses))
    lines += ["", "LOCATE (misfit a joint's or a link's missing parameters would explain; dRSS in noise variances)"]
    for t in d.location[:6]:
        lines.append(f"  {t.label:32s} dRSS {t.drss:10.1f} on {t.k} dof  p {t.p_value:.1e}")
    lines += ["", f"NAMES (candidate effects, best first; significant: p < {d.threshold:.1e}, i.e. "
                  f"{FAMILY_ALPHA} over {sum(1 for c in d.candidates if c.k > 0)} tests)"]
    for c in d.candidates:
        predicted = ", ".join(f"{s} {shown_rms(v, kinds[s])}" for s, v in c.predicted_rms.items())
        top = sorted(c.values.items(), key=lambda kv: -abs(kv[1]))[:3]
        values = ", ".join(f"{n} {_shown_value(n, v, units)}" for n, v in top)
        lines.append(f"  {c.label:14s} dof {c.k:3d}  dRSS {c.drss:10.1f}  p {c.p_value:8.1e}  "
                     f"{'yes' if c.significant else 'no ' if c.testable else 'n/a':3s}  uniqueness {c.uniqueness:.3f}  predicted {predicted}"
                     + (f"; {values}" if c.significant else ""))
    untestable = [c.label for c in d.candidates if not c.testable]
    if untestable:
        lines.append(f"n/a: {', '.join(untestable)}: more directions than the {len(np.unique(fit.obs.pose))} poses "
                     "can judge (significance counts poses): measure more poses to test them")
    for name, reason in fit.fixed_reasons.items():
        lines.append(f"fixed: {name}: {reason}")
    judged = [c for c in d.candidates if c.checks]
    if judged:
        lines += ["", "PHYSICAL? (each significant candidate on data its fit did not see, which the pixels cannot fool; "
                      f"worse: more than {HELDOUT_TOLERANCE:.0%} up)"]
    for c in judged:
        lines.append(f"  {c.label}: pixels " + ", ".join(
            f"{s} {shown_rms(before, kinds[s])} -> {shown_rms(after, kinds[s])}" for s, (before, after) in
            c.pixels.items()))
        for check in c.checks:
            change = "; ".join(f"{s} {shown_rms(check.without[s], kinds[s])} -> "
                               f"{shown_rms(check.with_effect[s], kinds[s])} "
                               f"({check.word(s)})"
                               for s in check.with_effect)
            lines.append(f"    held-out {check.how}: {change}")
        unconfirmed = not_confirmed_text(c, model)
        if c.physical is False:
            lines.append(f"    -> {c.refutation}: not recommended" + (f"; {unconfirmed}" if unconfirmed else ""))
        elif c.confirmed:
            lines.append("    -> physical: confirmed by " + ", ".join(
                sorted({s for check in c.deciding for s in check.better})) + " (better beyond chance)")
        else:
            lines.append(f"    -> not refuted, {unconfirmed or 'not confirmed'}: it may fit the pixels only "
                         "(proposed after any confirmed candidate)")
    best = d.best
    lines.append("")
    if best is None and d.refuted:
        lines.append("verdict: no physical candidate: " + "; ".join(f"{c.label} {c.refutation}" for c in d.refuted)
                     + ": not recommended" + ("; check the cameras' intrinsics and where the markers sit on the tool"
                                              if any(c.refutation.startswith(("fits the pixels", "fits one camera"))
                                                     for c in d.refuted) else "")
                     + ("; check where the reflectors sit on the tool" if any(
                         c.refutation.startswith("fits the 3-D sensor") for c in d.refuted) else ""))
    elif best is None:
        lines.append("verdict: no candidate effect is significant; nothing is missing from the model"
                     + (" (the fit is at the noise level)." if all(
                         d.rms[s] < 1.5 * d.noise[s] for s in d.rms) else
                        " among these candidates (the misfit above the noise is something else)."))
    else:
        lines.append(f"verdict: add {best.label}: naocal identify {dataset_label} --effects "
                     f"{','.join(model.effects + (best.label,))}" + "".join(f" --fix {n}" for n in best.inert)
                     + _held_options(fit) + " --out calibration.json")  # identify writes with --out
        if d.refuted:
            lines.append("  (the best physical candidate; not recommended: "
                         + "; ".join(f"{c.label} {c.refutation}" for c in d.refuted) + ")")
        if best.confirmed is False:
            lines.append(f"  (not confirmed: no significant candidate is better beyond chance on held-out data its "
                         f"fit did not see; {best.label} may fit the pixels only)")
        if d.heldout_with:
            lines.append("  held-out poses with it: " + "; ".join(
                f"{s} {shown_rms(v['calibrated'], kinds[s])}" for s, v in d.heldout_with.items()))
    lines += [f"  {c.label} {not_confirmed_text(c, model)}" for c in d.candidates if c.significant and
              c.not_confirmed_by]  # what the pixels say and held-out data do not confirm
    return "\n".join(lines)
