"""PWM driver (a differential drive's): the duties sent pass a PWM motor driver before the motors, which get its
floored PWM above its floor as a duty, not the duty logged. A choice of model without a parameter (the drive
model's motor duties; the kind supplies its driver's PWM range): a log does not say which driver sent its duties,
so it is named like an effect (identify --effects), and diagnose judges it by its refit, not a score test.
"""

from naocal.solver.effect import Effect


class PwmDriver(Effect):
    name = "pwm_driver"
    order = 95
    summary = ("a differential drive's PWM motor driver: the motors get the floored PWM above its floor, not the duty "
               "logged (a choice of model, no parameter)")

    def drive_parameters(self):
        return []


EFFECT = PwmDriver()
