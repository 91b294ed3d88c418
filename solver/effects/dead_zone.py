"""Dead zone (a differential drive's): the duty's magnitude less `dead_zone` drives the wheel, 0 inside it, both
wheels alike (the duty a motor loses to its static friction before it turns).

    w = sign(u) max(|u| - dead_zone, 0) k / (gain -+ trim)        u the duty held, k the motor constant
"""

from naocal.solver.effect import Effect, Parameter


class DeadZone(Effect):
    name = "dead_zone"
    order = 90
    summary = "a differential drive's dead zone: the duty's magnitude less it drives each wheel, 0 inside it (duty)"

    def drive_parameters(self):
        return [Parameter("dead_zone", self.name, "1", 0.03, component="dead_zone")]


EFFECT = DeadZone()
