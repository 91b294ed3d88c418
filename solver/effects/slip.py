"""Slip (a differential drive's): the wheels' ground speed lost in turns, growing with the turn rate; v and omega
scaled by

    1 - slip_s_per_m r |w_r - w_l|        r the wheel radius, w the wheels' speeds (rad/s)
"""

from naocal.solver.effect import Effect, Parameter


class Slip(Effect):
    name = "slip"
    order = 91
    summary = ("a differential drive's slip: speed and turn rate scaled by 1 - slip r |w_r - w_l| "
               "(ground speed lost in turns, s/m)")

    def drive_parameters(self):
        return [Parameter("slip_s_per_m", self.name, "s/m", 0.3, component="slip_s_per_m")]


EFFECT = Slip()
