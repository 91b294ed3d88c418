"""Pieces several effects share: per-joint parameters and file sections, and the apparent-offset picture."""

from __future__ import annotations

import numpy as np

from naocal.solver import fields
from naocal.solver.effect import Effect, Parameter, ProjectionTerm


def per_joint(effect, prefix: str, joints, unit: str, scale: float) -> list[Parameter]:
    """One parameter `<prefix>.<joint>` per joint."""
    return [Parameter(f"{prefix}.{j}", effect.name, unit, scale, joint=j) for j in joints]


def joint_section(effect, values: dict, setup) -> dict:
    """{joint: value} of the effect's per-joint parameters present in `values`."""
    return {p.joint: float(values[p.name]) for p in effect.parameters(setup) if p.name in values}


def read_joint_section(effect, content, path, where, robot, unit: str) -> None:
    """{joint: value}: joints of the robot description, finite values within the effect's file limit."""
    fields.json_object(content, path, where, optional=robot.joints, keys="joint")
    for joint, value in content.items():
        fields.number(value, path, f"{where}.{joint}", limit=effect.offsets_limit, unit=unit)


def per_name_section(values: dict, parameters, key) -> dict:
    """{key(p): {component: value}} of the parameters present in `values` (e.g. per camera or per target)."""
    out = {}
    for p in parameters:
        if p.name in values:
            out.setdefault(key(p), {})[p.component] = float(values[p.name])
    return out


def read_per_name_section(content, path, where, names, components, limits, units, *, complete=True) -> None:
    """{name: {component: value}} with names from `names`, every component (when `complete`) within its limit."""
    fields.json_object(content, path, where, optional=names, keys="name")
    for name, entry in content.items():
        fields.json_object(entry, path, f"{where}.{name}", components if complete else (),
                           () if complete else components)
        for component, value in entry.items():
            fields.number(value, path, f"{where}.{name}.{component}", limit=limits[component], unit=units[component])


def apparent_offset_panels(fit, prefix: str, joints, regressor, xlabel, *, jitter=0.0, slope_from_value=True):
    """Panels of the apparent per-image error of each joint (the fitted term `<prefix>.<joint>` plus what remains)
    against a per-image regressor (M,) of that joint: `regressor(column)`, labelled `xlabel(joint)`."""
    from naocal.solver.diagnostics import apparent_errors, partial_residuals

    data = fit.model.data
    panels = []
    for k, joint in enumerate(joints):
        term = f"{prefix}.{joint}"
        offset = _offset_name(fit, joint)
        # the apparent c of the joint: the fitted term is -dq, so q_true = theta - c_apparent
        c_apparent = apparent_errors(fit, [offset], partial_residuals(fit, [term]))[:, 0]
        ok = np.isfinite(c_apparent)
        x = regressor(data.column(joint))
        value = fit.value(term)
        slope, const = (value, 0.0) if slope_from_value else (0.0, value)
        xs = np.linspace(np.min(x[ok]), np.max(x[ok]), 2) if ok.any() else np.zeros(2)
        shake = np.random.default_rng(k).uniform(-jitter, jitter, ok.sum()) if jitter else 0.0
        # shown as the apparent joint error alpha = -c: what the term adds to the joint angle
        panels.append((x[ok] + shake, np.degrees(-c_apparent[ok]), xlabel(joint), f"apparent {joint} error (deg)",
                       data.target[ok], (xs, np.degrees(const + slope * xs) * (1 if slope_from_value else -1))))
    return panels


def _offset_name(fit, joint):
    setup = fit.registry.setup
    return ("head_offset." if joint in setup.camera_joints() else "joint_offset.") + joint


class CameraCorrections(Effect):
    """Corrections of some of each camera's intrinsic components (solver.camera.COMPONENTS) to the prior: one
    parameter `<prefix>.<camera>.<component>` each, a projection term, a per-camera section of the offsets file.
    The intrinsics and distortion effects are this with their components."""

    prefix: str = ""
    components: tuple = ()
    unit: str = "1"
    scale: float = 1.0
    non_rigid = True

    def parameters(self, setup):
        return [Parameter(f"{self.prefix}.{cam}.{k}", self.name, self.unit, self.scale, camera=cam, component=k)
                for cam in setup.cameras for k in self.components]

    def projection_terms(self, layout, values):
        return [ProjectionTerm(i, p.camera, p.component, float(values[i])) for i, p in layout.params(self.name)
                if p.camera in layout.cameras]

    def fitted(self, fit, camera: str):
        """value(component) of the fit's correction of `camera`'s component, 0 when the fit has none."""
        prefix = f"{self.prefix}.{camera}."
        return lambda k: fit.value(prefix + k) if prefix + k in fit.registry.index else 0.0

    def write_offsets(self, values, setup):
        return per_name_section(values, self.parameters(setup), lambda p: p.camera)

    def read_offsets(self, content, path, where, robot):
        read_per_name_section(content, path, where, tuple(robot.cameras), self.components,
                              dict.fromkeys(self.components, self.offsets_limit),
                              dict.fromkeys(self.components, self.unit), complete=False)
