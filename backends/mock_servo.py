"""The realistic mock's joint servo: how a joint follows its interpolated command, and where it comes to rest.

Dynamics. The command is interpolated into a reference r(t) that runs in straight lines (backends.mock._Track).
The joint's sensor-space position follows r through a second-order system with unit gain,
    y'' + 2 zeta omega y' + omega^2 y = omega^2 r,
damping ratio zeta < 1 and decay time constant T = 1 / (zeta omega). For a piecewise linear r the response is
exact in closed form (no integration, so the state at any past time is exact, as everywhere in the mock):
    y(t) = r(t) - G r'(t) - sum_k ds_k h(t - t_k),
where t_k are the instants at which r's slope changes by ds_k, G = 2 zeta / omega is the lag with which the joint
follows a ramp, and h(tau) -> 0 is the decaying part of the error after a unit change of slope. A change of the
rest offset by a step J at t_k (see below) adds J (1 - f(t - t_k)), f the error after a unit step.

Rest. Where a still joint stands inside (or off) its commanded encoder step: backends.mock_realism.Realism's
`servo_rest`, and the sag tau / K under the gravity torque tau (`rest_offsets`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SecondOrder:
    """A unit-gain underdamped second-order response with decay time constant `time_constant_s` and damping."""

    time_constant_s: float
    damping: float

    @property
    def omega(self) -> float:
        return 1.0 / (self.damping * self.time_constant_s)

    @property
    def ramp_lag_s(self) -> float:
        """G: how far behind a ramp the joint runs, in time."""
        return 2.0 * self.damping / self.omega

    @property
    def horizon_s(self) -> float:
        """After this long a transient has decayed below 1e-12 of its size (e^-28)."""
        return 28.0 * self.time_constant_s

    def step_error(self, tau) -> np.ndarray:
        """f(tau): the remaining error tau after a unit step of the reference (1 at 0, 0 at infinity)."""
        tau = np.asarray(tau, dtype=float)
        z = self.damping
        wd = self.omega * math.sqrt(1.0 - z * z)
        a = z * self.omega
        out = np.exp(-a * tau) * (np.cos(wd * tau) + (a / wd) * np.sin(wd * tau))
        return np.where(tau >= 0.0, out, 1.0)

    def ramp_transient(self, tau) -> np.ndarray:
        """h(tau): the decaying part of the tracking error tau after the reference's slope changed by 1/s
        (the error itself is G + h(tau) for tau >= 0, h(0) = -G)."""
        tau = np.asarray(tau, dtype=float)
        z, w = self.damping, self.omega
        wd = w * math.sqrt(1.0 - z * z)
        a = z * w
        out = np.exp(-a * tau) * (-2.0 * a * np.cos(wd * tau) + (wd - a * a / wd) * np.sin(wd * tau)) / (w * w)
        return np.where(tau >= 0.0, out, 0.0)

    def step_response(self, tau) -> np.ndarray:
        """The response to a unit step at 0 (overshoots by exp(-pi zeta / sqrt(1 - zeta^2)))."""
        return 1.0 - self.step_error(tau)

    def overshoot(self) -> float:
        z = self.damping
        return math.exp(-math.pi * z / math.sqrt(1.0 - z * z))

    def settling_time_s(self, tolerance: float = 0.02) -> float:
        """Time after which a step response stays within `tolerance` of its final value (envelope bound)."""
        z = self.damping
        return self.time_constant_s * math.log(1.0 / (tolerance * math.sqrt(1.0 - z * z)))


def servo_positions(t: float, reference, slope, slope_changes, dyn: SecondOrder | None, rest_times, rest_offsets
                    ) -> np.ndarray:
    """The joints' positions (J,) at t (see the module docstring).

    reference, slope : (J,) the references and their slopes at t; slope_changes : per joint ([t_k], [ds_k]), t_k
    increasing; rest_times (E,) increasing, rest_offsets [(J,)]: the rest offsets, each in force from its time on.
    Only changes younger than dyn.horizon_s add transients (older ones have decayed).
    """
    k = bisect.bisect_right(rest_times, t)
    offset = rest_offsets[k - 1] if k else 0.0
    if dyn is None:
        return np.asarray(reference, dtype=float) + offset
    out = np.asarray(reference, dtype=float) - dyn.ramp_lag_s * np.asarray(slope, dtype=float) + offset
    for i, (times, changes) in enumerate(slope_changes):
        lo, hi = bisect.bisect_left(times, t - dyn.horizon_s), bisect.bisect_right(times, t)
        if hi > lo:
            out[i] -= float(np.dot(changes[lo:hi], dyn.ramp_transient(t - np.asarray(times[lo:hi]))))
    for e in range(bisect.bisect_left(rest_times, t - dyn.horizon_s), k):
        before = rest_offsets[e - 1] if e else 0.0
        out -= (rest_offsets[e] - before) * float(dyn.step_error(t - rest_times[e]))
    return out


def rest_offset(command: float, tau_nm: float, mode: str, step: float, stiffness, u: float = 0.0) -> float:
    """Where a still joint commanded to `command` (rad, sensor space) stands, minus the command.

    mode : 'command', 'centre', 'uniform' (at u in [-1/2, 1/2) of the cell) or 'load' (Realism.servo_rest);
    tau_nm : the gravity torque on the joint (positive turns it in +q); stiffness : K in N m/rad or None.
    """
    sag = 0.0 if stiffness is None else tau_nm / stiffness
    if mode == "load":
        return sag
    if step <= 0.0:
        return 0.0 if mode == "command" else sag
    k = round(command / step)
    base = {"command": command, "centre": k * step, "uniform": (k + u) * step}[mode]
    # The servo does not act while its reading stays in the commanded cell: the load pulls the joint up to the
    # cell's edge, and no further (a hair inside, so that the reading is the commanded step).
    edge = 0.5 * step * (1.0 - 1e-4)
    position = min(max(base + sag, k * step - edge), k * step + edge)
    return position - command
