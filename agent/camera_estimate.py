"""The rotation of a camera the running estimate does not fit (the NAO's top camera), learnt from its captures.

The top camera's captures come after the bottom camera's: the joint offsets and sandal mounts are known from the
running estimate (agent.estimate, the bottom camera's 21 parameters) and held; only this camera's roll, pitch and
yaw are fitted, so that its later captures are predicted to a pixel and detected with the narrow search margin.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from naocal.agent.estimate import FULL
from naocal.solver.adapter import make_model_data
from naocal.solver.effect import Setup
from naocal.solver.errors import SolveError
from naocal.solver.identify import identify
from naocal.solver.model import Model
from naocal.solver.registry import Registry
from naocal.solver.robot import nao

log = logging.getLogger(__name__)


class CameraEstimate:
    """Predicts a camera's view of a sandal from the running estimate's values plus this camera's own rotation.

    camera : the camera's name in the robot description ('top').
    intrinsics : its prior intrinsics dict.
    camera_prior : {"roll", "pitch", "yaw"} rad to start from.
    """

    def __init__(self, camera: str, intrinsics: dict, camera_prior=None):
        self.camera = camera
        self.intrinsics = dict(intrinsics)
        self.intrinsics.setdefault("distortion", [0.0] * 5)
        robot = nao()
        self.registry = Registry(setup=Setup(robot, (camera,), tuple(robot.default_targets)))
        self.rotation = {a: float((camera_prior or {}).get(a, 0.0)) for a in ("roll", "pitch", "yaw")}
        self.rms_px = (float("inf"), float("inf"))
        self._theta, self._leg, self._uv = [], [], []

    @property
    def fitted(self) -> bool:
        return np.isfinite(self.rms_px[0])

    def _data(self, theta, leg):
        data = make_model_data(np.atleast_2d(np.asarray(theta, dtype=float)), np.asarray(leg),
                               np.zeros(len(leg), dtype=int), np.zeros(len(leg), dtype=int),
                               intrinsics=self.intrinsics)
        return replace(data, camera=np.full(len(leg), self.camera), cameras={self.camera: dict(self.intrinsics)})

    def _values(self, estimate) -> np.ndarray:
        """This registry's vector: the running estimate's joint offsets and sandal mounts, this camera's rotation."""
        known = dict(zip(FULL.names, estimate.values))
        values = self.registry.zeros()
        for k, name in enumerate(self.registry.names):
            if name.startswith(f"camera.{self.camera}."):
                values[k] = self.rotation[name.rsplit(".", 1)[1]]
            elif name in known:
                values[k] = known[name]
        return values

    def predict(self, estimate, leg: str, theta14) -> np.ndarray:
        """Predicted pixel positions (24, 2) of `leg`'s board vertices in this camera at measured angles theta14."""
        data = self._data(np.asarray(theta14, dtype=float)[None], [leg])
        return Model(data, self.registry).residuals(self._values(estimate))  # detections are zero

    def add(self, estimate, leg: str, theta14, uv_px) -> None:
        """Record a capture and refit the rotation (the joint offsets and mounts held at the estimate's)."""
        self.preload(leg, theta14, uv_px)
        self.refit(estimate)

    def preload(self, leg: str, theta14, uv_px) -> None:
        """Record a capture made earlier (a resumed run) without refitting; call refit() after the last."""
        self._theta.append(np.asarray(theta14, dtype=float))
        self._leg.append(leg)
        self._uv.append(np.asarray(uv_px, dtype=float))

    def refit(self, estimate) -> None:
        """Fit the rotation to the captures recorded so far (the joint offsets and mounts held at the estimate's)."""
        if not self._theta:
            return
        data = self._data(np.array(self._theta), self._leg)
        data.uv_px = np.concatenate(self._uv)
        free = self.registry.with_fixed(("joint_offsets", "board_mount"))
        try:
            result = identify(data, free, x0=self._values(estimate), check=False)
        except SolveError as err:
            log.info("%s camera rotation not refitted: %s", self.camera, err)
            return
        if not result.success:
            return
        for a in self.rotation:
            self.rotation[a] = result.value(f"camera.{self.camera}.{a}")
        self.rms_px = tuple(float(r) for r in result.rms_px)
        log.info("%s camera rotation from %d captures: roll %.2f, pitch %.2f, yaw %.2f deg (RMS %.2f, %.2f px)",
                 self.camera, len(self._theta), *np.degrees([self.rotation[a] for a in ("roll", "pitch", "yaw")]),
                 *self.rms_px)
