"""Identification of an arm's parameters (kinds.arm.model) from a naocal.arm_dataset/1 (docs/ARM.md).

1. Each sensor's frame is found from the data first (it may be anywhere): a 3-D sensor by the least-squares rigid
   alignment of the nominal points with its readings (Kabsch), a camera by the direct linear transform of its
   pixels (camera_pose_dlt); a pose given in dataset.json is used as it is.
2. The fit is the NAO's (solver.identify.solve): Levenberg-Marquardt on the normal equations, accumulated over
   chunks of observations (ArmEquations), or scipy's trust region for a robust loss (`--loss`), on residuals divided
   by each sensor's noise (dataset.json's noise_m / noise_px; when missing, estimated from a first fit and the fit
   repeated). The identifiability policy is the NAO's (solver.identify.gauges): one threshold, 1e-6 of the largest
   singular value; the arm's parameters are gauges in their effects' gauge_priority order (sensor frames first: they
   may be anywhere, so they absorb e.g. a turn of the whole arm about its first axis, which makes the first joint's
   offset redundant, and a link along that axis): those are fixed at their start value and said so; whatever else is
   undetermined stops the fit. A sensor frame is never a gauge.
3. Detections no model explains (a marker mistaken for another, a reflection) are set aside as the NAO's corners
   are (solver.identify.trimmed: OUTLIER_SCALES robust scales, the worst of a pose each round; those the final fit
   explains taken back) and listed.
4. Standard deviations are the NAO's cluster-robust ones, the cluster being the pose: a real arm's errors are
   correlated within a pose (its repeatability, what no model holds), never below the classic estimate.
5. Priors (soft bounds, on by default): every physical parameter has a Gaussian prior about the URDF's value with
   its effect's plausible size (its module's prior_size; a camera's intrinsics: about the filed ones, at a
   checkerboard calibration's error, arm_prior_size), one whitened pseudo-observation each (solver.identify.Prior),
   so that a direction the data hardly determine stays near the URDF instead of soaking up what the model lacks.
   A parameter whose posterior std is more than PRIOR_HELD of its prior's was held by the prior, not the data: the
   report says so. After the fit the weakest directions of the data's whitened Jacobian at the solution are
   reported; a value beyond RUNOFF_FACTOR plausible sizes stops identify naming the direction it ran along.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from naocal.kinds.arm.model import ArmModel, Observations
from naocal.solver.effects import EFFECTS
from naocal.solver.errors import DataError, SolveError
from naocal.solver.identify import (CHUNK_ROWS, LOSSES, MAD_TO_SIGMA, OUTLIER_SCALES, Normal, Prior,
                             WEAK_RATIO, check_identifiable, gauges, identifiability, last_pass_cached, solve,
                             trimmed, weak_direction)

DEFAULT_NOISE = {"points": 1e-3, "camera": 1.0}  # m, px: the first fit's weights when the dataset states none
CV_TO_NAO = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # OpenCV camera -> NAO camera axes


@dataclass
class ArmFit:
    model: ArmModel
    obs: Observations
    x: np.ndarray
    free: np.ndarray  # bool (P,)
    std: np.ndarray  # (P,), 0 for fixed
    sigma: np.ndarray  # (S,) noise used per sensor (m or px)
    noise_known: np.ndarray  # (S,) bool
    fixed_reasons: dict  # name -> why it was fixed
    weak_directions: list
    condition_number: float
    iterations: int
    success: bool
    message: str
    solve_time_s: float
    residual: np.ndarray = field(default=None)  # (N, 3) prediction - measurement, physical units, 0 where unmeasured
    std_iid: np.ndarray = field(default=None)  # (P,) the classic s^2 (J^T J)^-1 standard deviations, for comparison
    outliers: list = field(default_factory=list)  # [ArmOutlier]: detections set aside (not in `obs`)
    loss: str = "linear"
    weights: np.ndarray = field(default=None)  # (N,) the robust loss's weight of each observation (1: linear)
    prior_std: np.ndarray = field(default=None)  # (P,) the std of each parameter's prior (0: none, or priors off)

    def rms(self) -> dict:
        """{sensor: RMS per measured component (m or px)}."""
        return sensor_rms(self.model, self.obs, self.residual)

    def parameters_dict(self) -> dict:
        values = self.model.reported_values(self.x)
        prior = self.prior_std if self.prior_std is not None else np.zeros(len(self.x))
        return {p.name: {"value": values[p.name], "std": float(self.std[i]), "unit": p.unit,
                         "fixed": not bool(self.free[i]), "prior_std": float(prior[i]) if prior[i] > 0 else None}
                for i, p in enumerate(self.model.parameters)}

    @property
    def priors(self) -> bool:
        return self.prior_std is not None and bool(np.any(self.prior_std > 0))

    @property
    def held_by_prior(self) -> list:
        """Names of the free parameters whose posterior std is more than PRIOR_HELD of their prior's: the data
        hardly informed them; their values are the URDF's, as the prior says."""
        if self.prior_std is None:
            return []
        return [p.name for i, p in enumerate(self.model.parameters)
                if self.free[i] and self.prior_std[i] > 0 and self.std[i] > PRIOR_HELD * self.prior_std[i]]

    @property
    def free_names(self):
        return [n for n, f in zip(self.model.names, self.free) if f]


@dataclass
class ArmOutlier:
    """A detection set aside: its pose (as the file names it), sensor, point, size at the final fit (m or px) and
    its line in observations.csv (None when unknown)."""

    pose: object
    sensor: str
    point: str
    size: float
    unit: str
    line: int | None = None

    def describe(self) -> str:
        from naocal.solver.effect import shown

        value, unit = shown(self.size, self.unit)
        where = f" (line {self.line})" if self.line is not None else ""
        return f"pose {self.pose} {self.sensor} {self.point} {value:.3g} {unit}{where}"

    def as_dict(self) -> dict:
        return {"pose": self.pose, "sensor": self.sensor, "point": self.point, "size": self.size, "unit": self.unit,
                "line": self.line}


def describe_outliers(outliers, count: int = 8) -> str:
    """One line: the detections set aside ([ArmOutlier]), the largest of each unit first ('outliers: none')."""
    if not outliers:
        return "outliers: none"
    worst = sorted(outliers, key=lambda o: (o.unit, -o.size))[:count]
    poses = len({o.pose for o in outliers})
    return (f"outliers: {len(outliers)} detections in {poses} poses set aside (beyond {OUTLIER_SCALES:g} x the "
            f"robust scale of their sensor's residuals): {', '.join(o.describe() for o in worst)}"
            + (" ..." if len(outliers) > count else ""))


def sensor_rms(model, obs, residual) -> dict:
    mask = model.component_mask(obs)
    out = {}
    for s, sensor in enumerate(model.sensors):
        rows = obs.sensor == s
        e = residual[rows][mask[rows]]
        out[sensor.name] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
    return out


def shown_rms(value, kind) -> str:
    """An RMS for people: a 3-D sensor's (kind 'points') in mm, a camera's in px."""
    return f"{value * 1e3:.3f} mm" if kind == "points" else f"{value:.3f} px"


# ------------------------------------------------------------------------------------------------ sensor frames


def kabsch(p_from, p_to):
    """(R, t) minimising sum |R p_from + t - p_to|^2 (rows are points)."""
    a, b = p_from.mean(axis=0), p_to.mean(axis=0)
    H = (p_from - a).T @ (p_to - b)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, b - R @ a


def camera_pose_dlt(points, pixels, K):
    """(R, t) of OpenCV's camera frame (x_cv ~ K (R p + t)) from 6 or more points (rows) not in one plane and their
    pixels: the direct linear transform on normalised coordinates (Hartley & Zisserman, Multiple View Geometry,
    sec. 7.1), its 3x3 part projected onto the rotations. A starting value (lens distortion ignored); None if the
    points do not determine it."""
    points, pixels = np.asarray(points, dtype=float), np.asarray(pixels, dtype=float)
    centre = points.mean(axis=0)
    spread = np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1)))
    if len(points) < 6 or not spread > 0 or np.linalg.matrix_rank((points - centre) / spread, tol=1e-6) < 3:
        return None
    X = np.hstack([(points - centre) / spread, np.ones((len(points), 1))])
    xn = np.linalg.solve(K, np.vstack([pixels.T, np.ones(len(pixels))])).T
    A = np.zeros((2 * len(X), 12))
    A[0::2, 0:4], A[0::2, 8:12] = X, -xn[:, :1] * X
    A[1::2, 4:8], A[1::2, 8:12] = X, -xn[:, 1:2] * X
    P = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 4)  # V only: U would be (2 N, 2 N)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.eye(3) / spread, -centre / spread
    P = P @ T  # back from the normalised points
    M = P[:, :3]
    scale = np.cbrt(np.linalg.det(M))
    if not abs(scale) > 1e-12:
        return None
    M, p = M / scale, P[:, 3] / scale  # det(M) = 1
    if np.median(points @ M[2] + p[2]) < 0:  # the points must be in front of the camera
        M, p = -M, -p
    U, sv, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        return None
    return R, p / np.mean(sv)


def initialise_sensors(model: ArmModel, obs: Observations, path="dataset", start=None) -> np.ndarray:
    """Set each sensor's R0 and return parameter values with its translation, from its prior or from the data;
    the arm's parameters at `start` ({name: SI value}; default the URDF's, 0), where the data are seen from."""
    x = model.initial_values()
    for name, value in (start or {}).items():
        x[model.names.index(name)] = value
    p_b = model.base_points(np.where([p.effect == "sensors" for p in model.parameters], 0.0, x), obs)
    for s, sensor in enumerate(model.sensors):
        rows = obs.sensor == s
        if sensor.prior_rotation is not None:
            continue
        if sensor.kind == "points":
            if rows.sum() < 3 or np.linalg.matrix_rank(p_b[rows] - p_b[rows].mean(axis=0), tol=1e-6) < 2:
                raise DataError(path, f"sensor {sensor.name}: needs 3 or more readings not on one line to find its "
                                      "frame (or give its pose in dataset.json)", field=f"sensors.{sensor.name}")
            R, t = kabsch(p_b[rows], obs.measured[rows])
        else:
            if rows.sum() < 6:
                raise DataError(path, f"camera {sensor.name}: needs 6 or more observations to find its pose (or give "
                                      "its pose in dataset.json)", field=f"sensors.{sensor.name}")
            k = model.sensor_intrinsics(x, s)  # as filed, or as `start` corrects them
            K = np.array([[k["fx_px"], 0.0, k["cx_px"]], [0.0, k["fy_px"], k["cy_px"]], [0.0, 0.0, 1.0]])
            pose = camera_pose_dlt(p_b[rows], obs.measured[rows, :2], K)  # (the solver does without OpenCV)
            if pose is None:
                raise SolveError(f"camera {sensor.name}: cannot find its pose from the data: its points lie in one "
                                 "plane or line (give its pose in dataset.json)")
            R = CV_TO_NAO @ pose[0]
            t = CV_TO_NAO @ pose[1]
        model.R0[s] = R
        for i, p in model.params("sensors"):
            if p.index == s and p.axis < 3:  # its translation
                x[i] = t[p.axis]
    return x


# ------------------------------------------------------------------------------------------------ the fit


def whitened(model, obs, x, sigma, *, jacobian=False):
    """Residuals divided by their sensor's noise, only measured components; with `jacobian` the (M, P) Jacobian."""
    mask = model.component_mask(obs)
    w = 1.0 / sigma[obs.sensor]
    if jacobian:
        pred, J = model.predict(x, obs, jacobian=True)
        r = (pred - obs.measured) * w[:, None]
        return r[mask], (J * w[:, None, None])[mask]
    r = (model.predict(x, obs) - obs.measured) * w[:, None]
    return r[mask]


class ArmEquations:
    """The arm's normal equations for solver.identify.solve, as NormalEquations are the NAO's: residuals divided by
    their sensor's noise, accumulated over chunks of `chunk_rows` observations (the (N, 3, P) Jacobian is never held
    whole), each observation's score for the cluster-robust covariance (its cluster: its pose)."""

    def __init__(self, model: ArmModel, obs: Observations, base, free: np.ndarray, sigma, *,
                 chunk_rows: int = CHUNK_ROWS):
        self.model, self.obs, self.sigma = model, obs, np.asarray(sigma, dtype=float)
        self.base = np.asarray(base, dtype=float)
        self.index = np.flatnonzero(free)
        self.scales = model.scales[self.index]
        self.mask = model.component_mask(obs)
        self.chunks = [slice(a, min(a + chunk_rows, len(obs))) for a in range(0, max(len(obs), 1), chunk_rows)]

    def values(self, free) -> np.ndarray:
        x = self.base.copy()
        x[self.index] = free
        return x

    def _chunk(self, x, rows, jacobian):
        sub = self.obs.subset(rows)
        w = 1.0 / self.sigma[sub.sensor]
        mask = self.mask[rows]
        if jacobian:
            pred, J = self.model.predict(x, sub, jacobian=True)
            J = J[:, :, self.index] * w[:, None, None]
            J[~mask] = 0.0
        else:
            pred, J = self.model.predict(x, sub), None
        r = (pred - sub.measured) * w[:, None]
        r[~mask] = 0.0
        return r, J

    def __call__(self, free, *, weights=None, jacobian: bool = True) -> Normal:
        x = self.values(free)
        p = len(self.index)
        A, g, rss = np.zeros((p, p)), np.zeros(p), 0.0
        residuals = np.zeros((len(self.obs), 3))
        scores = np.zeros((len(self.obs), p))
        for rows in self.chunks:
            r, J = self._chunk(x, rows, jacobian)
            residuals[rows] = r
            if weights is not None:
                r = r * np.sqrt(weights[rows])[:, None]
            rss += float(np.sum(r ** 2))
            if jacobian:
                Js = J * self.scales
                flat = Js.reshape(-1, p)
                A += flat.T @ flat
                g += flat.T @ r.reshape(-1)
                scores[rows] = np.einsum("ncp,nc->np", Js, r)
        return Normal(0.5 * (A + A.T), g, 0.5 * rss, residuals, scores)

    def dense(self, free):
        """(r, J) over the measured components, unscaled: for scipy's solvers (robust losses)."""
        x = self.values(free)
        rs, Js = [], []
        for rows in self.chunks:
            r, J = self._chunk(x, rows, True)
            rs.append(r[self.mask[rows]])
            Js.append(J[self.mask[rows]])
        return np.concatenate(rs), np.concatenate(Js)


def prior_sizes(model) -> np.ndarray:
    """(P,) each parameter's plausible size (its effect's arm_prior_size: its prior_size of its unit; 0: none, a
    sensor)."""
    return np.array([EFFECTS[p.effect].arm_prior_size(p, model) for p in model.parameters])


def arm_prior(model, free, priors: bool = True):
    """The solver.identify.Prior of the free parameters that have a plausible size: mean the URDF (0), std that
    size; None with `priors` off."""
    if not priors:
        return None
    size = prior_sizes(model)[free]
    index = np.flatnonzero(size > 0)
    return Prior(index, np.zeros(len(index)), size[index])


def _solve(model, obs, x0, free, sigma, loss="linear", priors=True):
    """(x, solver.identify.Solution, equations): the free parameters fitted from x0 (with their priors)."""
    equations = ArmEquations(model, obs, x0, free, sigma)
    if not len(equations.index):
        raise SolveError("no free parameters to identify")
    r0 = equations(x0[equations.index], jacobian=False).residuals
    if not np.all(np.isfinite(r0)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(r0), axis=1))[0])
        raise SolveError(f"the model's prediction is not finite at the start (observation {bad}: a point behind a "
                         "camera?)")
    if len(equations.index) > equations.mask.sum():
        raise SolveError(f"{len(equations.index)} parameters but only {int(equations.mask.sum())} measured "
                         "components: too few observations")
    solution = solve(equations, last_pass_cached(equations), x0[equations.index], loss=loss, loss_scale=LOSS_SCALE_SIGMA,
                     max_iterations=MAX_ITERATIONS, measured=equations.mask, prior=arm_prior(model, free, priors))
    return equations.values(solution.free), solution, equations


# The robust loss bends at this many noise standard deviations of the residual's sensor (the residuals are divided
# by their noise: one scale for pixels and metres).
LOSS_SCALE_SIGMA = 1.0
MAX_ITERATIONS = 200
# A free parameter whose posterior std is above this share of its prior's was held by the prior (the data alone
# would know it no better than 1.15 prior stds).
PRIOR_HELD = 0.5
# A value beyond this many plausible sizes (the effects' prior_size) is no calibration: the fit ran off along a
# direction the data hardly determine (with the priors on it can only land there if the data insist).
RUNOFF_FACTOR = 5.0


def identifiable(model, obs, x, free, sigma, priors: bool = True):
    """(free mask, {name: reason}): the gauges of the arm's parametrisation (solver.identify.gauges, in the order of
    the effects' gauge_priority) fixed; raises SolveError (solver.identify.check_identifiable) if anything else is
    undetermined.

    With the priors (`arm_prior`) only what the sensor frames absorb is a gauge (they have no prior: the first
    joint's offset, the base's height); what physical parameters cannot tell apart among themselves (a tool's
    turn and its markers, two links along one axis) their priors resolve, each by its plausible size, rather than
    one being held at the URDF and the other taking it all (a tool turned 8 deg to carry its markers' 2 mm). The
    check that nothing else is undetermined then counts the priors' information."""
    equations = ArmEquations(model, obs, x, free, sigma)
    A = equations(x[equations.index]).A
    names = [model.names[i] for i in equations.index]
    effect = [model.parameters[i].effect for i in equations.index]
    order = sorted(range(len(names)), key=lambda j: (EFFECTS[effect[j]].gauge_priority, j))
    fixable = [EFFECTS[e].arm_gauge for e in effect]
    prior = arm_prior(model, free, priors)
    if prior is None or not len(prior):
        found = gauges(A, order, fixable)
    else:
        sensors = [j for j in order if not fixable[j]]
        found = {}
        for j in order:
            if fixable[j]:
                found.update(gauges(A, sensors + [j], fixable))
        A = A + prior.information(equations.scales)
    reasons = {}
    for j, (partners, residual) in found.items():
        reasons[names[j]] = ("it changes no prediction of these data" if not partners else
                             f"the data cannot tell it from {', '.join(names[k] for k in partners)} (relative "
                             f"residual {residual:.1e}); fixed at its start value, its effect is absorbed there")
    keep = [j for j in range(len(names)) if j not in found]
    check_identifiable(A[np.ix_(keep, keep)], [names[j] for j in keep], lambda d: _fix_advice(model, d))
    out = free.copy()
    out[equations.index[list(found)]] = False
    return out, reasons


def _fix_advice(model, directions) -> str:
    """What to fix for undetermined directions that move a parameter no gauge may be (solver.effect's arm_gauge:
    a print's scale): that parameter, the last in the gauge order, as its effect says; '' when none does."""
    effect_of = {p.name: p.effect for p in model.parameters}
    said = []
    for direction in directions:
        named = [n for n in direction.coefficients if EFFECTS[effect_of[n]].undetermined_hint]
        if named:
            name = max(named, key=lambda n: (EFFECTS[effect_of[n]].gauge_priority, abs(direction.coefficients[n])))
            said.append(f"This direction is {EFFECTS[effect_of[name]].undetermined_hint.format(name=name)}")
    return "; ".join(dict.fromkeys(said)) + ("." if said else "")


def _estimated_sigma(model, obs, residual, sigma, known, n_free):
    """Each sensor's noise where the dataset states none: the RMS the fit left, corrected for the parameters."""
    sigma = sigma.copy()
    dof = max(1.0, 1.0 - n_free / max(1, model.component_mask(obs).sum()))
    rms = sensor_rms(model, obs, residual)
    for s, sensor in enumerate(model.sensors):
        if not known[s]:
            sigma[s] = max(rms[sensor.name] / np.sqrt(dof), 1e-12)
    return sigma


def _outlier_sizes(model, obs, residual, kept, sigma) -> tuple[np.ndarray, float]:
    """(each detection's residual in robust (MAD) scales of its sensor's kept residuals, OUTLIER_SCALES): what
    solver.identify.trimmed judges (the worst detection of each pose beyond it is set aside each round)."""
    mask = model.component_mask(obs)
    size = np.zeros(len(obs))
    for s in range(len(model.sensors)):
        rows = obs.sensor == s
        if not rows.any():
            continue
        fitted = rows & kept
        scale = MAD_TO_SIGMA * float(np.median(np.abs(residual[fitted][mask[fitted]]))) if fitted.any() else 0.0
        scale = scale if scale > 0 else sigma[s]
        size[rows] = np.linalg.norm(residual[rows] * mask[rows], axis=1) / scale
    return size, OUTLIER_SCALES


def fit(model: ArmModel, obs: Observations, x0, *, fixed=(), auto_fix=True, path="dataset", loss: str = "linear",
        robust: bool = True, priors: bool = True) -> ArmFit:
    """Fit the free parameters (all but `fixed` names or effects, and the gauges the data cannot tell apart).

    fixed : names or effects held at their value in x0.
    loss : 'linear' or a robust loss (solver.identify.ROBUST_WEIGHT), bending at LOSS_SCALE_SIGMA noise stds.
    robust : set aside the detections no model explains (`_outlier_sizes`, solver.identify.trimmed), refitting after
        each round, and take back those the final fit explains.
    priors : each physical parameter's Gaussian prior (`arm_prior`); off, the data alone.
    """
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}: expected one of {', '.join(LOSSES)}")
    start = time.perf_counter()
    free = np.array([not (p.name in fixed or p.effect in fixed or any(p.name.startswith(f + ".") for f in fixed))
                     for p in model.parameters])
    known = np.array([s.noise is not None for s in model.sensors])
    sigma = np.array([s.noise if s.noise is not None else DEFAULT_NOISE[s.kind] for s in model.sensors])
    for s, sensor in enumerate(model.sensors):
        if not np.any(obs.sensor == s):
            raise DataError(path, f"sensor {sensor.name} has no observations", field=f"sensors.{sensor.name}")
    reasons = {}
    if auto_fix:
        free, reasons = identifiable(model, obs, x0, free, sigma, priors)
    all_obs, kept = obs, np.arange(len(obs))
    x, solution, _ = _solve(model, obs, x0, free, sigma, loss, priors)
    if not known.all():  # weights from what the first fit left, then fit again
        sigma = _estimated_sigma(model, obs, model.predict(x, obs) - obs.measured, sigma, known, free.sum())
        x, solution, _ = _solve(model, obs, x, free, sigma, loss, priors)
    if robust:
        def refit(keep, fitted):
            x, _ = fitted
            return _solve(model, all_obs.subset(np.flatnonzero(keep)), x, free, sigma, loss, priors)[:2]

        def judge(fitted, keep):
            return _outlier_sizes(model, all_obs, model.predict(fitted[0], all_obs) - all_obs.measured, keep, sigma)

        (x, solution), keep, _ = trimmed((x, solution), refit, judge, all_obs.pose, np.ones(len(all_obs), bool))
        kept = np.flatnonzero(keep)
        obs = all_obs.subset(kept)
    if len(kept) < len(all_obs) and not known.all():  # the noise from the detections kept
        sigma = _estimated_sigma(model, obs, model.predict(x, obs) - obs.measured, sigma, known, free.sum())
        x, solution, _ = _solve(model, obs, x, free, sigma, loss, priors)
    names = [n for n, f in zip(model.names, free) if f]
    _, cluster = np.unique(obs.pose, return_inverse=True)
    spread = solution.spread(cluster.reshape(-1), names)
    std, std_iid = np.zeros(len(x)), np.zeros(len(x))
    std[free] = np.sqrt(np.clip(np.diag(spread.covariance), 0.0, None))
    std_iid[free] = np.sqrt(np.clip(np.diag(spread.covariance_iid), 0.0, None))
    residual = model.predict(x, obs) - obs.measured
    residual[~model.component_mask(obs)] = 0.0
    outliers = _outliers(model, all_obs, np.setdiff1d(np.arange(len(all_obs)), kept), x)
    prior_std = np.where(free, prior_sizes(model), 0.0) if priors else np.zeros(len(x))
    cond, weak = data_weakest(model, obs, x, free, sigma)
    return ArmFit(model, obs, x, free, std, sigma, known, reasons, weak, cond,
                  solution.n_fun, solution.success, solution.message, time.perf_counter() - start, residual,
                  std_iid, outliers, loss, solution.weights, prior_std)


def _data_directions(model, obs, x, free, sigma):
    """(condition number, singular values, Vt, indices of the free parameters) of the data's whitened,
    column-scaled Jacobian at x (solver.identify.identifiability; the priors left out)."""
    equations = ArmEquations(model, obs, x, free, sigma)
    return (*identifiability(equations(x[equations.index]).A), equations.index)


def data_weakest(model, obs, x, free, sigma, count: int = 3):
    """(condition number, [solver.identify.WeakDirection]) of the data's whitened, column-scaled Jacobian at x (the
    solution, not the start; the priors left out: what the data themselves determine least), weakest first."""
    cond, sv, Vt, index = _data_directions(model, obs, x, free, sigma)
    names = [model.names[i] for i in index]
    return cond, [weak_direction(sv[k] / max(sv[0], 1e-300), 1.0 / sv[k] if sv[k] > 0 else np.inf, Vt[k], names)
                  for k in np.argsort(sv)[:count]]


def ran_off(fit_: ArmFit):
    """None, or one line: the parameter furthest beyond RUNOFF_FACTOR of its plausible size (or beyond what a
    calibration file may hold, kinds.arm.calibration.LIMITS), the data's weak direction at the solution it moves
    most cheaply along, and the `--fix` that removes that direction: its largest physical parameter held at the
    URDF's value."""
    from naocal.kinds.arm.calibration import LIMITS
    from naocal.solver.effect import shown

    model = fit_.model
    size = prior_sizes(model)
    worst, worst_ratio = None, 1.0
    for i, p in enumerate(model.parameters):
        if not fit_.free[i] or p.effect == "sensors":
            continue
        limit = min(RUNOFF_FACTOR * size[i] if size[i] > 0 else np.inf, LIMITS.get(p.unit, np.inf))
        if abs(fit_.x[i]) > worst_ratio * limit:
            worst, worst_ratio = i, abs(fit_.x[i]) / limit
    if worst is None:
        return None
    p = model.parameters[worst]
    _, sv, Vt, index = _data_directions(model, fit_.obs, fit_.x, fit_.free, fit_.sigma)
    j = int(np.flatnonzero(index == worst)[0])
    k = int(np.argmax(np.abs(Vt[:, j]) / np.maximum(sv, 1e-300)))  # the direction along which it moves most cheaply
    direction = weak_direction(sv[k] / max(sv[0], 1e-300), 1.0 / max(sv[k], 1e-300), Vt[k],
                               [model.names[i] for i in index])
    physical = [(abs(c), n) for n, c in direction.coefficients.items() if not n.startswith("sensor.")]
    to_fix = max(physical)[1] if physical else p.name
    value, unit = shown(fit_.x[worst], p.unit)
    plausible = shown(size[worst], p.unit)[0] if size[worst] > 0 else None
    beyond = (f"(its plausible size is {plausible:.3g} {unit}: more than {RUNOFF_FACTOR:g} x that is no calibration)"
              if plausible is not None else "(beyond any plausible calibration)")
    if direction.singular_value >= WEAK_RATIO:  # no flat direction: the data themselves put it there
        return (f"{p.name} = {value:.4g} {unit} is beyond a calibration {beyond}, and the data determine it (its "
                f"weakest direction has relative singular value {direction.singular_value:.1e}: "
                f"{direction.describe()}): is the URDF the arm's, are the readings' zeros its zeros? nothing written")
    return (f"{p.name} = {value:.4g} {unit} ran off {beyond}"
            + f" along a direction the data hardly determine (relative singular value {direction.singular_value:.1e}"
            f" at the solution): {direction.describe()}; fix {to_fix} at the URDF's value (--fix {to_fix}=0)"
            + ("" if fit_.priors else " or fit with the priors on")
            + ", or measure poses that move it; nothing written")


def _outliers(model, obs, rows, x) -> list:
    """[ArmOutlier] of the observations `rows`, sized at the final fit's values."""
    if not len(rows):
        return []
    sub = obs.subset(rows)
    e = (model.predict(x, sub) - sub.measured) * model.component_mask(sub)
    unit = {"points": "m", "camera": "px"}
    return [ArmOutlier(sub.pose_name(sub.pose[k]), model.sensors[sub.sensor[k]].name,
                       model.point_names[sub.point[k]], float(np.linalg.norm(e[k])),
                       unit[model.sensors[sub.sensor[k]].kind],
                       None if sub.source_line is None else int(sub.source_line[k]))
            for k in range(len(sub))]


# ------------------------------------------------------------------------------------------------ held-out poses


def pose_folds(obs: Observations, n_folds: int, seed: int = 0) -> list:
    """Row masks of the test set of each fold: whole poses held out, poses shuffled by `seed`."""
    poses = np.unique(obs.pose)
    n_folds = min(n_folds, len(poses))
    order = np.random.default_rng(seed).permutation(poses)
    return [np.isin(obs.pose, order[f::n_folds]) for f in range(n_folds)]


def heldout_rms(fit_: ArmFit, n_folds: int = 5, folds=None) -> dict:
    """{sensor: {"nominal": RMS, "calibrated": RMS}} on poses held out of the fit (per measured component, m or px).

    nominal: only the sensor frames fitted (the URDF as it is); calibrated: every parameter the full fit used.
    folds: the test rows of each fold (default `pose_folds`).
    """
    model, obs = fit_.model, fit_.obs
    folds = pose_folds(obs, n_folds) if folds is None else folds
    sensor_only = np.array([p.effect == "sensors" for p in model.parameters]) & fit_.free
    nominal = sensor_rms(model, obs, heldout_residuals(fit_, folds, sensor_only))
    calibrated = sensor_rms(model, obs, heldout_residuals(fit_, folds))
    return {s: {"nominal": nominal[s], "calibrated": calibrated[s]} for s in nominal}


def heldout_residuals(fit_: ArmFit, folds, free=None) -> np.ndarray:
    """(N, 3) residuals of `fit_.obs`, each fold's test rows predicted by the model fitted to the other rows (its
    `free` parameters, default the fit's, from the URDF's values and the fit's sensor frames); 0 where unmeasured."""
    model, obs = fit_.model, fit_.obs
    free = fit_.free if free is None else free
    x_start = np.where([p.effect == "sensors" for p in model.parameters], fit_.x, 0.0)
    errors = np.zeros_like(obs.measured)
    for test in folds:
        held = obs.subset(test)
        x, _, _ = _solve(model, obs.subset(~test), x_start, free, fit_.sigma, fit_.loss, fit_.priors)
        errors[test] = model.predict(x, held) - held.measured
    errors[~model.component_mask(obs)] = 0.0
    return errors


def model_for(dataset, effects) -> ArmModel:
    """The ArmModel of a read naocal.arm_dataset/1 with these effects."""
    return ArmModel(dataset.chain, dataset.points, dataset.sensors, effects, dataset.gravity_mps2, dataset.load,
                    dataset.link_names, markers=dataset.markers, sheets=dataset.sheets)


def identify_dataset(dataset, effects, *, fixed=(), start=None, loss: str = "linear", robust: bool = True,
                     priors: bool = True) -> ArmFit:
    """The fit of a read dataset: `fixed` names or effects held at their start value, `start` {name: SI value} of
    the arm's parameters to start from (--start, --fix NAME=VALUE; the rest at the URDF's)."""
    model = model_for(dataset, effects)
    meta_path = dataset.path / "dataset.json"
    x0 = initialise_sensors(model, dataset.observations, meta_path, start)
    return fit(model, dataset.observations, x0, fixed=fixed, path=meta_path, loss=loss, robust=robust, priors=priors)
