"""Errors of the robot side: a refused command, a robot that does not answer in time, a failed bridge. User-facing
(NaocalError: one line, exit 2), raised by the backends and the agent."""

from solver.errors import NaocalError, SafetyError  # noqa: F401 (a refused command: the limits' own, solver.limits)


class RobotTimeout(NaocalError):
    """A wait on the robot passed its deadline."""


class BridgeError(NaocalError):
    """The network bridge failed after its retries, or the server answered with an error."""
