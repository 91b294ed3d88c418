"""Elasticity: a joint yields to the static gravity torque of the links it carries.

    q_true = theta - c + C_j * tau_j(q_true)

tau_j the gravity torque of the distal links and the target's board (its mass at its centre), positive when
gravity turns the joint in +q, taken at the joint's own, sagging angle (the model solves this implicitly and
differentiates it exactly). Modelled for chains that hang free (a robot on its back with sandals); a chain that
carries the body (a standing robot's support leg) has no such term.

An arm (kinds.arm.model.ArmModel) has the term on every revolute joint, tau from the URDF's masses and what the tip
carries, taken at the readings (a fixed regressor: the sag's own change of tau is second order in C).
"""

import math

import numpy as np

from naocal.solver.effect import Effect, JointTerm, MockPerturbation, Parameter
from naocal.solver.effects._common import apparent_offset_panels, joint_section, per_joint, read_joint_section


class Elasticity(Effect):
    name = "elasticity"
    order = 10
    summary = "compliance C of each joint on hanging chains (+ C * gravity torque at the sagging angle)"
    plausible_limit = 0.2  # rad/(N m): 11 deg per N m; gravity torques are 0.05-0.3 N m
    no_signal_hint = "no gravity torque on the joints of the chains to the targets"
    offsets_section, offsets_key = "body", "elasticity_rad_per_nm"
    offsets_limit = 1.0
    mock_size_unit, mock_stream = "rad/(N m)", 1
    plausible_min, plausible_min_why = 0.0, "a compliance is never negative"
    prior_size = {"rad/(N m)": math.radians(0.05)}  # an arm: 0.5 deg under 10 N m, a soft gear
    gauge_priority = 6

    def parameters(self, setup):
        return per_joint(self, "elasticity", setup.target_joints(), "rad/(N m)", 0.02)

    def arm_parameters(self, arm):
        if any(arm.prismatic):
            raise ValueError("elasticity with a prismatic joint is not modelled (its gravity force is not a torque)")
        return [Parameter(f"elasticity.{j}", self.name, "rad/(N m)", arm.scale, joint=j) for j in arm.joint_names]

    def joint_terms(self, layout):
        tau = layout.data.tau
        return [JointTerm(i, c, tau[:, c], gravity=True) for i, p in layout.params(self.name)
                for c in [layout.column(p.joint)]]

    def untestable_reason(self, data):
        if not any(data.robot.target(t).load == "hanging" for t in np.unique(data.target)):
            return "every target is on a chain that carries the body: no free-hanging chain to yield to gravity"
        return ""

    def partial_residual_panels(self, fit):
        from naocal.solver.model import gravity_torques_of

        data = fit.model.data
        # the fitted model's own gravity torques: its joints sag, so they differ from those at the readings
        tau = gravity_torques_of(data, fit.model.joint_angles(fit.values))
        size = {p.joint: abs(fit.value(p.name)) * np.ptp(tau[:, data.column(p.joint)])
                for p in fit.registry.parameters if p.effect == self.name}
        joints = sorted(size, key=lambda j: -size[j])[:3]
        return apparent_offset_panels(fit, "elasticity", joints, lambda c: tau[:, c],
                                      lambda j: f"gravity torque on {j} (N m)")

    def mock_perturbation(self, rng, size, setup):
        """Compliance size * U(0.5, 1.5) on each joint of the chains to the targets; the mock's PyBullet masses
        give the torques (q_true = servo + alpha + C tau(q_true), solved by fixed-point iteration)."""
        joints = setup.target_joints()
        compliance = {j: float(size * f) for j, f in zip(joints, rng.uniform(0.5, 1.5, len(joints)))}
        return MockPerturbation(compliance_rad_per_nm=compliance, record={"compliance_rad_per_nm": compliance})

    def display(self, parameter, value):
        return math.degrees(value), "deg/(N m)"

    def write_offsets(self, values, setup):
        return joint_section(self, values, setup)

    def read_offsets(self, content, path, where, robot):
        read_joint_section(self, content, path, where, robot, "rad/(N m)")


EFFECT = Elasticity()
