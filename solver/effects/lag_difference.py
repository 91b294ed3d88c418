"""Lag difference (a differential drive's, with wheel_lag): the wheels' lags differ, the left wheel_lag_s -
wheel_lag_difference_s / 2, the right + / 2. At every start and stop one wheel leads: the robot turns and turns
back, and creeps sideways (lags +-5 % of 20-60 ms: 15 mm over a calibration's drives, most of a joint fit's 2.9 px
RMS, and the trim biased 0.004, in a simulated mission). Fitted from the fit without it (drive_from_base_fit).
"""

from naocal.solver.effect import Effect, Parameter


class LagDifference(Effect):
    name = "lag_difference"
    order = 94
    summary = ("a differential drive's lag difference: the left wheel's lag less the right's (s; the wheels' lags "
               "wheel_lag_s -+ half of it)")
    drive_from_base_fit = True

    def drive_parameters(self):
        return [Parameter("wheel_lag_difference_s", self.name, "s", 0.005, component="wheel_lag_difference_s")]


EFFECT = LagDifference()
