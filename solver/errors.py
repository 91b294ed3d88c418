"""Typed errors raised at naocal's boundaries.

A `NaocalError` is a user-facing problem (bad file, bad argument, robot that never settles): the CLI prints its
message on one line and exits non-zero without a traceback. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class NaocalError(Exception):
    """A problem the user can act on. `str(err)` is a complete one-line message."""

    exit_code = 2


class DataError(NaocalError):
    """Bad input data. Names the file and, when known, the line and the field."""

    def __init__(self, path, problem, *, line=None, field=None):
        self.path = str(path)
        self.problem = problem
        self.line = line
        self.field = field
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {problem}")


class SolveError(NaocalError):
    """Identification failed or cannot be trusted; nothing is written."""

    exit_code = 3


class DiskFullError(NaocalError):
    """A write failed for want of space (ENOSPC) or quota (EDQUOT). Names the file and the free space; what was
    saved before stays intact (writes are atomic or appended whole)."""

    exit_code = 3

    def __init__(self, path, free_bytes: int | None, reason: str = "no space left on the device"):
        self.path = str(path)
        self.free_bytes = free_bytes
        free = "free space unknown" if free_bytes is None else f"{free_bytes} bytes free"
        super().__init__(f"cannot write {self.path}: {reason} ({free})")


class SafetyError(NaocalError):
    """A command was refused because it would leave the joint limits (solver.limits) or collide (the backends)."""
