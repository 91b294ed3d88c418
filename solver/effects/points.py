"""Points (an arm's, kinds.arm.model.ArmModel): where each observed point (marker corner, reflector) sits on the tool.

    p_tool = p0 + t + (Exp(r) - I)(p0 - c)        p0 the point's nominal position in the tip frame (dataset.json)

A printed marker's corners (dataset.json's `marker`) are one rigid body: glued off by a translation t and a turn r
about its centre c (the mean of its corners' nominal positions), its printed size kept, which is what gives cameras
a metric scale (without it every length and the cameras' distance scale together). A point of no marker (a
reflector) moves by t alone.

`point.<marker or point>.<x|y|z>` t (m) and, for a marker, `point.<marker>.<rx|ry|rz>` r (rad), in the tool's frame.
"""

import math

from naocal.solver.effect import POSE_COMPONENTS, Effect, Parameter


class Points(Effect):
    name = "points"
    order = 82
    summary = "pose error of each marker (its corners rigid) or position error of each other point on the tool"
    prior_size = {"m": 3e-3, "rad": math.radians(3.0)}  # a marker or reflector glued by hand: mm and degrees
    gauge_priority = 4

    def arm_parameters(self, arm):
        return [Parameter(f"point.{body}.{q}", self.name, unit, arm.scale, component=q, index=b, axis=c)
                for b, (body, rigid) in enumerate(zip(arm.body_names, arm.body_rigid))
                for c, (q, unit) in enumerate(POSE_COMPONENTS[:6 if rigid else 3])]


EFFECT = Points()
