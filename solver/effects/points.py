"""Points (an arm's, kinds.arm.model.ArmModel): where each observed point (marker, reflector) sits on the tool.

    p_tool = p0 + dp          p0 the point's nominal position in the tip frame (dataset.json)

`point.<name>.<x|y|z>` dp (m), in the tool's frame.
"""

from naocal.solver.effect import Effect, Parameter

AXES = "xyz"


class Points(Effect):
    name = "points"
    order = 82
    summary = "position error of each observed point on the end effector (tip frame), m"
    prior_size = {"m": 3e-3}  # a marker or reflector glued by hand
    gauge_priority = 4

    def arm_parameters(self, arm):
        return [Parameter(f"point.{p}.{a}", self.name, "m", arm.scale, component=a, index=i, axis=c)
                for i, p in enumerate(arm.point_names) for c, a in enumerate(AXES)]


EFFECT = Points()
