"""Backlash (gear play): a joint stands off its reading by b_j in the direction it was last driven.

    q_true = theta - c + b_j * dir_j      (dir_j = -1, 0, 1: the approach direction, dataset columns dir_<J>)

A joint always approached from the same side cannot tell b_j from its offset: the diagnostics fix such b_j.
"""

import math

import numpy as np

from naocal.solver.effect import Effect, JointTerm, MockPerturbation
from naocal.solver.effects._common import apparent_offset_panels, joint_section, per_joint, read_joint_section


class Backlash(Effect):
    name = "backlash"
    order = 20
    summary = "half play b of each joint on the chains to the targets (+ b * approach direction)"
    plausible_limit = math.radians(5.0)  # B-Human warns above 5 deg
    no_signal_hint = "no approach directions recorded: approach each pose from both sides"
    offsets_section, offsets_key = "body", "backlash_rad"
    offsets_limit = math.radians(10.0)
    mock_size_unit, mock_stream = "rad", 2
    plausible_min, plausible_min_why = 0.0, "a play is never negative"

    def parameters(self, setup):
        return per_joint(self, "backlash", setup.target_joints(), "rad", 0.01)

    def joint_terms(self, layout):
        direction = layout.data.direction
        return [JointTerm(i, c, direction[:, c]) for i, p in layout.params(self.name)
                for c in [layout.column(p.joint)]]

    def partial_residual_panels(self, fit):
        data = fit.model.data
        size = {p.joint: abs(fit.value(p.name)) * np.ptp(data.direction[:, data.column(p.joint)])
                for p in fit.registry.parameters if p.effect == self.name}
        joints = sorted(size, key=lambda j: -size[j])[:3]
        return apparent_offset_panels(fit, "backlash", joints, lambda c: data.direction[:, c],
                                      lambda j: f"approach direction of {j}", jitter=0.08)

    def mock_perturbation(self, rng, size, setup):
        """Half play size * U(0.5, 1.5) on each joint of the chains to the targets: the joint stands b_j away
        from its servo in the direction of its last command's change (0 before any change)."""
        joints = setup.target_joints()
        play = {j: float(size * f) for j, f in zip(joints, rng.uniform(0.5, 1.5, len(joints)))}
        return MockPerturbation(half_play_rad=play, record={"half_play_rad": play})

    def write_offsets(self, values, setup):
        return joint_section(self, values, setup)

    def read_offsets(self, content, path, where, robot):
        read_joint_section(self, content, path, where, robot, "rad")


EFFECT = Backlash()
