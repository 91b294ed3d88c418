"""The one way the tests run naocal's command line.

`naocal(...)` runs it in this process (tools.cli.main): no interpreter to start, nothing imported again (0.7 CPU
seconds saved per call). `naocal_process(...)` runs it as a child process, for the tests where the process
boundary is what is tested (signals, a kill and --resume, the real exit status, a read that would block for ever
and must be cut by a timeout).
"""

from __future__ import annotations

import contextlib
import io
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_HANDLED = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)  # cli.main installs its own for these


def naocal(*argv) -> subprocess.CompletedProcess:
    """`naocal ARGV...` in this process: its exit code, stdout and stderr, as a child process would give them."""
    from naocal.tools import cli

    argv = [str(a) for a in argv]
    out, err = io.StringIO(), io.StringIO()
    handlers = {signum: signal.getsignal(signum) for signum in _HANDLED}
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(argv)
            except SystemExit as exit_:  # argparse's usage errors and --help
                code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    return subprocess.CompletedProcess(["naocal", *argv], int(code or 0), out.getvalue(), err.getvalue())


def naocal_process(*argv, timeout=600, **kw) -> subprocess.CompletedProcess:
    """`naocal ARGV...` in a child process, run to its end (a test fails, not hangs, after `timeout` s)."""
    kw.setdefault("cwd", ROOT)
    kw.setdefault("capture_output", True)
    return subprocess.run([sys.executable, "-m", "naocal", *map(str, argv)], text=True, timeout=timeout, **kw)
