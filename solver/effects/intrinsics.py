"""Intrinsics: corrections of each camera's focal lengths and principal point to the dataset's prior.

    (u, v) = (cx + dcx + (fx + dfx) * xd, cy + dcy + (fy + dfy) * yd)

The NAO's model: fx, fy, cx, cy per camera (a projection term). An arm's (kinds.arm.model.ArmModel,
`arm_parameters`): fx, fy, cx, cy and the whole plumb_bob distortion k1, k2, p1, p2, k3 (OpenCV's, solver/camera.py:
xd = xn (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 xn yn + p2 (r^2 + 2 xn^2), ...) of each camera sensor, refined with
the arm about the intrinsics the dataset files, under a prior at a separate checkerboard calibration's error
(ARM_PRIOR): `intrinsics.<camera>.<fx|fy|cx|cy>` (px), `intrinsics.<camera>.<k1|k2|p1|p2|k3>` (1).
"""

import numpy as np

from naocal.solver.camera import COMPONENTS as CAMERA_COMPONENTS
from naocal.solver.effect import MockPerturbation, Parameter
from naocal.solver.effects._common import CameraCorrections

COMPONENTS = ("fx", "fy", "cx", "cy")
DISTORTION = CAMERA_COMPONENTS[4:]  # k1, k2, p1, p2, k3: the order of an intrinsics dict's "distortion"
ARM_COMPONENTS = COMPONENTS + DISTORTION
# An arm camera's filed intrinsics are off by about this much (one std; what a separate checkerboard calibration
# leaves): focal lengths 0.3 % of themselves, the principal point 1.5 px (the sizes kinds/arm/sim.py's
# CAMERA_FILING_ERROR draws, with k1's); the distortion coefficients each about 1-4 px at the image's edge (r^2 ~ 0.75
# at fx 1100 px and 1920 px wide): k1 0.002; k2 0.005 and k3 0.01, larger because a checkerboard fit tells the radial
# terms' sum at the edge far better than each (k2, k3 trade against k1); the tangential p1, p2 0.0005 (a lens
# decentred by a few micrometres: f (r^2 + 2 x^2) p ~ 1 px).
ARM_PRIOR = {"f_rel": 3e-3, "px": 1.5, "k1": 2e-3, "k2": 5e-3, "p1": 5e-4, "p2": 5e-4, "k3": 1e-2}
# The arm's solver works on value / scale: a pixel, and a distortion coefficient in thousandths.
ARM_SCALE = {"px": 1.0, "1": 1e-3}


class Intrinsics(CameraCorrections):
    name = "intrinsics"
    order = 50
    summary = "corrections of each camera's fx, fy, cx, cy to the prior (an arm's camera: and k1, k2, p1, p2, k3)"
    prefix, components, unit, scale = "intrinsics", COMPONENTS, "px", 5.0
    plausible_limit = 60.0  # px: 10 % of the focal length
    offsets_section, offsets_key = "head", "intrinsics_correction_px"
    offsets_limit = 200.0
    mock_size_unit, mock_stream = "px", 5
    prior_size = {"px": ARM_PRIOR["px"], "1": ARM_PRIOR["k1"]}  # the arm's per component: arm_prior_size
    # Last of the arm's gauges: what the data cannot tell from the arm's geometry stays at the filed intrinsics
    # (a separate calibration's), the arm's physical parameters take it; against a camera's frame (its turn moves
    # the image as cx, cy do, but not exactly: perspective) the prior splits it.
    gauge_priority = 7

    def arm_parameters(self, arm):
        def unit(k):
            return "1" if k in DISTORTION else "px"

        return [Parameter(f"{self.prefix}.{sensor.name}.{k}", self.name, unit(k), ARM_SCALE[unit(k)],
                          camera=sensor.name, component=k, index=s)
                for s, sensor in enumerate(arm.sensors) if sensor.kind == "camera" for k in ARM_COMPONENTS]

    def arm_prior_size(self, parameter, arm):
        if parameter.component in ("fx", "fy"):
            return ARM_PRIOR["f_rel"] * arm.sensors[parameter.index].intrinsics[f"{parameter.component}_px"]
        return ARM_PRIOR.get(parameter.component, ARM_PRIOR["px"])

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
