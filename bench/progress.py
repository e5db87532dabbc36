"""The console progress display: a run of several minutes should show what it is doing."""

from __future__ import annotations

import sys
import time


class Progress:
    """One updating line per phase on stderr (a plain line per phase when not a terminal)."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self._last = 0.0
        self._text = ""

    def update(self, text: str, force: bool = False) -> None:
        self._text = text
        now = time.monotonic()
        if not self.tty or (not force and now - self._last < 0.2):
            return
        self._last = now
        sys.stderr.write("\r\x1b[K" + text[:200])
        sys.stderr.flush()

    def done(self, text: str | None = None) -> None:
        text = text if text is not None else self._text
        sys.stderr.write(("\r\x1b[K" if self.tty else "") + text + "\n")
        sys.stderr.flush()
        self._text = ""

    def note(self, text: str) -> None:
        sys.stderr.write(("\r\x1b[K" if self.tty else "") + text + "\n")
        sys.stderr.flush()
