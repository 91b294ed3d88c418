"""The agent's entry points: calibrate a robot end to end, or only record a dataset (naocal simulate).

    result, ctx = calibrate(backend, out_dir, AgentSettings(seed=0))

Files under out_dir (DIR): plan.json, dataset/ (naocal.dataset/2, images/), progress.json, offsets.json
(+ offsets.json.bak), verification/, verification.json, summary.txt, calibrate.log.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

from agent.machine import Machine, RunResult
from agent.measure import opencv_detector
from agent.summary import summary_text
from agent.states import AgentSettings, Context, calibrate_states, simulate_states
from solver.fileio import atomic_write_text

log = logging.getLogger(__name__)


@contextlib.contextmanager
def log_to_file(path: Path, level=logging.INFO):
    """Send the log of everything (agent, solver, backends) to `path` while the block runs."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > level:
        root.setLevel(level)
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(old_level)
        handler.close()


def calibrate(backend, out_dir, settings: AgentSettings = AgentSettings(), *, detector=None,
              backend_label: str | None = None, truth: dict | None = None) -> tuple[RunResult, Context]:
    """Run modelling -> measurement -> identification -> compensation -> verification on `backend`.

    Writes summary.txt even when the run fails. `truth` (mock only) adds a comparison to the summary; the agent
    itself never sees it.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ctx = Context(backend=backend, settings=settings, out_dir=out_dir, dataset_dir=out_dir / "dataset",
                  progress_path=out_dir / "progress.json", plan_path=out_dir / "plan.json",
                  detector=detector or opencv_detector)
    with log_to_file(out_dir / "calibrate.log"):
        log.info("naocal calibrate: backend %s, seed %d, output %s%s", backend_label or backend.name, settings.seed,
                 out_dir, " (resume)" if settings.resume else "")
        try:
            result = Machine(calibrate_states()).run(ctx, clock=backend.now)
        finally:
            ctx.close()
        text = summary_text(ctx, result, backend_label=backend_label or backend.name, truth=truth)
        atomic_write_text(out_dir / "summary.txt", text)
        log.info("run ended: %s%s", result.final, f" ({result.reason})" if result.reason else "")
    return result, ctx


def simulate(backend, dataset_dir, settings: AgentSettings = AgentSettings(), *, detector=None
             ) -> tuple[RunResult, Context]:
    """Modelling and measurement only: record the standard plan's dataset in `dataset_dir` (no plan.json,
    no progress file: the directory holds the dataset alone)."""
    dataset_dir = Path(dataset_dir)
    ctx = Context(backend=backend, settings=settings, out_dir=dataset_dir, dataset_dir=dataset_dir,
                  progress_path=None, plan_path=None, detector=detector or opencv_detector)
    try:
        result = Machine(simulate_states()).run(ctx, clock=backend.now)
    finally:
        ctx.close()
    return result, ctx
