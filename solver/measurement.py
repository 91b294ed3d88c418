"""Measurement kinds: what a sensor reports of a point y in its own frame, as a prediction and its exact Jacobian
d prediction / d y. Every robot kind's model ends in one of these (the arm's sensors: kinds.arm.model; the NAO's
cameras project through the same solver.camera.project inside solver.model's factored Jacobian).

A prediction has 3 components; a kind that measures fewer (a pixel: u, v) leaves the rest 0 and says which are
measured (`measured`), so residuals of every kind stack into one (N, 3) array for the solver (solver.identify).
"""

from __future__ import annotations

import numpy as np

from naocal.solver.camera import project


class PointMeasurement:
    """A 3-D point sensor (a laser tracker, a motion-capture system): y itself, in metres."""

    kind = "points"
    unit = "m"
    measured = (True, True, True)

    def predict(self, y: np.ndarray, sensor) -> tuple[np.ndarray, np.ndarray]:
        """(prediction (N, 3), d prediction / d y (N, 3, 3))."""
        y = np.asarray(y, dtype=float)
        return y.copy(), np.broadcast_to(np.eye(3), (len(y), 3, 3)).copy()


class PixelMeasurement:
    """A camera (the NAO camera frame: x the optical axis, y left, z up): the pixel (u, v) of y, in px
    (solver.camera.project: the paper's Eq. 1 with OpenCV's lens distortion); the third component 0."""

    kind = "camera"
    unit = "px"
    measured = (True, True, False)

    @staticmethod
    def projection(y: np.ndarray, sensor):
        """solver.camera.Projection of y through the sensor's intrinsics."""
        k = sensor.intrinsics
        return project(y, k["fx_px"], k["fy_px"], k["cx_px"], k["cy_px"],
                       tuple((k.get("distortion") or [0.0] * 5)[:5]))

    def intrinsic_jacobian(self, y: np.ndarray, sensor, components) -> np.ndarray:
        """(N, 3, K): d prediction / d each intrinsic component (solver.camera.COMPONENTS) of the sensor's."""
        proj = self.projection(y, sensor)
        J = np.zeros((len(y), 3, len(components)))
        for c, component in enumerate(components):
            J[:, :2, c] = proj.intrinsic_jacobian(component)
        return J

    def predict(self, y: np.ndarray, sensor) -> tuple[np.ndarray, np.ndarray]:
        proj = self.projection(y, sensor)
        pred = np.zeros((len(y), 3))
        pred[:, :2] = proj.uv_px
        J = np.zeros((len(y), 3, 3))
        J[:, :2, :] = proj.point_jacobian()
        return pred, J


MEASUREMENTS = {m.kind: m for m in (PointMeasurement(), PixelMeasurement())}


def residual(kind: str, y, measured, sensor) -> tuple[np.ndarray, np.ndarray]:
    """(r (N, 3), d r / d y (N, 3, 3)): prediction - measurement of kind `kind`, 0 in the components it does not
    measure."""
    m = MEASUREMENTS[kind]
    pred, J = m.predict(y, sensor)
    mask = np.array(m.measured)
    return np.where(mask, pred - np.asarray(measured, dtype=float), 0.0), J * mask[:, None]
