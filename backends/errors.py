"""Errors of the robot side: a refused command, a robot that does not answer in time, a failed bridge. User-facing
(NaocalError: one line, exit 2), raised by the backends and the agent."""

from naocal.solver.errors import NaocalError


class RobotTimeout(NaocalError):
    """A wait on the robot passed its deadline."""


class BridgeError(NaocalError):
    """The network bridge failed after its retries, or the server answered with an error."""


class RobotFault(NaocalError):
    """The robot sent a reading that cannot be trusted (not a number, not finite, beyond the joint's limits): the
    driver is in its safe state and refuses motion until it is restarted (docs/DEPLOY.md)."""
