"""Distortion: corrections of each camera's radial lens distortion k1, k2 to the prior (OpenCV's model)."""

import numpy as np

from naocal.solver.effect import MockPerturbation
from naocal.solver.effects._common import CameraCorrections

COMPONENTS = ("k1", "k2")


class Distortion(CameraCorrections):
    name = "distortion"
    order = 55
    summary = "corrections of each camera's radial distortion k1, k2 to the prior"
    prefix, components, unit, scale = "distortion", COMPONENTS, "1", 0.05
    plausible_limit = 0.5
    offsets_section, offsets_key = "head", "distortion_correction"
    offsets_limit = 2.0
    mock_size_unit, mock_stream = "1 (radial k1)", 6

    def partial_residual_panels(self, fit):
        from naocal.solver.diagnostics import partial_residuals

        data = fit.model.data
        r_off = partial_residuals(fit, [self.name])
        groups = data.target[data.image_of_row]
        panels = []
        for cam in np.unique(data.camera):
            rows = data.camera[data.image_of_row] == cam
            intr = data.cameras[cam]
            du, dv = data.uv_px[rows, 0] - intr["cx_px"], data.uv_px[rows, 1] - intr["cy_px"]
            radius = np.hypot(du, dv)
            radial = (r_off[rows, 0] * du + r_off[rows, 1] * dv) / np.maximum(radius, 1e-9)
            get = self.fitted(fit, cam)
            xs = np.linspace(0, radius.max(), 50)
            rho2 = (xs / intr["fx_px"]) ** 2
            panels.append((radius, radial, f"distance from the principal point (px), {cam}",
                           "radial partial residual (px)", groups[rows],
                           (xs, -xs * (get("k1") * rho2 + get("k2") * rho2 ** 2))))
        return panels

    def mock_perturbation(self, rng, size, setup):
        """The cameras' true radial distortion k1 = size (OpenCV's model on the normalised coordinates)."""
        return MockPerturbation(distortion={"k1": float(size)}, record={"k1": float(size)})


EFFECT = Distortion()
