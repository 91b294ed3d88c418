"""Wheel lag (a differential drive's): each wheel's speed follows its command with a first-order lag of time
constant `wheel_lag_s`.

Started at 0.06 s (a typical small geared motor's), not 0: on frames grabbed at rest after the wheels settle the
lag's signature is what they still turn at the grab, exp(-t / lag), whose derivative at lag 0 is 0: a fit started
there stays there, and a score test there sees nothing. Fitted from the fit without it (drive_from_base_fit).
"""

from naocal.solver.effect import Effect, Parameter


class WheelLag(Effect):
    name = "wheel_lag"
    order = 92
    summary = "a differential drive's wheel lag: each wheel's speed follows its command with this time constant (s)"
    drive_from_base_fit = True

    def drive_parameters(self):
        return [Parameter("wheel_lag_s", self.name, "s", 0.05, component="wheel_lag_s", start=0.06)]


EFFECT = WheelLag()
