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


#: a frame in this file is numba compiling (not loading from its cache, which does not
#: pass through it)
NUMBA_COMPILER = ("numba", "core", "compiler.py")
#: numba's on-disk cache: loading a compiled function passes through compiler.py too
#: (``CompileResult._rebuild``), which is not compiling
NUMBA_CACHE_LOAD = (("numba", "core", "caching.py"), "load_overload")


class CompileNotice:
    """``with CompileNotice():`` — when the thread that entered has been inside numba's
    compiler for ``after`` s, say once on ``stream`` that the kernels are being compiled
    (the first run after an install or an update compiles for tens of seconds, silently
    otherwise), and where the result is cached. A daemon thread looks at the entering
    thread's stack (``sys._current_frames``) every ``period`` s; nothing else is touched."""

    def __init__(self, after: float = 2.0, period: float = 0.5, stream=None,
                 enabled: bool = True):
        import threading
        self.after, self.period = after, period
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.said = False
        self._stop = threading.Event()
        self._thread = None
        self._target = None

    def _compiling(self) -> bool:
        """A frame of numba's compiler on the entering thread's stack, not under a cache
        load (a helper's trial on a loaded host saw the notice for a warm cache: loading
        took over ``after`` s through compiler.py's ``_rebuild``)."""
        import os
        frame = sys._current_frames().get(self._target)
        mark = os.sep + os.sep.join(NUMBA_COMPILER)
        load_file = os.sep + os.sep.join(NUMBA_CACHE_LOAD[0])
        compiling = False
        while frame is not None:
            code = frame.f_code
            if code.co_filename.endswith(load_file) and code.co_name == NUMBA_CACHE_LOAD[1]:
                return False
            compiling = compiling or code.co_filename.endswith(mark)
            frame = frame.f_back
        return compiling

    def _watch(self):
        if self._stop.wait(self.after):
            return
        while not self._stop.is_set():
            if self._compiling():
                where = ""
                try:
                    import numba
                    where = f"; cached in {numba.config.CACHE_DIR}" if \
                        numba.config.CACHE_DIR else ""
                except ImportError:             # pragma: no cover - only numba compiles
                    pass
                print("flexarm: compiling the numba kernels (once after an install or an "
                      f"update of flexarm_ros, a minute or two{where}) ...", file=self.stream,
                      flush=True)
                self.said = True
                return
            self._stop.wait(self.period)

    def __enter__(self):
        import threading
        if self.enabled:
            self._target = threading.get_ident()
            self._thread = threading.Thread(target=self._watch, name="compile-notice",
                                            daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        return False
