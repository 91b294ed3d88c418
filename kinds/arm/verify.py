"""Is an arm's calibration still good? The residuals of new data under a calibration's fixed values (docs/ARM.md).

What identify sets aside (kinds.arm.identify.fit's robust trimming: detections no model explains, a corner
mistaken) is set aside first, by identify's own rule, decided against a refit of every calibrated parameter so
that a drift, which the refit follows, is never set aside; as the NAO's verify (solver/verify.py). Left in, 2 % of
corners wrong by 8-40 px made an unchanged dual arm's camera RMS 3-10 times the calibration's (its RMS is over the
detections identify kept). The verdict and statistics are on the detections kept; those set aside are listed.

The arm's parameters are the calibration's and are not refitted. The sensors' frames are found from the new data
(6 parameters per sensor, the arm's fixed): they belong to the setup, and a tracker or camera set up again stands
elsewhere. Each sensor's RMS is compared with a reference, the larger of the calibration's own RMS for that sensor
and the new data's noise floor (dataset.json's noise_m / noise_px, else the RMS of a refit of every calibrated
parameter on the new data). The verdict is the NAO's rule (solver.verify.still_good): drifted beyond DRIFT_RATIO
times it, or when a calibrated parameter moved: named by the NAO's forward score tests from the calibration's values
(solver.verify.forward_changes; the sensors' frames and nuisances refitted with each), a change of DRIFT_Z standard
deviations and DRIFT_MIN_SCALE of its typical size. As the NAO's, with sensors for cameras and poses for images.

Nuisance parameters (`refit`, --refit sensors,points,intrinsics): what belongs to the new data's setup rather than
to the arm, refitted with the calibration's arm held, e.g. where a laser tracker's reflector sits on the tool, so that
a calibration made from cameras can be checked on a tracker's data (its frame and reflector unknown), or the
cameras' intrinsics of a new session (refocused, warmed up); the verdict is on the residual of that refit. A nuisance
the new data cannot determine (the identifiability check fixes it: it changes no prediction, or the data cannot
tell it from the sensors' frames) is refused, naming it: its "refit" would be its start value. The calibration's
intrinsics of a camera the new data lack (a tracker's data) belong to that camera, not to the arm: unused. They are never among what moved. A nuisance can hide a wrong arm (a reflector moved
by 17 mm carries a flange turned by 10 deg), so what the refit absorbed is reported against the nuisances' prior
(the plausible size of where a reflector is glued: the points effect's prior_size): beyond it
(`absorbed_beyond_prior`) the verdict cannot be good. Nor when the refitted points of one tool moved together
beyond what an unchanged robot leaves (`tools_moved_together`): that is the tool's mount, an arm error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from naocal.solver.errors import DataError, NaocalError
from naocal.solver.verify import (DRIFT_MIN_SCALE, DRIFT_RATIO, WORST_IMAGES, forward_changes, moved_text,
                                   still_good, verdict_text)

UNIT = {"points": "m", "camera": "px"}


@dataclass
class ArmVerdict:
    good: bool
    verdict: str
    per_sensor: dict  # sensor -> statistics (its unit), calibration RMS, noise floor, reference, ratio
    per_pose: list  # [{"pose", "rms_reference", "n"}]: each pose's RMS in units of its sensors' reference
    ratio: float  # the largest sensor ratio
    refitted: list  # the nuisance parameters refitted beside the sensors' frames: {"parameter", "value", "std", "unit"}
    absorbed: dict | None  # what the refitted nuisances took up against their prior (`absorbed_beyond_prior`); None
    moved: list
    suspects: list
    worst_poses: list
    uncalibrated: list
    warnings: list = field(default_factory=list)
    outliers: list = field(default_factory=list)  # [kinds.arm.identify.ArmOutlier]: set aside, as identify does
    together: list = field(default_factory=list)  # tools_moved_together (with --refit points)

    def as_dict(self) -> dict:
        return {"good": self.good, "verdict": self.verdict, "per_sensor": self.per_sensor, "per_pose": self.per_pose,
                "ratio": self.ratio, "drift_ratio": DRIFT_RATIO, "refitted": self.refitted, "absorbed": self.absorbed,
                "moved": self.moved,
                "suspects": self.suspects,
                "worst_poses": self.worst_poses, "uncalibrated": self.uncalibrated, "warnings": self.warnings,
                "outliers": [o.as_dict() for o in self.outliers], "together": self.together}


def error_statistics(residual: np.ndarray, kind: str) -> dict:
    """{"n", "rms" (per axis, as identify), "median", "p95", "max" (of each observation's error distance)} in the
    sensor's unit (m or px)."""
    e = residual[:, :3] if kind == "points" else residual[:, :2]
    if not len(e):
        return {"n": 0, "rms": None, "median": None, "p95": None, "max": None, "unit": UNIT[kind]}
    distance = np.linalg.norm(e, axis=1)
    return {"n": int(len(e)), "rms": float(np.sqrt(np.mean(e ** 2))), "median": float(np.median(distance)),
            "p95": float(np.percentile(distance, 95)), "max": float(distance.max()), "unit": UNIT[kind]}


def check_same_arm(cal, dataset) -> None:
    """DataError (naming the calibration file) unless it is of the dataset's chain and arm."""
    for key, ours in (("base", dataset.base), ("tip", dataset.tip)):
        if cal.robot.get(key) != ours:
            raise DataError(cal.path, f"the calibration is of the chain's {key} {cal.robot.get(key)!r}, the dataset "
                                      f"of {ours!r}", field=f"robot.{key}")
    theirs = str(dataset.meta.get("robot", {}).get("id", "unknown"))
    ours = cal.robot.get("id", "unknown")
    if "unknown" not in (ours, theirs) and ours != theirs:
        raise DataError(cal.path, f"the calibration is of arm {ours!r}, the dataset of {theirs!r}: another arm's "
                                  "calibration", field="robot.id")


# What --refit may name: the sensors' frames (always refitted) and effects of the setup rather than the arm.
NUISANCE_EFFECTS = ("points", "intrinsics")


def of_absent_sensors(cal, model) -> list:
    """The calibration's parameters of its sensors that `model` lacks (a camera's intrinsics on a tracker's data):
    they belong to that sensor, not to the arm."""
    absent = {s for s in (*cal.rms, *cal.noise) if s not in {sensor.name for sensor in model.sensors}}
    return [n for n in cal.arm_parameters if n.startswith("intrinsics.") and any(
        n.startswith(f"intrinsics.{s}.") for s in absent)]


def undetermined_nuisances(fit_, nuisance, held=()) -> None:
    """SolveError naming the first of the refitted `nuisance` parameters that the identifiability check of `fit_`
    fixed although it moves these data's predictions (the data cannot tell it from others: its refit would be its
    start value), unless the user held it. One that moves none (a marker the tracker never sees) is no matter."""
    from naocal.kinds.arm.identify import whitened
    from naocal.solver.errors import SolveError

    lost = [n for n in nuisance if n in fit_.fixed_reasons and n not in held]
    if lost:
        _, J = whitened(fit_.model, fit_.obs, fit_.x, fit_.sigma, jacobian=True)
        moves = np.linalg.norm(J, axis=0) > 0
        lost = [n for n in lost if moves[fit_.model.names.index(n)]]
    if lost:
        why = fit_.fixed_reasons[lost[0]].partition("; fixed at")[0]  # identify's reason, less what identify does
        raise SolveError(f"--refit: these data cannot determine {lost[0]} ({len(lost)} such; {why}): hold it "
                         f"(--fix {lost[0]}[=VALUE]) or verify on data that determine it")


def nuisance_fit(model, obs, values: dict, refit_effects=(), *, held=(), priors: bool = True, path="dataset"):
    """The ArmFit of the sensors' frames and the `refit_effects` (NUISANCE_EFFECTS) to `obs`, the arm's other
    parameters held at `values` ({name: SI}, the URDF's where missing; also where the nuisances start); `held`
    nuisance names held too. Every detection of `obs` kept: what identify sets aside is decided before, against a
    refit (verify_arm), never against the held arm, whose drift would be set aside with the mis-detections."""
    from naocal.kinds.arm.identify import fit, initialise_sensors

    x0 = initialise_sensors(model, obs, path, {n: v for n, v in values.items() if n in model.names})
    arm = tuple(p.name for p in model.parameters if p.effect != "sensors" and p.effect not in refit_effects)
    return fit(model, obs, x0, fixed=arm + tuple(held), path=path, robust=False, priors=priors)


def absorbed_beyond_prior(fit_, names) -> dict | None:
    """What the refitted nuisances `names` (the free ones) of the nuisance fit `fit_` absorbed, against their prior
    N(0, plausible size) (kinds.arm.identify.prior_sizes; 0: where dataset.json puts them): {"size" (per
    parameter, in plausible sizes), "chi2" (sum of their squares), "bound" (its 1 - FAMILY_ALPHA quantile with as
    many degrees of freedom: what gluing errors as plausible as the prior says leave), "beyond"}; None if none is
    refitted. Beyond the bound the nuisances carry more than the setup explains: an arm error hides in them."""
    from scipy.stats import chi2

    from naocal.solver.diagnostics import FAMILY_ALPHA
    from naocal.kinds.arm.identify import prior_sizes

    size = prior_sizes(fit_.model)
    index = [i for i, n in enumerate(fit_.model.names) if n in names and fit_.free[i] and size[i] > 0]
    if not index:
        return None
    z = {fit_.model.names[i]: float(fit_.x[i] / size[i]) for i in index}
    total = float(sum(v * v for v in z.values()))
    bound = float(chi2.ppf(1.0 - FAMILY_ALPHA, len(index)))
    return {"size": z, "chi2": total, "bound": bound, "beyond": total > bound}


def tools_moved_together(fit_, values: dict, located=()) -> list:
    """What the refitted points (`fit_`'s free point.* parameters) moved TOGETHER on each tool, judged: [{"tool",
    "translation" (m, at the tool's origin), "rotation" (rad), "shift" (m: the largest shift it gives a marker's
    centre), "chi2", "bound", "beyond"}], one per tool with two bodies or more refitted (with one, its gluing and the
    mount are one motion).

    The points nuisance is each marker's own gluing error, independent per marker; a motion all the markers of one tool
    share is the tool's mount moving: an arm error, which the points would absorb whole (a 1 mm knock is 1 mm of
    each marker's 3 mm prior: chi2 4 of a bound of 99.6, "still good"). So each tool's refitted shifts, from where the
    calibration located its markers (`values`; 0 for those it did not, a tracker's reflectors), are split by least
    squares into the rigid 6-DoF motion of the tool best explaining them and the rest, and that common motion is
    tested (chi2, 6 degrees of freedom, FAMILY_ALPHA) against what it may be unchanged: the new data's uncertainty of
    it (this fit's covariance, the sensors' frames and the other points refitted with it) plus, for markers the
    calibration never `located`, the common part of independent gluing errors of their prior size. The markers the
    calibration located are taken where it put them: its file holds their marginal stds only (1.4 mm here), which
    the tool / points split it resolves by priors alone dominates, while where they sit on the flange is far better
    known. Why this rather than refitting the points under the constraint that they not move together: the same
    test on the reflectors the calibration never located (their common part IS unknown, bounded by the gluing prior),
    no constraint in the fit, and the verdict names the tool."""
    from scipy.stats import chi2

    from naocal.kinds.arm.identify import prior_sizes, whitened
    from naocal.solver.diagnostics import FAMILY_ALPHA
    from naocal.solver.transforms import skew

    model, obs = fit_.model, fit_.obs
    size = prior_sizes(model)
    free = np.flatnonzero(fit_.free)
    _, J = whitened(model, obs, fit_.x, fit_.sigma, jacobian=True)
    J = J[:, free]
    information = J.T @ J
    if fit_.prior_std is not None:
        prior = fit_.prior_std[free]
        information[np.diag_indices(len(free))] += np.where(prior > 0, 1.0 / np.where(prior > 0, prior, 1.0) ** 2, 0.0)
    covariance = np.linalg.pinv(information)
    where = {i: k for k, i in enumerate(free)}
    chain = np.zeros(len(obs), int) if obs.chain is None else obs.chain
    out = []
    for c, ac in enumerate(model.arm_chains):
        bodies = sorted({int(model.point_body[p]) for p in np.unique(obs.point[chain == c])})
        rows, index, before = [], [], []
        for i, p in enumerate(model.parameters):
            if p.effect != "points" or p.index not in bodies or i not in where:
                continue
            centre = model.point_xyz[model.point_body == p.index].mean(axis=0)
            L = np.zeros(6)
            if p.axis < 3:  # the body's translation: t + w x centre
                L[p.axis] = 1.0
                L[3:] = -skew(centre)[p.axis]
            else:  # its turn: w
                L[p.axis] = 1.0
            rows.append(L)
            index.append(i)
            before.append(0.0 if p.name in located else size[i])
        if len({model.parameters[i].index for i in index}) < 2:
            continue
        L, k = np.array(rows), [where[i] for i in index]
        change = fit_.x[index] - np.array([values.get(model.names[i], 0.0) for i in index])
        weight = 1.0 / np.array([size[i] for i in index]) ** 2  # each shift in units of its plausible size
        solve = np.linalg.pinv(L.T @ (weight[:, None] * L)) @ (L.T * weight)  # (6, n): the common motion's LS
        common = solve @ change
        spread = solve @ (covariance[np.ix_(k, k)] + np.diag(np.array(before) ** 2)) @ solve.T
        statistic = float(common @ np.linalg.pinv(spread) @ common)
        rank = int(np.linalg.matrix_rank(spread))
        centres = np.array([model.point_xyz[model.point_body == b].mean(axis=0) for b in bodies])
        shift = float(max(np.linalg.norm(common[:3] + np.cross(common[3:], x)) for x in centres))
        bound = float(chi2.ppf(1.0 - FAMILY_ALPHA, rank))
        out.append({"tool": ac.name, "translation": common[:3].tolist(), "rotation": common[3:].tolist(),
                    "shift": shift, "chi2": statistic, "bound": bound, "beyond": statistic > bound})
    return out


def verify_arm(dataset, cal, *, refit_effects=(), priors: bool = True, held=(), start=None) -> ArmVerdict:
    """The verdict of the calibration `cal` (kinds.arm.calibration) on `dataset` (kinds.arm.dataset).

    refit_effects : NUISANCE_EFFECTS refitted from the new data beside the sensors' frames, the arm held.
    priors : the nuisance parameters' priors (kinds.arm.identify.arm_prior).
    held, start : nuisance parameters held, and {name: SI value} to start them from (--fix NAME[=VALUE]).
    """
    from naocal.kinds.arm.identify import fit, model_for

    check_same_arm(cal, dataset)
    model = model_for(dataset, tuple(cal.effects) + tuple(e for e in refit_effects if e not in cal.effects))
    obs = dataset.observations
    meta_path = dataset.path / "dataset.json"
    nuisance = [p.name for p in model.parameters if p.effect in refit_effects]
    for effect in refit_effects:
        if not model.params(effect):
            raise NaocalError(f"--refit {effect}: {meta_path} has nothing it refits (sensors: "
                              f"{', '.join(s.name + ' (' + s.kind + ')' for s in model.sensors)})")
    arm_names = [n for n in model.names if not n.startswith("sensor.") and n not in nuisance]
    unused = of_absent_sensors(cal, model)
    foreign = [n for n in cal.arm_parameters if n not in model.names and n not in unused]
    if foreign:
        raise DataError(cal.path, f"{foreign[0]} is not a parameter of the dataset's chain ({len(foreign)} such): "
                                  "another arm's calibration", field=f"model.parameters.{foreign[0]}")
    missing = [n for n in arm_names if n not in cal.parameters]
    values = {n: e["value"] for n, e in cal.arm_parameters.items() if n not in unused}
    values.update(start or {})
    # 1. the calibration as it is on every detection: the sensors' frames (and nuisances) to start the refit from
    start_fit = nuisance_fit(model, obs, values, refit_effects, held=held, priors=priors, path=meta_path)
    undetermined_nuisances(start_fit, nuisance, held)
    # 2. a refit of what the calibration fitted, setting aside what identify sets aside (decided against the refit,
    # which follows a drift: a drift is never set aside); the noise floor (when the data state none) and what moved
    kept_fixed = tuple(n for n in arm_names if n in cal.parameters and cal.parameters[n]["fixed"]) + tuple(missing)
    refit = fit(model, obs, start_fit.x, fixed=kept_fixed + tuple(held), path=meta_path, robust=True, priors=priors)
    # 3. the calibration as it is on the detections kept: the verdict's residuals
    obs = refit.obs
    fixed = nuisance_fit(model, obs, values, refit_effects, held=held, priors=priors, path=meta_path)

    per_sensor, reference = {}, np.zeros(len(model.sensors))
    refit_rms = refit.rms()
    for s, sensor in enumerate(model.sensors):
        rows = obs.sensor == s
        stats = error_statistics(fixed.residual[rows], sensor.kind)
        own = cal.rms.get(sensor.name)
        calibration_rms = own[0] if own is not None and own[1] == UNIT[sensor.kind] else None
        if sensor.noise is not None:
            floor, source = sensor.noise, "dataset"
        else:
            m = int(model.component_mask(obs)[rows].sum())
            p = int(refit.free.sum())  # shared by the sensors: a conservative share each
            floor, source = refit_rms[sensor.name] * math.sqrt(m / max(1, m - p)), "refit"
        reference[s] = max(calibration_rms or 0.0, floor)
        ratio = stats["rms"] / reference[s] if reference[s] > 0 else math.inf
        per_sensor[sensor.name] = {**stats, "calibration_rms": calibration_rms, "noise_floor": float(floor),
                                   "noise_source": source, "reference": float(reference[s]), "ratio": float(ratio)}
    ratio = max(v["ratio"] for v in per_sensor.values())
    absorbed = absorbed_beyond_prior(fixed, nuisance)
    # the points the calibration fitted (one its data never saw, a tracker's reflector in a camera calibration, it
    # fixed: that changes no prediction)
    located = {n for n, e in cal.parameters.items() if n.startswith("point.") and not e["fixed"]}
    together = tools_moved_together(fixed, values, located) if "points" in refit_effects else []

    mask = model.component_mask(obs)
    scaled = (fixed.residual / reference[obs.sensor][:, None]) ** 2
    per_pose = []
    for pose in np.unique(obs.pose):
        rows = obs.pose == pose
        per_pose.append({"pose": obs.pose_name(pose), "rms_reference": float(np.sqrt(scaled[rows][mask[rows]].mean())),
                         "n": int(rows.sum())})
    worst = sorted((e for e in per_pose if e["rms_reference"] > DRIFT_RATIO), key=lambda e: -e["rms_reference"])

    # what moved: the NAO's forward score tests (solver.verify.forward_changes) from the calibration's values, the
    # sensors' frames and nuisances refitted with each candidate. A refit of every calibrated parameter at once
    # shares a change among its correlated neighbours (30 poses of the dual arm: right_j2 moved 0.04 deg, ratio
    # 1.41, refitted at 2.5 of its standard deviations), as the NAO's docstring says of the leg's pitch joints.
    from naocal.kinds.arm.identify import ArmEquations, prior_sizes
    from naocal.solver.effect import shown
    from naocal.solver.identify import Prior

    candidate = refit.free & np.array([p.effect != "sensors" and p.name not in nuisance for p in model.parameters])
    equations = ArmEquations(model, obs, fixed.x, fixed.free | candidate, fixed.sigma)
    # the nuisances under their prior, as the fit the tests start from put them (its gradient is nil only with it);
    # the candidates under none: theirs is about the URDF, and would pull them from the calibration's values
    size = prior_sizes(model)[equations.index]
    held_about = np.flatnonzero(np.isin(np.array(model.names)[equations.index], nuisance) & (size > 0) & priors)
    prior = Prior(held_about, np.zeros(len(held_about)), size[held_about])

    def normal_at(free):
        return prior.added(equations(free), free, equations.scales)

    mask = model.component_mask(obs)
    moved = []
    for k, change, std, z in forward_changes(normal_at, equations.scales, fixed.x[equations.index], int(mask.sum()),
                                             np.unique(obs.pose, return_inverse=True)[1].reshape(-1),
                                             np.flatnonzero(fixed.free[equations.index])):
        p = model.parameters[equations.index[k]]
        if abs(change) >= DRIFT_MIN_SCALE * p.scale:
            moved.append({"parameter": p.name, "group": _group(p.name), "change": change, "std": std, "z": z,
                          "unit": p.unit, "display": list(shown(change, p.unit)), "size": abs(change) / p.scale})
    moved.sort(key=lambda e: -e["size"])
    suspects = list(dict.fromkeys([e["group"] for e in moved] + [f"tool {e['tool']}" for e in together if e["beyond"]]))
    good = still_good(ratio, moved) and not (absorbed and absorbed["beyond"]) and not any(
        e["beyond"] for e in together)

    warnings = []
    if unused:
        warnings.append(f"the calibration's {', '.join(sorted({n.rsplit('.', 1)[0] for n in unused}))} belong to "
                        "sensors these data lack: unused")
    held_by_prior = [n for n in fixed.held_by_prior if n in nuisance]
    if held_by_prior:
        warnings.append(f"{len(held_by_prior)} refitted nuisance(s) held by their prior, the data hardly inform them "
                        f"({', '.join(held_by_prior[:6])}{' ...' if len(held_by_prior) > 6 else ''}): near their "
                        "filed values")
    if missing:
        warnings.append(f"the calibration has no value for {len(missing)} parameter(s) of these data "
                        f"({', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}): taken as 0 (nominal)")
    for name, v in per_sensor.items():
        if v["calibration_rms"] is None:
            warnings.append(f"sensor {name}: the calibration has no RMS of it; compared with the noise floor only")
    head = "; ".join(f"{name} RMS {_shown(v['rms'], v['unit'])} (reference {_shown(v['reference'], v['unit'])}, "
                     f"ratio {v['ratio']:.2f})" for name, v in per_sensor.items())
    if absorbed and absorbed["beyond"]:
        largest = max(absorbed["size"], key=lambda n: abs(absorbed["size"][n]))
        head += (f"; but the refitted nuisances absorbed beyond their prior (chi2 {absorbed['chi2']:.1f} over a bound "
                 f"of {absorbed['bound']:.1f}; {largest} {absorbed['size'][largest]:+.1f} plausible sizes): an arm error "
                 "can hide there; measure where they sit (--fix NAME=VALUE) or verify on data with them known")
    for e in together:
        if e["beyond"]:
            head += f"; but {together_text(e)}"
    verdict = verdict_text(good, head, moved, suspects, "an effect the calibration lacks, a moved tool, or bad "
                                                        "readings")
    entries = fixed.parameters_dict()
    refitted = [{"parameter": n, "value": entries[n]["value"], "std": entries[n]["std"], "unit": entries[n]["unit"],
                 "fixed": entries[n]["fixed"]} for n in nuisance if n in held or not entries[n]["fixed"]]
    return ArmVerdict(good, verdict, per_sensor, per_pose, float(ratio), refitted, absorbed, moved, suspects,
                      worst[:WORST_IMAGES], missing, warnings, refit.outliers, together)


def together_text(entry: dict) -> str:
    """One tool whose markers moved together (tools_moved_together), as verify prints it."""
    return (f"the markers of tool {entry['tool']} moved together by {entry['shift'] * 1e3:.2f} mm (chi2 "
            f"{entry['chi2']:.1f} over a bound of {entry['bound']:.1f}): the tool mount moved")


def _group(name: str) -> str:
    kind, rest = name.split(".", 1)
    if kind in ("joint_offset", "elasticity"):
        return f"joint {rest}"
    if kind in ("link_length", "link_pose"):
        return f"link {rest.rsplit('.', 1)[0] if kind == 'link_pose' else rest}"
    return "tool points" if kind == "point" else kind


def _shown(value, unit) -> str:
    from naocal.kinds.arm.identify import shown_rms

    return shown_rms(value, "points" if unit == "m" else "camera")


def format_arm_verdict(v: ArmVerdict) -> str:
    lines = []
    for name, s in v.per_sensor.items():
        u = s["unit"]
        lines.append(f"sensor {name}: RMS {_shown(s['rms'], u)} per axis, median {_shown(s['median'], u)}, p95 "
                     f"{_shown(s['p95'], u)}, max {_shown(s['max'], u)} ({s['n']} observations)")
        own = "-" if s["calibration_rms"] is None else _shown(s["calibration_rms"], u)
        lines.append(f"  the calibration's own fit {own}; noise floor {_shown(s['noise_floor'], u)} "
                     f"({'stated by the dataset' if s['noise_source'] == 'dataset' else 'from a refit'}); ratio "
                     f"{s['ratio']:.2f}")
    if v.worst_poses:
        lines.append("worst poses: " + ", ".join(f"{e['pose']} ({e['rms_reference']:.2f} x the reference)"
                                                 for e in v.worst_poses))
    if v.refitted:
        from naocal.solver.effect import shown

        def number(value, unit, sign=""):  # mm, deg, px to 3 decimals; a lens coefficient (no unit, ~0.001) to 5
            v, shown_unit = shown(value, unit)
            return f"{v:{sign}.{3 if shown_unit else 5}f}{' ' + shown_unit if shown_unit else ''}"

        lines.append("refitted with the arm held: " + ", ".join(
            f"{e['parameter']} {number(e['value'], e['unit'], '+')}"
            + (" (held)" if e["fixed"] else f" +- {number(e['std'], e['unit']).split(' ')[0]}") for e in v.refitted))
    if v.absorbed:
        lines.append(f"the refitted nuisances absorbed chi2 {v.absorbed['chi2']:.1f} of their prior (largest "
                     f"{max(abs(z) for z in v.absorbed['size'].values()):.1f} plausible sizes; bound "
                     f"{v.absorbed['bound']:.1f}): " + ("BEYOND what the prior allows" if v.absorbed["beyond"]
                                                         else "within what the prior allows"))
    lines += [together_text(e) for e in v.together if e["beyond"]]
    if v.outliers:
        from naocal.kinds.arm.identify import describe_outliers

        lines.append(describe_outliers(v.outliers))
    lines += [moved_text(e) for e in v.moved]
    lines += [f"warning: {w}" for w in v.warnings]
    lines.append(v.verdict)
    return "\n".join(lines)
