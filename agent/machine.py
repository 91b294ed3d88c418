"""The agent's state machine: states run in turn as the ONE transition table says, until done or failed(reason).

Each state declares the context fields it `needs` and the ones it `produces`; the machine checks both, so a state
can never run on missing inputs or silently leave out its result. A state returns an outcome name; a NaocalError
raised inside it (a timeout, a refused command, a bad file, an implausible fit) ends the run in `failed` with the
error as the reason. Ctrl-C (KeyboardInterrupt) inside a state ends the run in `interrupted`, so that the caller can
still say what was done and how to continue; the reason names what stopped it (`interrupt_cause`: Ctrl-C, or the
signal tools.cli turned into a KeyboardInterrupt, e.g. SIGTERM). Anything else is a bug: it is logged with its
traceback and raised.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from naocal.solver.errors import NaocalError

log = logging.getLogger(__name__)

DONE, FAILED, INTERRUPTED = "done", "failed", "interrupted"

# (state, outcome) -> next state. The whole control flow of the agent.
TRANSITIONS = {
    ("modelling", "ok"): "measurement",
    ("measurement", "ok"): "identification",
    ("measurement", "dataset_only"): DONE,  # naocal simulate: the dataset is the product
    ("identification", "ok"): "compensation",
    ("identification", "implausible"): FAILED,
    ("compensation", "ok"): "verification",
    ("verification", "ok"): DONE,
}


@dataclass
class Outcome:
    name: str
    reason: str = ""


@dataclass
class Step:
    """One state's run, for the log and the summary."""

    state: str
    outcome: str
    reason: str
    wall_s: float
    robot_s: float


@dataclass
class RunResult:
    final: str  # DONE, FAILED or INTERRUPTED
    reason: str
    history: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.final == DONE


class State:
    """A state: `run(ctx)` reads the fields in `needs`, sets those in `produces`, returns an Outcome."""

    name = "abstract"
    needs: tuple[str, ...] = ()
    produces: tuple[str, ...] = ()

    def run(self, ctx) -> Outcome:
        raise NotImplementedError


class Machine:
    def __init__(self, states, transitions=None, start: str = "modelling"):
        self.states = {s.name: s for s in states}
        self.transitions = TRANSITIONS if transitions is None else transitions
        self.start = start  # a machine may hold only some of the table's states (naocal simulate stops early)

    def run(self, ctx, clock=None) -> RunResult:
        """Run from `start` until done or failed. `clock()` gives robot time for the history (optional)."""
        current = self.start
        history = []
        while current not in (DONE, FAILED):
            state = self.states.get(current)
            if state is None:
                raise RuntimeError(f"the transition table leads to state {current}, which this machine lacks")
            missing = [n for n in state.needs if getattr(ctx, n, None) is None]
            if missing:
                raise RuntimeError(f"state {current} needs {', '.join(missing)}, which no earlier state produced")
            log.info("state %s: start", current)
            wall0, robot0 = time.perf_counter(), _safe_clock(clock)
            try:
                outcome = state.run(ctx)
            except NaocalError as err:
                outcome = Outcome("error", f"{current}: {err}")
            except KeyboardInterrupt as interrupt:
                cause = interrupt_cause(interrupt)
                history.append(Step(current, "interrupted", cause, time.perf_counter() - wall0,
                                    _safe_clock(clock) - robot0))
                log.info("state %s: interrupted (%s)", current, cause)  # the caller says it, once
                return RunResult(INTERRUPTED, f"{current}: interrupted ({cause})", history)
            except Exception:
                log.exception("state %s: unexpected error (a bug)", current)
                raise
            step = Step(current, outcome.name, outcome.reason, time.perf_counter() - wall0,
                        _safe_clock(clock) - robot0)
            history.append(step)
            log.info("state %s: %s%s (%.1f s wall, %.1f s robot)", current, outcome.name,
                     f" ({outcome.reason})" if outcome.reason else "", step.wall_s, step.robot_s)
            if outcome.name == "error":
                return RunResult(FAILED, outcome.reason, history)
            absent = [n for n in state.produces if getattr(ctx, n, None) is None] if outcome.name == "ok" else []
            if absent:
                raise RuntimeError(f"state {current} ended ok without producing {', '.join(absent)}")
            nxt = self.transitions.get((current, outcome.name))
            if nxt is None:
                raise RuntimeError(f"no transition for outcome '{outcome.name}' of state {current}")
            if nxt == FAILED:
                return RunResult(FAILED, f"{current}: {outcome.reason}", history)
            current = nxt
        return RunResult(DONE, "", history)


def interrupt_cause(interrupt: KeyboardInterrupt) -> str:
    """What stopped the run: the signal's name that tools.cli's handler raised the KeyboardInterrupt with (SIGTERM,
    SIGHUP), or Ctrl-C (Python raises its own KeyboardInterrupt for SIGINT, with no message)."""
    return str(interrupt) or "Ctrl-C"


def _safe_clock(clock) -> float:
    if clock is None:
        return 0.0
    try:
        return float(clock())
    except Exception:  # a dead robot connection must not hide the state's own result
        return float("nan")
