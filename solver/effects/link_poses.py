"""Link poses (an arm's, kinds.arm.model.ArmModel): the full pose error of each joint origin.

    A_k = F_{k-1} @ T_origin_k @ Trans(t_k) @ Exp(r_k)         in the joint's frame, before its motion

`link_pose.<origin>.<x|y|z>` t_k (m) and `link_pose.<origin>.<rx|ry|rz>` r_k (rad); the origin named by the URDF
link it ends, as link_lengths names it. A superset of link_lengths and, about the joint's axis, of joint_offsets:
the gauges (kinds.arm.identify.identifiable) keep those and fix what they already say.
"""

import math

from naocal.solver.effect import POSE_COMPONENTS, Effect, Parameter


class LinkPoses(Effect):
    name = "link_poses"
    order = 81
    summary = "full pose error of each joint origin: translation (m) and rotation (rad) in the joint frame"
    prior_size = {"m": 2e-3, "rad": math.radians(1.0)}
    gauge_priority = 5

    def arm_parameters(self, arm):
        return [Parameter(f"link_pose.{arm.origin_names[o]}.{q}", self.name, unit, arm.scale, joint=key[1],
                          component=q, index=o, axis=c)
                for o, key in enumerate(arm.origin_keys) if key[0] == "joint"
                for c, (q, unit) in enumerate(POSE_COMPONENTS)]


EFFECT = LinkPoses()
