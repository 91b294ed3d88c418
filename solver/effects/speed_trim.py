"""Speed trim (a differential drive's): the trim grows with the duty's magnitude, trim + speed_trim |u| (after the
dead zone): the wheels' mismatch depends on the speed.

    w = sign(u) |u| k / (gain -+ (trim + speed_trim |u|))
"""

from naocal.solver.effect import Effect, Parameter


class SpeedTrim(Effect):
    name = "speed_trim"
    order = 93
    summary = "a differential drive's speed trim: the trim grows with the duty's magnitude, trim + speed_trim |u| (1)"

    def drive_parameters(self):
        return [Parameter("speed_trim", self.name, "1", 0.05, component="speed_trim")]


EFFECT = SpeedTrim()
