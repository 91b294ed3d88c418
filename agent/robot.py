"""The agent's hands on a Backend: checked commands, approach-direction bookkeeping, and waits with deadlines.

All times are on the backend's clock (simulated for the mock, the robot's for a NAO); every wait has a deadline
and ends in RobotTimeout if the robot does not deliver.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from naocal.agent.safety import SafetyGuard
from naocal.backends.base import Backend, CameraImage
from naocal.backends.errors import RobotTimeout
from naocal.solver.joints import JOINTS

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TimingSettings:
    """How the agent decides that the robot is still and that an image shows the still robot."""

    sample_period_s: float = 0.01  # joint sensors: 100 Hz on a V5
    still_window_s: float = 0.10  # the joints must be still over this long ...
    still_tolerance_rad: float = 0.003  # ... each moving less than this (encoder resolution ~0.0017 rad)
    reach_tolerance_rad: float = 0.05  # and within this of the command (a stuck joint is not "there")
    settle_deadline_s: float = 5.0  # beyond the expected motion time
    exposure_guard_s: float = 0.1  # the mid-exposure time must be this much after the robot was still (and a
    # clock lag between image and joint stamps shorter than this cannot pair a moving robot with a still reading)
    image_poll_s: float = 0.02
    image_deadline_s: float = 2.0


def as_vector(angles: dict) -> np.ndarray:
    return np.array([float(angles[j]) for j in JOINTS])


def as_dict(q14) -> dict:
    return {j: float(a) for j, a in zip(JOINTS, q14)}


@dataclass(frozen=True)
class Rest:
    """The robot at rest: since `t_still_s` (first sample of the still window), last reading `reading_rad`."""

    t_still_s: float
    t_reading_s: float
    reading_rad: np.ndarray


class Robot:
    """Commands through a SafetyGuard and remembers what it commanded.

    direction : (14,) sign of the last change of each joint's command (0 until the joint is first moved).
    """

    def __init__(self, backend: Backend, guard: SafetyGuard, parked14, timing: TimingSettings = TimingSettings(),
                 speed_fraction: float = 0.4):
        self.backend = backend
        self.guard = guard
        self.parked = np.asarray(parked14, dtype=float)
        self.timing = timing
        self.speed_fraction = speed_fraction
        self.speeds = np.array([backend.max_speeds()[j] for j in JOINTS])
        self.commanded = as_vector(backend.read_joints().angles_rad)  # until we command, assume it is where it is
        self.direction = np.zeros(len(JOINTS))
        self.image_delay_s = 0.0  # learned: how long after its exposure an image has arrived
        self.n_commands = 0

    def now(self) -> float:
        return self.backend.now()

    def expected_duration_s(self, start14, target14, speed_fraction) -> float:
        return float(np.max(np.abs(np.asarray(target14) - np.asarray(start14)) / (self.speeds * speed_fraction)))

    def command(self, target14, speed_fraction: float) -> float:
        """Send one checked command; returns the expected motion time (s)."""
        target14 = np.asarray(target14, dtype=float)
        self.guard.check(target14)
        self.backend.command(as_dict(target14), speed_fraction)
        changed = np.abs(target14 - self.commanded) > 1e-12
        self.direction[changed] = np.sign(target14 - self.commanded)[changed]
        duration = self.expected_duration_s(self.commanded, target14, speed_fraction)
        self.commanded = target14.copy()
        self.n_commands += 1
        return duration

    def move(self, target14, speed_fraction: float | None = None) -> Rest:
        """Go to target14 (via a detour if the direct path is not clear) and wait until the joints are still."""
        f = self.speed_fraction if speed_fraction is None else speed_fraction
        still = None
        for waypoint in self.guard.waypoints(self.commanded, target14, f, self.parked):
            t_command = self.now()
            duration = self.command(waypoint, f)
            still = self.wait_still(waypoint, duration, t_command)
        return still

    def read(self) -> tuple[float, np.ndarray]:
        reading = self.backend.read_joints()
        return reading.t_s, as_vector(reading.angles_rad)

    def wait_still(self, target14, expected_s: float, t_command: float) -> Rest:
        """Wait until every joint has moved less than still_tolerance_rad over still_window_s and is within
        reach_tolerance_rad of target14. Deadline: t_command + expected_s + settle_deadline_s."""
        tm = self.timing
        deadline = t_command + expected_s + tm.settle_deadline_s
        remaining = t_command + expected_s - self.now()
        if remaining > 0:
            self.backend.sleep(remaining)  # no point polling while the joints are known to move
        window: deque = deque()
        while True:
            t, q = self.read()
            if not window or t > window[-1][0]:
                window.append((t, q))
            # Keep the shortest tail that still spans the window: samples need not divide it (LoLA: 12 ms).
            while len(window) > 1 and window[-1][0] - window[1][0] >= tm.still_window_s - 1e-9:
                window.popleft()
            if window[-1][0] - window[0][0] >= tm.still_window_s - 1e-9:
                angles = np.array([w[1] for w in window])
                moving = np.ptp(angles, axis=0) > tm.still_tolerance_rad
                away = np.abs(q - target14) > tm.reach_tolerance_rad
                if not moving.any() and not away.any():
                    # Start the still period where the joints stopped: the first sample that equals the rest.
                    return Rest(window[0][0], t, q)
            if self.now() > deadline:
                names = [JOINTS[j] for j in np.flatnonzero(np.abs(q - target14) > tm.reach_tolerance_rad)]
                detail = f"{', '.join(names)} not at the commanded angle" if names else "joints still moving"
                raise RobotTimeout(f"the robot did not come to rest within {expected_s + tm.settle_deadline_s:.1f} s "
                                   f"of robot time ({detail})")
            self.backend.sleep(tm.sample_period_s)

    def wait_image(self, exposed_after_s: float, camera: str = "bottom") -> CameraImage:
        """The first image of `camera` whose mid-exposure time is at or after `exposed_after_s` (images arrive
        late)."""
        tm = self.timing
        start = self.now()
        deadline = max(start, exposed_after_s) + tm.image_deadline_s
        wait = exposed_after_s + self.image_delay_s - start
        if wait > 0:
            self.backend.sleep(wait)
        while True:
            image = self.backend.capture() if camera == "bottom" else self.backend.capture(camera)
            if image is not None and image.t_exposure_s >= exposed_after_s - 1e-9:
                delay = self.now() - image.t_exposure_s
                # Learn the delivery delay from below: never wait longer than the fastest arrival seen.
                self.image_delay_s = delay if self.image_delay_s == 0.0 else min(self.image_delay_s, delay)
                return image
            if self.now() > deadline:
                raise RobotTimeout(f"no image exposed after t = {exposed_after_s:.3f} s arrived within "
                                   f"{tm.image_deadline_s:.1f} s")
            self.backend.sleep(tm.image_poll_s)

    def newest_image(self, camera: str = "bottom") -> CameraImage:
        """Whatever image arrived last, however old (for demonstrating why that is wrong)."""
        deadline = self.now() + self.timing.image_deadline_s
        while True:
            image = self.backend.capture() if camera == "bottom" else self.backend.capture(camera)
            if image is not None:
                return image
            if self.now() > deadline:
                raise RobotTimeout(f"no image arrived within {self.timing.image_deadline_s:.1f} s")
            self.backend.sleep(self.timing.image_poll_s)
