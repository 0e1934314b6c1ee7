"""The one-line progress display on stderr that every long command shows.

On a terminal the line is redrawn in place (``\\r``) and blanked at the end. When stderr
is not a terminal (a log file, a CI job, a pipe) a redrawn line would pile up as one
endless line of carriage returns; there each update is a line of its own, at most one
per :data:`LOG_PERIOD_S` (and the final one always), and nothing is blanked.
"""

from __future__ import annotations

import sys
import time

LOG_PERIOD_S = 5.0
"""Seconds between two progress lines when stderr is not a terminal."""


class ProgressLine:
    """``show(text)`` draws the progress text, ``clear()`` ends it; ``width``: the
    columns blanked on a terminal."""

    def __init__(self, width: int = 78, stream=None):
        self.width = width
        self.stream = stream if stream is not None else sys.stderr
        try:
            self.tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self.tty = False
        self.drawn = False
        self._last = -float("inf")

    def show(self, text: str, final: bool = False) -> None:
        """The progress now; ``final``: the last one (kept on its own line)."""
        if self.tty:
            print("\r" + text.ljust(self.width), end="\n" if final else "",
                  file=self.stream, flush=True)
            self.drawn = not final
            return
        now = time.monotonic()
        if final or now - self._last >= LOG_PERIOD_S:
            self._last = now
            print(text.strip(), file=self.stream, flush=True)

    def clear(self) -> None:
        """Blank a line drawn on a terminal (nothing otherwise)."""
        if self.tty and self.drawn:
            print("\r" + " " * self.width + "\r", end="", file=self.stream, flush=True)
            self.drawn = False
