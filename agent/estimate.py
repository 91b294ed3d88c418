"""The agent's running estimate of the robot, used while measuring: where will the board appear in the image?

The detector needs the predicted projection to find the right board and to order its vertices, and the agent
needs it to keep boards inside the image. The nominal model can be off by tens of pixels (real heads' cameras are
rotated by degrees), so every few captures the estimate is refitted to the captures so far: all 21 parameters
when the data determine them, else the camera rotation alone. A leg with too few captures to determine its six
offsets and its sandal mount keeps those at their current values (zero: unknown) while the rest is fitted, so
starting the second leg does not throw away what the first taught.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from naocal.solver.effects import EFFECTS
from naocal.solver.errors import SolveError
from naocal.solver.identify import identify
from naocal.solver.joints import JOINTS, LEGS, leg_joints
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.adapter import make_model_data

log = logging.getLogger(__name__)

FULL = Registry()
CAMERA_ONLY = Registry(fixed=("joint_offsets", "board_mount"))


class RunningEstimate:
    """Parameter values (the paper's 21, registry `FULL`) refitted as captures come in.

    intrinsics : the camera's prior intrinsics dict (fx_px, fy_px, cx_px, cy_px, width_px, height_px).
    camera_prior : {"roll", "pitch", "yaw"} rad to start from (the planner's prior camera rotation).
    """

    def __init__(self, intrinsics: dict, *, refit_every: int = 6, min_full_fit: int = 9, min_leg_fit: int = 6,
                 camera_prior=None, max_joint_offset_rad: float = EFFECTS["joint_offsets"].offsets_limit):
        self.intrinsics = dict(intrinsics)
        self.intrinsics.setdefault("distortion", [0.0] * 5)
        self.values = FULL.zeros()
        for angle, value in (camera_prior or {}).items():  # a real head's typical camera rotation
            self.values[FULL.index[f"camera.{FULL.setup.cameras[0]}.{angle}"]] = float(value)
        self.refit_every = refit_every
        self.min_full_fit = min_full_fit
        self.min_leg_fit = min_leg_fit  # captures of a leg before its offsets and sandal mount are fitted
        self.known_legs: frozenset = frozenset()  # legs whose offsets and mount the current values have fitted
        self.n_fitted = 0  # captures the current values were fitted to (0: nominal model)
        self.rms_px = (float("inf"), float("inf"))  # the current values' fit RMS (u, v)
        self.scope = "nominal"
        self.std = FULL.zeros()  # standard deviations of `values` from their fit (0: not fitted)
        self.covariance = np.zeros((len(FULL.names), len(FULL.names)))  # ... and their covariance
        self.max_joint_offset_rad = float(max_joint_offset_rad)  # a fit claiming more is not believed
        self._theta, self._leg, self._uv = [], [], []

    @property
    def fitted(self) -> bool:
        return self.n_fitted > 0

    def knows(self, leg: str) -> bool:
        """Whether the current values include this leg's fitted offsets and sandal mount."""
        return leg in self.known_legs

    def _seen(self, leg: str) -> bool:
        """Whether the last refit had captures of this leg."""
        return leg in self._leg[:self.n_fitted]

    def set_values(self, values: np.ndarray, scope: str = "given") -> None:
        self.values = np.asarray(values, dtype=float).copy()
        self.n_fitted = max(self.n_fitted, 1)
        self.scope = scope

    def offsets_known(self) -> bool:
        """Whether the joint offsets of both legs have been fitted (until then a leg's true angles are unknown)."""
        return self.known_legs == frozenset(LEGS)

    def joint_alpha(self) -> np.ndarray:
        """(14,) estimated true-minus-measured angle of each joint (solver.joints.JOINTS order, rad); zero for the
        joints of a leg not fitted yet."""
        alpha = np.zeros(len(JOINTS))
        for leg in self.known_legs:
            for joint in leg_joints(leg):
                alpha[JOINTS.index(joint)] = -self.values[FULL.index[f"joint_offset.{joint}"]]  # alpha = -c
        if len(self.known_legs) == 1:  # one HipYawPitch motor: the fitted leg's offset is the other's too
            known = next(iter(self.known_legs))
            alpha[[JOINTS.index(f"{leg}HipYawPitch") for leg in LEGS]] = alpha[JOINTS.index(f"{known}HipYawPitch")]
        return alpha

    def joint_covariance(self, prior14, *, n_std: float = 4.0, floor_rad: float = np.radians(0.1)) -> np.ndarray:
        """(14, 14) covariance (rad^2) of the joints' true offsets around joint_alpha(), for the safety check (which
        keeps 3 standard deviations away): prior14 (14, 14) for the joints of a leg not fitted yet; for a fitted
        leg the fit's covariance scaled so that 3 of the check's standard deviations are n_std of the fit's, plus
        floor_rad (read as 3 standard deviations) for what the fit does not know. Both HipYawPitch joints are one
        motor: once either leg is fitted, its offset and variance hold for both."""
        C = np.asarray(prior14, dtype=float).copy()
        known = [JOINTS.index(j) for leg in self.known_legs for j in leg_joints(leg)]
        if not known:
            return C
        rows = [FULL.index[f"joint_offset.{JOINTS[k]}"] for k in known]
        C[known, :] = 0.0
        C[:, known] = 0.0
        C[np.ix_(known, known)] = self.covariance[np.ix_(rows, rows)] * (n_std / 3.0) ** 2
        C[known, known] += (floor_rad / 3.0) ** 2
        hyp = [JOINTS.index("LHipYawPitch"), JOINTS.index("RHipYawPitch")]
        fitted = hyp[0] if "L" in self.known_legs else hyp[1]
        other = hyp[1] if fitted == hyp[0] else hyp[0]
        C[other, :] = C[fitted, :]  # the other HipYawPitch joint: the same motor, the same offset
        C[:, other] = C[:, fitted]
        C[other, other] = C[fitted, fitted]
        return C

    def board_mounts(self) -> dict:
        """{leg: (rot_z rad, trans_x m, trans_y m)} as estimated; zero for a leg not fitted yet."""
        return {leg: tuple(float(self.values[FULL.index[f"board.{leg}.{k}"]]) if leg in self.known_legs else 0.0
                           for k in ("rot_z", "trans_x", "trans_y")) for leg in LEGS}

    def predict(self, leg: str, theta14) -> np.ndarray:
        """Predicted pixel positions (24, 2) of `leg`'s board vertices at measured angles theta14 (rad)."""
        data = make_model_data(np.asarray(theta14, dtype=float)[None], np.array([leg]), np.array([0]),
                               np.array([0]), intrinsics=self.intrinsics)
        return Model(data, FULL).residuals(self.values)  # detections are zero: residual = prediction

    def preload(self, leg: str, theta14, uv_px) -> None:
        """Record a capture made earlier (a resumed run) without refitting; call refit() after the last."""
        self._theta.append(np.asarray(theta14, dtype=float))
        self._leg.append(leg)
        self._uv.append(np.asarray(uv_px, dtype=float))

    def add(self, leg: str, theta14, uv_px) -> None:
        """Record a still capture (measured angles, detected vertices (24, 2)) and refit when due."""
        self._theta.append(np.asarray(theta14, dtype=float))
        self._leg.append(leg)
        self._uv.append(np.asarray(uv_px, dtype=float))
        if (len(self._theta) - self.n_fitted >= self.refit_every or not self.fitted
                or not self._seen(leg)):  # the first capture of a leg: refit at once
            self.refit()

    def _without_outliers(self, data):
        """data without the vertices the current values miss by far more than the rest (a corner found a square
        off or on a reflection: real detectors do that now and then), so that one bad corner cannot pull the
        estimate the safety check and the detector rely on. Far: beyond 6 robust standard deviations and 4 px.
        Only the boards of legs the current values have fitted are judged (a leg joining the fit is missed by
        its unknown offsets, not by its corners), and never more than 5 % of them: beyond that the values are
        off, not the corners."""
        miss = np.linalg.norm(Model(data, FULL).residuals(self.values).reshape(-1, 2), axis=1)
        judged = np.isin(data.target[data.image_of_row], list(self.known_legs))
        if not judged.any():
            return data
        limit = max(4.0, 6.0 * 1.4826 * float(np.median(miss[judged])))
        keep = ~judged | (miss <= limit)
        if keep.all() or (~keep).sum() > 0.05 * judged.sum():
            return data
        log.info("running estimate: %d of %d vertices left out (missed by more than %.1f px)", int((~keep).sum()),
                 len(keep), limit)
        return replace(data, image_of_row=data.image_of_row[keep], vertex=data.vertex[keep],
                       uv_px=data.uv_px[keep], p_mount=data.p_mount[keep])

    def refit(self) -> None:
        n = len(self._theta)
        if n == 0:
            return
        legs = np.array(self._leg)
        counts = {leg: int(np.sum(legs == leg)) for leg in LEGS}
        # A leg with few captures would trade its unknown offsets against the camera: it joins the full fit (its
        # offsets and sandal mount freed) from min_leg_fit captures on; until then only the camera fit sees it.
        learning = [leg for leg in LEGS if counts[leg] < self.min_leg_fit]
        held = [f"board.{leg}.{k}" for leg in learning for k in ("rot_z", "trans_x", "trans_y")]
        held += [f"joint_offset.{j}" for leg in learning for j in leg_joints(leg)]
        full = FULL.with_fixed(held) if held else FULL
        fitted = np.flatnonzero(~np.isin(legs, learning))
        for registry, scope in ((full, "all 21 parameters"), (CAMERA_ONLY, "camera rotation")):
            images = fitted if registry is full else np.arange(n)
            if registry is full and (len(images) < self.min_full_fit or len(learning) == len(LEGS)):
                continue  # a handful of stances trade joint offsets against the board mount wildly
            data = make_model_data(np.array(self._theta)[images], legs[images], np.arange(len(images)),
                                   np.zeros(len(images), dtype=int), intrinsics=self.intrinsics)
            data.uv_px = np.concatenate([self._uv[m] for m in images])
            if registry is full and self.known_legs:
                data = self._without_outliers(data)
            try:
                result = identify(data, registry, x0=self.values if registry is full else None)
            except SolveError:
                continue
            joints = [result.value(n) for n in result.registry.names if n.startswith("joint_offset.")]
            plausible = bool(np.all(np.abs(joints) < self.max_joint_offset_rad))
            if result.success and max(result.rms_px) < 20.0 and plausible:
                self.values = FULL.from_dict({name: result.value(name) for name in result.registry.names})
                std = dict(zip(result.registry.names, result.std))
                self.std = np.array([std.get(name, 0.0) for name in FULL.names])
                expand = result.registry.expand  # free parameters -> the registry's names
                covariance = expand @ result.covariance @ expand.T
                where = [result.registry.names.index(name) if name in result.registry.names else -1
                         for name in FULL.names]
                self.covariance = np.zeros((len(FULL.names), len(FULL.names)))
                ok = np.array([w >= 0 for w in where])
                idx = np.array([w for w in where if w >= 0])
                self.covariance[np.ix_(ok, ok)] = covariance[np.ix_(idx, idx)]
                self.n_fitted = n
                self.rms_px = tuple(result.rms_px)
                self.scope = scope
                self.known_legs = frozenset(leg for leg in LEGS if leg not in learning and registry is full)
                log.info("running estimate refitted to %d of %d captures (%s): RMS %.2f / %.2f px", len(images),
                         n, scope, *result.rms_px)
                return
        self.n_fitted = n  # nothing better: keep the old values, try again later
