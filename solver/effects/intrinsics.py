"""Intrinsics: corrections of each camera's focal lengths and principal point to the dataset's prior.

    (u, v) = (cx + dcx + (fx + dfx) * xd, cy + dcy + (fy + dfy) * yd)
"""

import numpy as np

from naocal.solver.effect import MockPerturbation
from naocal.solver.effects._common import CameraCorrections

COMPONENTS = ("fx", "fy", "cx", "cy")


class Intrinsics(CameraCorrections):
    name = "intrinsics"
    order = 50
    summary = "corrections of each camera's fx, fy, cx, cy to the prior"
    prefix, components, unit, scale = "intrinsics", COMPONENTS, "px", 5.0
    plausible_limit = 60.0  # px: 10 % of the focal length
    offsets_section, offsets_key = "head", "intrinsics_correction_px"
    offsets_limit = 200.0
    mock_size_unit, mock_stream = "px", 5

    def partial_residual_panels(self, fit):
        from naocal.solver.diagnostics import partial_residuals

        data = fit.model.data
        r_off = partial_residuals(fit, [self.name])
        groups = data.target[data.image_of_row]
        panels = []
        for cam in np.unique(data.camera):
            rows = data.camera[data.image_of_row] == cam
            intr = data.cameras[cam]
            get = self.fitted(fit, cam)
            for axis, (f, c, fk, ck) in enumerate((("fx_px", "cx_px", "fx", "cx"), ("fy_px", "cy_px", "fy", "cy"))):
                d = data.uv_px[rows, axis] - intr[c]
                xs = np.array([d.min(), d.max()])
                panels.append((d, r_off[rows, axis], f"{'u - cx' if axis == 0 else 'v - cy'} (px), {cam}",
                               f"partial residual {'x' if axis == 0 else 'y'} (px)", groups[rows],
                               (xs, -(get(fk) * xs / intr[f] + get(ck)))))
        return panels

    def mock_perturbation(self, rng, size, setup):
        """The cameras' true focal lengths off the prior: fx by s * size, fy by s * size * U(0.7, 1.3), s = +-1."""
        sign = rng.choice([-1.0, 1.0])
        ratio = rng.uniform(0.7, 1.3)
        delta = {"fx": float(sign * size), "fy": float(sign * size * ratio)}
        return MockPerturbation(intrinsics_px=delta, record={"delta_px": dict(delta)})


EFFECT = Intrinsics()
