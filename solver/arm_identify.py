"""Identification of an arm's parameters (solver.arm) from a naocal.arm_dataset/1 (docs/ARM.md).

1. Each sensor's frame is found from the data first (it may be anywhere): a 3-D sensor by the least-squares rigid
   alignment of the nominal points with its readings (Kabsch), a camera by OpenCV's solvePnP; a pose given in
   dataset.json is used as it is.
2. Parameters the data cannot tell apart are fixed at zero and said so: the columns of the scaled Jacobian are
   taken in the order of solver.arm.PRIORITY (sensor frames, joint offsets, link lengths, points, link poses,
   elasticity); a column within `tolerance` of the span of those kept before it is fixed (a QR with the
   priority as pivot order). The first joint's offset of an arm whose first axis is seen only by external sensors
   is such a case (a sensor rotation about that axis does the same), and so is a link along the first joint's
   axis (a sensor translation).
3. Levenberg-Marquardt (scipy.optimize.least_squares, method 'lm', analytic Jacobian) on residuals divided by each
   sensor's noise (dataset.json's noise_m / noise_px; when missing, estimated from a first fit and the fit
   repeated). Standard deviations from the Jacobian at the solution, scaled by the residual; weak directions are
   the smallest singular values of the scaled Jacobian.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from solver.arm import ArmModel, Observations
from solver.errors import DataError, SolveError
from solver.identify import WeakDirection  # one concept, one class: the NAO's (tests/test_boundaries.py)

TOLERANCE = 1e-5  # relative residual of a Jacobian column below which its parameter is fixed (not identifiable)
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

    def rms(self) -> dict:
        """{sensor: RMS per measured component (m or px)}."""
        return sensor_rms(self.model, self.obs, self.residual)

    def parameters_dict(self) -> dict:
        values = self.model.reported_values(self.x)
        return {p.name: {"value": values[p.name], "std": float(self.std[i]), "unit": p.unit,
                         "fixed": not bool(self.free[i])} for i, p in enumerate(self.model.parameters)}

    @property
    def free_names(self):
        return [n for n, f in zip(self.model.names, self.free) if f]


def sensor_rms(model, obs, residual) -> dict:
    mask = model.component_mask(obs)
    out = {}
    for s, sensor in enumerate(model.sensors):
        rows = obs.sensor == s
        e = residual[rows][mask[rows]]
        out[sensor.name] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
    return out


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


def initialise_sensors(model: ArmModel, obs: Observations, path="dataset") -> np.ndarray:
    """Set each sensor's R0 and return parameter values with its translation, from its prior or from the data."""
    x = model.initial_values()
    p_b = model.base_points(np.zeros(len(model.parameters)), obs)
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
            k = sensor.intrinsics
            K = np.array([[k["fx_px"], 0.0, k["cx_px"]], [0.0, k["fy_px"], k["cy_px"]], [0.0, 0.0, 1.0]])
            pose = camera_pose_dlt(p_b[rows], obs.measured[rows, :2], K)  # (the solver does without OpenCV)
            if pose is None:
                raise SolveError(f"camera {sensor.name}: cannot find its pose from the data: its points lie in one "
                                 "plane or line (give its pose in dataset.json)")
            R = CV_TO_NAO @ pose[0]
            t = CV_TO_NAO @ pose[1]
        model.R0[s] = R
        for i, p in model.params("sensor"):
            if p.index == s and p.kind == "translation":
                x[i] = t[p.component]
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


def identifiable(model, obs, x, free, sigma, tolerance=TOLERANCE):
    """(free mask, {name: reason}) keeping, in priority order, only parameters the data can tell apart."""
    from solver.arm import PRIORITY

    _, J = whitened(model, obs, x, sigma, jacobian=True)
    Js = J * model.scales
    order = sorted(np.flatnonzero(free), key=lambda i: (PRIORITY.index(model.parameters[i].effect), i))
    kept, basis, reasons = [], [], {}
    out = np.zeros(len(free), dtype=bool)
    for i in order:
        v = Js[:, i]
        norm = np.linalg.norm(v)
        if norm == 0.0:
            reasons[model.names[i]] = "it changes no prediction of these data"
            continue
        u = v / norm
        for _ in range(2):  # Gram-Schmidt twice: stable to 1e-15
            for b in basis:
                u = u - b * (b @ u)
        rel = np.linalg.norm(u)
        if rel < tolerance:
            coef, *_ = np.linalg.lstsq(Js[:, kept] / np.linalg.norm(Js[:, kept], axis=0), v / norm, rcond=None)
            top = np.argsort(-np.abs(coef))[:3]
            partners = ", ".join(model.names[kept[j]] for j in top if abs(coef[j]) > 1e-3)
            reasons[model.names[i]] = (f"the data cannot tell it from {partners} (relative residual {rel:.1e}); "
                                       "fixed at 0, its effect is absorbed there")
            continue
        basis.append(u / rel)
        kept.append(i)
        out[i] = True
    return out, reasons


def _solve(model, obs, x0, free, sigma):
    from scipy.optimize import least_squares

    idx = np.flatnonzero(free)

    def full(z):
        x = x0.copy()
        x[idx] = z
        return x

    def fun(z):
        return whitened(model, obs, full(z), sigma)

    def jac(z):
        return whitened(model, obs, full(z), sigma, jacobian=True)[1][:, idx]

    r0 = fun(x0[idx])
    if not np.all(np.isfinite(r0)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(r0.reshape(-1, 1)), axis=1))[0])
        raise SolveError(f"the model's prediction is not finite at the start (residual {bad}: a point behind a "
                         "camera?)")
    if len(idx) > r0.size:
        raise SolveError(f"{len(idx)} parameters but only {r0.size} measured components: too few observations")
    result = least_squares(fun, x0[idx], jac=jac, method="lm", x_scale=model.scales[idx], xtol=1e-12, ftol=1e-12,
                           gtol=1e-12, max_nfev=200 * (len(idx) + 1))
    return full(result.x), result


def fit(model: ArmModel, obs: Observations, x0, *, fixed=(), auto_fix=True, path="dataset") -> ArmFit:
    """Fit the free parameters (all but `fixed` names or effects, and those the data cannot tell apart)."""
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
        free, reasons = identifiable(model, obs, x0, free, sigma)
    x, result = _solve(model, obs, x0, free, sigma)
    if not known.all():  # weights from what the first fit left, then fit again
        residual = model.predict(x, obs) - obs.measured
        dof = max(1.0, 1.0 - free.sum() / max(1, model.component_mask(obs).sum()))
        rms = sensor_rms(model, obs, residual)
        for s, sensor in enumerate(model.sensors):
            if not known[s]:
                sigma[s] = max(rms[sensor.name] / np.sqrt(dof), 1e-12)
        x, result = _solve(model, obs, x, free, sigma)
    r, J = whitened(model, obs, x, sigma, jacobian=True)
    Jf = J[:, free]
    dof = max(1, r.size - int(free.sum()))
    s2 = float(r @ r) / dof
    std = np.zeros(len(x))
    weak, cond = [], float("inf")
    if free.any():
        Js = Jf * model.scales[free]
        U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
        inv = np.where(sv > sv[0] * 1e-14, 1.0 / np.maximum(sv, 1e-300), 0.0)
        cov = (Vt.T * inv ** 2) @ Vt * s2
        std[free] = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * model.scales[free]
        names = [n for n, f in zip(model.names, free) if f]
        for k in np.argsort(sv)[:3]:
            coefs = {names[j]: float(Vt[k, j]) for j in np.argsort(-np.abs(Vt[k])) if abs(Vt[k, j]) >= 0.1}
            std_along = math.sqrt(s2) / sv[k] if sv[k] > 0 else math.inf  # scaled units, as the NAO's
            weak.append(WeakDirection(float(sv[k] / sv[0]), float(std_along), coefs))
    residual = model.predict(x, obs) - obs.measured
    residual[~model.component_mask(obs)] = 0.0
    return ArmFit(model, obs, x, free, std, sigma, known, reasons, weak, cond, int(result.nfev),
                  bool(result.success), str(result.message), time.perf_counter() - start, residual)


# ------------------------------------------------------------------------------------------------ held-out poses


def pose_folds(obs: Observations, n_folds: int, seed: int = 0) -> list:
    """Row masks of the test set of each fold: whole poses held out, poses shuffled by `seed`."""
    poses = np.unique(obs.pose)
    n_folds = min(n_folds, len(poses))
    order = np.random.default_rng(seed).permutation(poses)
    return [np.isin(obs.pose, order[f::n_folds]) for f in range(n_folds)]


def heldout_rms(fit_: ArmFit, n_folds: int = 5) -> dict:
    """{sensor: {"nominal": RMS, "calibrated": RMS}} on poses held out of the fit (per measured component, m or px).

    nominal: only the sensor frames fitted (the URDF as it is); calibrated: every parameter the full fit used.
    """
    model, obs = fit_.model, fit_.obs
    sensor_only = np.array([p.effect == "sensor" for p in model.parameters]) & fit_.free
    x_start = fit_.x.copy()
    for i, p in enumerate(model.parameters):
        if p.effect != "sensor":
            x_start[i] = 0.0
    errors = {"nominal": np.zeros_like(obs.measured), "calibrated": np.zeros_like(obs.measured)}
    for test in pose_folds(obs, n_folds):
        train = obs.subset(~test)
        held = obs.subset(test)
        for label, free in (("nominal", sensor_only), ("calibrated", fit_.free)):
            x, _ = _solve(model, train, x_start, free, fit_.sigma)
            errors[label][test] = model.predict(x, held) - held.measured
    mask = model.component_mask(obs)
    for e in errors.values():
        e[~mask] = 0.0
    nominal, calibrated = sensor_rms(model, obs, errors["nominal"]), sensor_rms(model, obs, errors["calibrated"])
    return {s: {"nominal": nominal[s], "calibrated": calibrated[s]} for s in nominal}


def model_for(dataset, effects) -> ArmModel:
    """The ArmModel of a read naocal.arm_dataset/1 with these effects."""
    return ArmModel(dataset.chain, dataset.points, dataset.sensors, effects, dataset.gravity_mps2, dataset.load,
                    dataset.link_names)


def identify_dataset(dataset, effects, *, fixed=()) -> ArmFit:
    model = model_for(dataset, effects)
    meta_path = dataset.path / "dataset.json"
    x0 = initialise_sensors(model, dataset.observations, meta_path)
    return fit(model, dataset.observations, x0, fixed=fixed, path=meta_path)
