"""Tool (an arm's, kinds.arm.model.ArmModel): the pose error of the tool (the end-effector mount) on each chain's tip.

    p_tip = Trans(t_T) @ Exp(r_T) @ p_tool        p_tool a point on the tool (its nominal position plus `points`)

`tool.<chain>.<x|y|z>` t_T (m) and `tool.<chain>.<rx|ry|rz>` r_T (rad), in the tip's frame.
"""

import math

from naocal.solver.effect import POSE_COMPONENTS, Effect, Parameter


class Tool(Effect):
    name = "tool"
    order = 83
    summary = "pose error of the tool (end-effector mount) on each chain's tip: translation (m), rotation (rad)"
    prior_size = {"m": 5e-3, "rad": math.radians(1.0)}  # a tool mounted on its flange by hand: mm and a degree
    gauge_priority = 3

    def arm_parameters(self, arm):
        return [Parameter(f"tool.{ac.name}.{q}", self.name, unit, arm.scale, component=q, index=c, axis=i)
                for c, ac in enumerate(arm.arm_chains) for i, (q, unit) in enumerate(POSE_COMPONENTS)]


EFFECT = Tool()
