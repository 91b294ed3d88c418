"""Sensors (an arm's, kinds.arm.model.ArmModel): the frame of each external sensor that sees the arm's points.

    y = Exp(rotation correction) @ R0 @ p + translation          T_sensor_mount = (R, t)

`sensor.<name>.rotation.<x|y|z>` the correction's rotation vector (rad; reported as R's own rotation vector),
`sensor.<name>.translation.<x|y|z>` t (m). Always in the arm's model, never fixed: found from the data, anywhere
(no prior); `naocal verify --refit sensors` refits them on new data.
"""

from naocal.solver.effect import Effect, Parameter

AXES = "xyz"


class Sensors(Effect):
    name = "sensors"
    order = 80
    summary = "pose of each external sensor (tracker, camera) in the frame it is mounted on: rotation, translation"
    scale = 0.01
    gauge_priority = 0
    arm_always = True
    arm_gauge = False  # found from the data, anywhere

    def arm_parameters(self, arm):
        return [Parameter(f"sensor.{sensor.name}.{part}.{a}", self.name, unit, self.scale, component=f"{part}.{a}",
                          index=s, axis=first + c)
                for s, sensor in enumerate(arm.sensors)
                for part, unit, first in (("rotation", "rad", 3), ("translation", "m", 0)) for c, a in enumerate(AXES)]


EFFECT = Sensors()
