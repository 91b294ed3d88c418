"""A plain-text progress bar on stderr: redrawn in place on a terminal, one line per tenth otherwise."""

from __future__ import annotations

import sys


class ProgressBar:
    def __init__(self, total: int, label: str = "measuring", stream=None, width: int = 30, enabled: bool = True):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.enabled = enabled
        self.done = 0
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_tenth = -1

    def update(self, done: int, note: str = "") -> None:
        self.done = min(int(done), self.total)
        if not self.enabled:
            return
        filled = int(self.width * self.done / self.total)
        line = (f"{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total}"
                + (f"  {note}" if note else ""))
        if self._tty:
            self.stream.write("\r" + line + "\033[K")
            self.stream.flush()
        else:
            tenth = 10 * self.done // self.total
            if tenth != self._last_tenth:
                self._last_tenth = tenth
                self.stream.write(line + "\n")
                self.stream.flush()

    def finish(self, note: str = "") -> None:
        if self.enabled:
            self.update(self.done, note)
            if self._tty:
                self.stream.write("\n")
                self.stream.flush()
