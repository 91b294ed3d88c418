"""Duckietown's differential-drive kinematics, exactly as its kinematics node and wheel driver compute them, as pure
vectorised functions (docs/DUCKIEBOT.md; public source: Duckietown's dt-car-interface kinematics_node and
dt-duckiebot-interface wheels driver, formulas only).

Inverse (a body velocity to duties): v clamped to +-v_max, omega to +-omega_max;
    w_r = (v + omega b / 2) / r,  w_l = (v - omega b / 2) / r,
    u_r = (gain + trim) w_r / k,  u_l = (gain - trim) w_l / k,  each duty clipped to +-limit.
Forward (open loop, duties to motion): w_r = u_r k / (gain + trim), w_l = u_l k / (gain - trim);
    v = r (w_r + w_l) / 2,  omega = r (w_r - w_l) / b.
A robot's true motion is the forward map with its true (hidden) parameters; Duckietown's calibration is the
parameters with which the inverse map makes the robot do what was asked.
"""

from __future__ import annotations

import math

import numpy as np

from naocal.kinds.duckiebot.robot import Kinematics

PWM_MAX = 255  # the wheel driver's 8-bit PWM
PWM_MIN = 60  # the smallest PWM it sends for a non-zero duty (a dead zone, then a jump)
DUTY_DEAD_ZONE = 0.01  # |duty| at or below this sends PWM 0


def inverse_kinematics(v_mps, omega_radps, kin: Kinematics):
    """(u_left, u_right) duties for a body velocity (v forward m/s, omega counter-clockwise rad/s), as Duckietown
    computes them: limits applied, so no returned duty is ever outside [-kin.limit, kin.limit]."""
    v = np.clip(np.asarray(v_mps, dtype=float), -kin.v_max_mps, kin.v_max_mps)
    omega = np.clip(np.asarray(omega_radps, dtype=float), -kin.omega_max_radps, kin.omega_max_radps)
    w_right = (v + 0.5 * omega * kin.baseline_m) / kin.radius_m
    w_left = (v - 0.5 * omega * kin.baseline_m) / kin.radius_m
    u_right = (kin.gain + kin.trim) * w_right / kin.k
    u_left = (kin.gain - kin.trim) * w_left / kin.k
    return np.clip(u_left, -kin.limit, kin.limit), np.clip(u_right, -kin.limit, kin.limit)


def wheel_speeds(u_left, u_right, kin: Kinematics):
    """(w_left, w_right) rad/s of the wheels for duties (the forward map's motor part; duties as given, unclipped:
    the caller's duties are what the robot received)."""
    u_left = np.asarray(u_left, dtype=float)
    u_right = np.asarray(u_right, dtype=float)
    return u_left * kin.k / (kin.gain - kin.trim), u_right * kin.k / (kin.gain + kin.trim)


def body_velocity(w_left, w_right, radius_m: float, baseline_m: float):
    """(v m/s, omega rad/s) of a differential drive whose wheels (both of `radius_m`) turn at w_left, w_right."""
    w_left = np.asarray(w_left, dtype=float)
    w_right = np.asarray(w_right, dtype=float)
    return radius_m * (w_right + w_left) / 2.0, radius_m * (w_right - w_left) / baseline_m


def forward_kinematics(u_left, u_right, kin: Kinematics):
    """(v m/s, omega rad/s) that duties produce on a robot whose true parameters are `kin` (open loop)."""
    return body_velocity(*wheel_speeds(u_left, u_right, kin), kin.radius_m, kin.baseline_m)


def duty_problem(name: str, duty, limit: float = 1.0) -> str | None:
    """Why `duty` may not be sent to a wheel (not a finite number within [-limit, limit]), or None. A bad duty is
    refused, never clipped: the caller has a bug. The one check of the mock, the mission and the ROS driver."""
    if isinstance(duty, bool) or not isinstance(duty, (int, float, np.floating, np.integer)) \
            or not math.isfinite(duty) or abs(duty) > limit:
        return f"{name} duty {duty!r} is not within [-{limit:g}, {limit:g}]"
    return None


def duty_to_pwm(duty):
    """The wheel driver's PWM (0..255, an integer array) for duties: floor(|u| (255 - 60) + 60) when |u| > 0.01,
    else 0; the sign (direction) is the duty's. Duties beyond +-1 are clipped first (the driver's range)."""
    magnitude = np.minimum(np.abs(np.asarray(duty, dtype=float)), 1.0)
    pwm = np.floor(magnitude * (PWM_MAX - PWM_MIN) + PWM_MIN).astype(int)
    return np.where(magnitude > DUTY_DEAD_ZONE, pwm, 0)


def pwm_drift_bound_m(duty: float, duty_offset: float, baseline_m: float, distance_m: float) -> float:
    """The lateral drift over `distance_m` straight that the wheel driver's PWM floor alone allows at `duty` (the
    mean of the two wheels'): each wheel's PWM is floored, losing 0-1 step, so the wheels may differ by up to one
    step, a relative speed difference d = (1 / 195) / (|duty| - duty_offset) (duty_offset: what the motor loses
    before it turns, fit.duty_offset), turning the robot at d v / b: d L^2 / (2 b) off its line after L."""
    relative = 1.0 / (PWM_MAX - PWM_MIN) / max(abs(duty) - duty_offset, 1e-6)
    return relative * distance_m ** 2 / (2.0 * baseline_m)


def integrate_pose(pose, v_mps, omega_radps, dt_s):
    """The planar pose (x, y, theta) after moving at constant (v, omega) for dt_s: the exact arc (a straight line
    when omega is 0). Vectorised over the leading axis of `pose` (..., 3) and the broadcasting velocities."""
    pose = np.asarray(pose, dtype=float)
    x, y, theta = pose[..., 0], pose[..., 1], pose[..., 2]
    v, omega, dt = (np.asarray(a, dtype=float) for a in (v_mps, omega_radps, dt_s))
    dtheta = omega * dt
    # chord of the arc: length v dt sinc(dtheta / 2), along the mean heading; exact for every omega
    chord = v * dt * np.sinc(dtheta / (2.0 * np.pi))
    heading = theta + dtheta / 2.0
    return np.stack(np.broadcast_arrays(x + chord * np.cos(heading), y + chord * np.sin(heading), theta + dtheta),
                    axis=-1)
