"""A Backend wrapper that applies a calibration: commands + c, readings - c.

With the stored offset c = -alpha (naocal.offsets) and the robot's q_true = theta_measured + alpha, a command
q_req sent as q_req + c makes the servo drive its sensor to q_req + c, so the joint truly stands at
q_req + c + alpha = q_req; and a reading theta gives theta - c = theta + alpha = the true angle.
Joints the offsets do not mention pass unchanged. The limits it reports are the robot's, seen from the
compensated side (a raw limit L is reached by requesting L - c), so checks against them stay exact.
"""

from __future__ import annotations

from naocal.backends.base import Backend, JointReading
from naocal.solver.compensation import compensate_command, correct_reading


class CompensatedBackend(Backend):
    """`backend` seen through the offsets (an Offsets or a {joint: c} mapping, rad)."""

    def __init__(self, backend: Backend, offsets):
        self.inner = backend
        self.offsets = offsets
        table = offsets.joint_offsets_rad if hasattr(offsets, "joint_offsets_rad") else offsets
        self._c = {j: float(c) for j, c in table.items()}
        self.name = f"compensated {backend.name}"

    def robot_identity(self) -> dict:
        return self.inner.robot_identity()

    def joint_names(self):
        return self.inner.joint_names()

    def joint_limits(self):
        return {j: (lo - self._c.get(j, 0.0), hi - self._c.get(j, 0.0))
                for j, (lo, hi) in self.inner.joint_limits().items()}

    def max_speeds(self):
        return self.inner.max_speeds()

    def command(self, targets_rad, speed_fraction):
        self.inner.command(compensate_command(dict(targets_rad), self._c), speed_fraction)

    def read_joints(self) -> JointReading:
        reading = self.inner.read_joints()
        return JointReading(correct_reading(dict(reading.angles_rad), self._c), reading.t_s)

    def set_stiffness(self, names, stiffness):
        self.inner.set_stiffness(names, stiffness)

    def capture(self, camera: str = "bottom"):
        return self.inner.capture(camera)

    @property
    def cameras(self):
        return self.inner.cameras

    def intrinsics(self):
        return self.inner.intrinsics()

    def now(self):
        return self.inner.now()

    def sleep(self, duration_s):
        self.inner.sleep(duration_s)

    def gravity_torso_mps2(self):
        return self.inner.gravity_torso_mps2()

    def close(self):
        """Closing the wrapper leaves the wrapped backend open: its owner closes it."""
