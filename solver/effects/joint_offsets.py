"""Joint offsets (the paper's Eq. 2): the encoder offset c of every joint on the chains to the targets (an arm:
of every joint of its chains).

    q_true = theta - c          (theta the reading; the paper's alpha = -c)

`joint_offset.<J>` is c, the number robot code stores: ADDED to every command and SUBTRACTED from every reading
(B-Human, HULKs; docs/CONVENTIONS.md), in rad (an arm's prismatic joint: m). Joints on one motor (the NAO's
HipYawPitch) can be tied to one value.
"""

import math

import numpy as np

from naocal.solver.effect import Effect, JointTerm, Parameter
from naocal.solver.effects._common import joint_section, per_joint, read_joint_section


class JointOffsets(Effect):
    name = "joint_offsets"
    order = 0
    base = True
    summary = "encoder offset c of each joint on the chains to the targets (q = theta - c)"
    reading_offsets = True
    plausible_limit = math.radians(20.0)  # real robots: HipYawPitch up to 11.5 deg (HULKs body configs)
    offsets_section, offsets_key = "body", "joint_offsets_rad"
    offsets_limit = math.radians(20.0)
    prior_size = {"rad": math.radians(2.0), "m": 2e-3}  # encoder zeros are off by degrees (a slide's by mm)
    gauge_priority = 1

    def parameters(self, setup):
        return per_joint(self, "joint_offset", setup.target_joints(), "rad", 0.01)

    def arm_parameters(self, arm):
        units = ["m" if sliding else "rad" for sliding in arm.prismatic]
        return [Parameter(f"joint_offset.{j}", self.name, unit, arm.scale, joint=j)
                for j, unit in zip(arm.joint_names, units)]

    def tie(self, parameter, setup):
        partner = setup.robot.motor_partner(parameter.joint)
        return f"joint_offset.{partner}" if partner else None

    def joint_terms(self, layout):
        minus_one = -np.ones(layout.n_images)  # (an arm's layout: per observation)
        return [JointTerm(i, layout.column(p.joint), minus_one) for i, p in layout.params(self.name)]

    def write_offsets(self, values, setup):
        section = joint_section(self, values, setup)
        for group in setup.robot.shared_motors:  # one motor, one sensor: a joint its partner's estimate stands for
            known = [j for j in group if j in section]
            for joint in group:
                if known and joint not in section:
                    section[joint] = section[known[0]]
        return {j: section[j] for j in setup.robot.joints if j in section}

    def read_offsets(self, content, path, where, robot):
        read_joint_section(self, content, path, where, robot, "rad")


EFFECT = JointOffsets()
