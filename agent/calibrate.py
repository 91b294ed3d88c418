"""The agent's entry points: calibrate a robot end to end, or only record a dataset (naocal simulate).

    result, ctx = calibrate(backend, out_dir, AgentSettings(seed=0))

Files under out_dir (DIR): plan.json, dataset/ (naocal.dataset/2, images/), progress.json, offsets.json
(+ offsets.json.bak), verification/, verification.json, summary.txt, calibrate.log. summary.txt is written however
the run ends (done, failed, Ctrl-C), unless the disk is full: then its text stays in ctx.summary.
"""

from __future__ import annotations

import contextlib
import logging
import shlex
from pathlib import Path

from naocal.agent.machine import Machine, RunResult
from naocal.agent.measure import opencv_detector
from naocal.agent.states import AgentSettings, Context, calibrate_states, dataset_meta, run_finished, simulate_states
from naocal.agent.summary import summary_text
from naocal.solver.dataset import COMPARED_META_KEYS, META_FILE, parse_json_text, read_text, validate_meta
from naocal.solver.errors import DataError, DiskFullError, NaocalError
from naocal.solver.fileio import atomic_write_text, disk_full_as_error

log = logging.getLogger(__name__)


@contextlib.contextmanager
def log_to_file(path: Path, level=logging.INFO):
    """Send the log of everything (agent, solver, backends) to `path` while the block runs."""
    with disk_full_as_error(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        handler = _QuietFileHandler(path, encoding="utf-8")
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


class _QuietFileHandler(logging.FileHandler):
    """A log file that stops, silently, when it cannot be written (a full disk): logging's own answer is a
    traceback on stderr per message, while the run's next data write reports the full disk in one line."""

    def handleError(self, record) -> None:
        self.setLevel(logging.CRITICAL + 1)


def check_same_setup(backend, dataset_dir: Path, source: str) -> None:
    """On --resume: the robot, camera and boards must be the ones the stored dataset was measured with. Checked
    before anything is written (the dataset's appender checks the same when it opens, but later)."""
    meta_path = dataset_dir / META_FILE
    if not meta_path.exists():
        return
    stored = validate_meta(parse_json_text(read_text(meta_path), meta_path), meta_path)
    now = validate_meta(dataset_meta(backend, source), "<this robot>")
    for key in COMPARED_META_KEYS:
        if stored.get(key) != now.get(key):
            raise DataError(meta_path, f"this run measured another set-up ({key} {stored.get(key)!r}, now "
                                       f"{now.get(key)!r}): resume it with the same robot (nothing was changed)",
                            field=key)


def check_unfinished(out_dir: Path) -> None:
    """Refuse to run again in a finished run's DIR (NaocalError; nothing changed): there is nothing to resume, and
    its verification would move the robot again. Says where the result is and what can be done instead."""
    out_dir = Path(out_dir)
    if not run_finished(out_dir):
        return
    offsets = out_dir / "offsets.json"
    check = shlex.join(["naocal", "verify", str(out_dir / "verification" / "raw"), "--offsets", str(offsets)])
    raise NaocalError(f"{out_dir} holds a finished calibration (offsets {offsets}, summary {out_dir / 'summary.txt'}): "
                      "there is nothing to resume, and running it again would move the robot to verify once more. "
                      f"To calibrate again, choose another --out; to check these offsets again without moving the "
                      f"robot (its held-out captures under them): {check} (nothing was changed)")


def calibrate(backend, out_dir, settings: AgentSettings = AgentSettings(), *, detector=None,
              backend_label: str | None = None, truth: dict | None = None) -> tuple[RunResult, Context]:
    """Run modelling -> measurement -> identification -> compensation -> verification on `backend`.

    Writes summary.txt even when the run fails or is interrupted (result.final INTERRUPTED). `truth` (mock only)
    adds a comparison to the summary; the agent itself never sees it. On resume, a robot other than the stored
    dataset's is refused (DataError) before anything is written; so is any run in a finished run's DIR.
    """
    out_dir = Path(out_dir)
    check_unfinished(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ctx = Context(backend=backend, settings=settings, out_dir=out_dir, dataset_dir=out_dir / "dataset",
                  progress_path=out_dir / "progress.json", plan_path=out_dir / "plan.json",
                  detector=detector or opencv_detector)
    if settings.resume:
        check_same_setup(backend, ctx.dataset_dir, settings.source)
    with log_to_file(out_dir / "calibrate.log"):
        log.info("naocal calibrate: backend %s, seed %d, output %s%s", backend_label or backend.name, settings.seed,
                 out_dir, " (resume)" if settings.resume else "")
        try:
            result = Machine(calibrate_states()).run(ctx, clock=backend.now)
        finally:
            ctx.close()
        ctx.summary = summary_text(ctx, result, backend_label=backend_label or backend.name, truth=truth)
        try:
            atomic_write_text(out_dir / "summary.txt", ctx.summary)
        except DiskFullError as err:
            ctx.summary_error = str(err)
            log.error("%s", err)
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
