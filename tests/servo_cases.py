"""An independent generator of datasets whose servos do not stand where naocal assumes: the true joint angle, the
reading and the command each follow one of the ways a real position servo behaves (tests' own generator, written
apart from the mock's servo).

servo:
  'step'      the servo drives its sensor to the commanded step: true = reading = the step nearest the command
  'anywhere'  true anywhere inside the commanded step (uniform); the reading is that step
  'command'   true = command (a servo with a finer inner sensor); the reading is the command's step
  'load'      true = command + compliance x gravity torque (a steady error that grows with the load); the reading is
              the step of the true angle
"""

import numpy as np

from naocal.sim.synthetic import dataset_parts, random_plan
from naocal.solver.adapter import make_model_data
from naocal.solver.dataset import Dataset
from naocal.solver.model import Model
from naocal.solver.registry import Registry

STEP_RAD = 2 * np.pi / 4096  # the NAO's 12-bit encoders


def servo_dataset(rng, truth, *, servo="step", step_rad=STEP_RAD, effects=(), pixel_noise_px=0.1,
                  n_stances_per_leg=24, compliance_rad_per_nm=0.0, outliers=0.0, float32=True):
    """(Dataset, truth): readings in float32 radians as LoLA sends them; `outliers` a share of corners moved
    3-20 px (a square off, a reflection)."""
    command, leg, stance, posture = random_plan(rng, n_stances_per_leg, 3)
    step = np.round(command / step_rad) * step_rad
    if servo == "step":
        true = step
    elif servo == "anywhere":
        true = step + rng.uniform(-0.5, 0.5, command.shape) * step_rad
    elif servo == "command":
        true = command.copy()
    elif servo == "load":
        tau = make_model_data(command, leg, stance, posture).tau
        true = command + compliance_rad_per_nm * tau
    else:
        raise ValueError(servo)
    reading = np.round(true / step_rad) * step_rad
    if servo in ("anywhere", "command"):
        reading = step
    direction = rng.choice([-1.0, 1.0], size=command.shape)
    data = make_model_data(true, leg, stance, posture, direction=direction)
    registry = Registry(effects)
    uv = data.uv_px + Model(data, registry).residuals(registry.from_dict(truth))
    uv += rng.normal(0.0, pixel_noise_px, uv.shape)
    if outliers:
        bad = rng.random(len(uv)) < outliers
        angle = rng.uniform(0, 2 * np.pi, bad.sum())
        uv[bad] += rng.uniform(3.0, 20.0, bad.sum())[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    read = make_model_data(reading.astype(np.float32).astype(float) if float32 else reading, leg, stance, posture,
                           direction=direction)
    read.uv_px = uv
    read.commanded = command
    meta, columns = dataset_parts(read, pixel_noise_px=None)
    return Dataset(meta, columns)
