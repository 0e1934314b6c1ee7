"""The optional numba compiler, in one place: ``jit`` / ``jit_inline`` / ``jit_raw`` compile a scalar
Python function when numba is installed (and ``FLEXARM_NO_NUMBA`` is not set), else return
it unchanged, so every compiled function also runs as plain Python."""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from pathlib import Path

#: files outside this package whose functions numba compiles (the programs are compiled
#: in chain.py); every module of this package counts as well (:func:`compiled_sources`)
_OTHER_SOURCES = ("bearings.py", "drives.py", "programs.py")


def compiled_sources() -> list[Path]:
    """The files whose functions numba compiles: this package's modules and
    :data:`_OTHER_SOURCES` of ``flexarm_ros/model`` (``test_kernel`` checks no module
    elsewhere uses the compiler)."""
    here = Path(__file__).resolve().parent
    return sorted(here.glob("*.py")) + [here.parent / n for n in _OTHER_SOURCES]


def source_key() -> str:
    """A digest of every compiled source file and the option that changes the code
    (``FLEXARM_KERNEL_NRT``).

    Why: numba's cache keys a function on its own file's time stamp only. An entry point
    in ``loops.py`` inlines the kernel of ``chain.py``; edit ``chain.py`` alone and
    ``loops.py``'s cached entry points go on running the old kernel (met in session 14: a
    probe of the kernel measured the unchanged code). One cache directory per digest
    (:func:`cache_dir`) makes a changed source a fresh compile."""
    h = hashlib.sha256(os.environ.get("FLEXARM_KERNEL_NRT", "").encode())
    for path in compiled_sources():
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def cache_dir(base: str | None = None) -> Path:
    """``<base>/flexarm-<source_key()>``: ``base`` is ``NUMBA_CACHE_DIR`` when set, else
    this package's ``__pycache__`` where it is writable, else ``~/.cache/flexarm_ros``.
    Other ``flexarm-*`` directories under the same base (older sources) are removed when
    a new one is made."""
    if base is None:
        base = os.environ.get("NUMBA_CACHE_DIR")
    if not base:
        here = Path(__file__).resolve().parent / "__pycache__"
        try:
            here.mkdir(exist_ok=True)
            writable = os.access(here, os.W_OK)
        except OSError:
            writable = False
        base = here if writable else Path(os.environ.get(
            "XDG_CACHE_HOME", Path.home() / ".cache")) / "flexarm_ros"
    base = Path(base)
    path = base / f"flexarm-{source_key()}"
    if not path.is_dir():
        try:
            for old in base.glob("flexarm-*"):
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass
    return path


class _CompileLock:
    """One compile of a function at a time across the processes sharing a cache directory.

    Why: on a cold cache every process that needs a kernel compiles it, the same ~10–40 s
    of CPU each — the test suite's two xdist workers, the CLI processes its tests start, a
    Dask cluster's workers, the nodes of a graph. numba looks in its cache only before it
    compiles, so two processes that start on one function both compile it. Here a
    function's compile holds an exclusive ``flock`` on ``<cache>/<name>.lock``; a process
    that finds it held waits, then loads what the other saved (numba reads the cache
    index again at each compile). Locks are taken caller before callee, along the call
    graph, which has no cycle: no two processes wait on each other. Inside one process the
    count makes it reentrant; numba's global compiler lock, taken first, keeps threads in
    turn. A process waits at most :attr:`patience`, then compiles as it would without
    the lock."""

    held: dict = {}                     # lock path -> [fd, depth] in this process
    #: s to wait for another process's compile before compiling anyway (a holder that
    #: was stopped, e.g. SIGSTOP, must not stall every other process for good); the
    #: longest single compile measured is ~50 s of CPU
    patience = 600.0

    def __init__(self, dispatcher):
        self.path = Path(numba.config.CACHE_DIR) / f"{dispatcher.py_func.__module__}." \
                                                  f"{dispatcher.py_func.__qualname__}.lock"

    def __enter__(self):
        entry = self.held.get(self.path)
        if entry is not None:
            entry[1] += 1
            return self
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError:                 # a read-only cache: compile unlocked, as before
            self.held[self.path] = [None, 1]
            return self
        deadline = time.monotonic() + self.patience
        pause = 0.0005          # doubling to 50 ms: a cache load holds a lock ~1–20 ms
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError:
                if time.monotonic() > deadline:     # a holder stopped or hung: go on
                    os.close(fd)                    # and compile, as without the lock
                    self.held[self.path] = [None, 1]
                    return self
                time.sleep(pause)
                pause = min(2.0 * pause, 0.05)
        self.held[self.path] = [fd, 1]
        return self

    def __exit__(self, *exc):
        entry = self.held[self.path]
        entry[1] -= 1
        if entry[1] == 0:
            del self.held[self.path]
            if entry[0] is not None:
                fcntl.flock(entry[0], fcntl.LOCK_UN)
                os.close(entry[0])


def _one_compile_at_a_time(dispatcher):
    """``dispatcher`` whose compiles hold its :class:`_CompileLock` (numba calls
    ``compile`` on the instance, from Python and when typing a caller)."""
    if fcntl is None:
        return dispatcher
    from numba.core import sigutils
    from numba.core.compiler_lock import global_compiler_lock
    compile_unlocked = dispatcher.compile
    lock = _CompileLock(dispatcher)

    def compile(sig):
        args, _ = sigutils.normalize_signature(sig)
        if tuple(args) in dispatcher.overloads:     # in this process already (typing a
            return compile_unlocked(sig)            # caller): no wait on another's compile
        with global_compiler_lock, lock:
            return compile_unlocked(sig)
    dispatcher.compile = compile
    return dispatcher


def _locked(**options):
    """``numba.njit(**options)`` whose functions compile one process at a time."""
    def decorate(f):
        return _one_compile_at_a_time(numba.njit(**options)(f))
    return decorate


try:  # pragma: no cover - exercised by whichever environment runs the tests
    import fcntl
except ImportError:                     # not POSIX: each process compiles for itself
    fcntl = None

try:  # pragma: no cover - exercised by whichever environment runs the tests
    if os.environ.get("FLEXARM_NO_NUMBA"):
        raise ImportError("disabled by FLEXARM_NO_NUMBA")
    import numba
    numba.config.CACHE_DIR = str(cache_dir())
    HAVE_NUMBA = True
    # fast-math without 'nnan'/'ninf': the divergence checks must still see NaN and inf;
    # and without 'reassoc': with it a process that compiled the kernel and one that loaded
    # it from numba's cache rounded differently (ensembles' tables differed between Dask
    # workers in the last bits); without it the kernel costs the same within the host's
    # noise (bench/bench_kernel.py; docs/decisions/0016-the-compiled-kernel.md, "Why not
    # 'reassoc'")
    _FLAGS = {"contract", "arcp", "nsz", "afn"}
    jit = _locked(cache=True, error_model="numpy", fastmath=_FLAGS)
    jit_inline = _locked(cache=True, error_model="numpy", inline="always", fastmath=_FLAGS)
    # the hot loops without numba's reference counting (NRT): every array the kernel
    # reads through the model and workspace tuples is otherwise incref'd and decref'd
    # (an atomic instruction each) at every inlined call, per point, per stage — perf
    # showed NRT_incref/NRT_decref taking about two thirds of a rigid rung's chain_terms.
    # Such a function allocates nothing and returns no array it made: its callers (plain
    # ``jit`` wrappers) hand it its scratch arrays (docs/decisions/0016-the-compiled-kernel.md,
    # "No reference counting in the hot loops")
    # ``FLEXARM_KERNEL_NRT=1`` compiles them with it, as before (bench/bench_kernel.py's
    # comparison; a fallback should a numba release refuse the option)
    jit_raw = (jit if os.environ.get("FLEXARM_KERNEL_NRT") else
               _locked(cache=True, error_model="numpy", fastmath=_FLAGS, _nrt=False))
    # IEEE arithmetic as numpy and Python do it (no contraction into fused multiply-adds):
    # the closed loop's controller and encoder read-out, which must give the bits the
    # Python cores give — an encoder count is a floor, and one ulp can flip it
    jit_exact = _locked(cache=True, error_model="numpy")
except ImportError:
    HAVE_NUMBA = False

    def jit(f):
        return f

    jit_inline = jit
    jit_raw = jit
    jit_exact = jit


def cache_is_cold() -> bool:
    """numba is in use and its cache for these sources holds no compiled function yet (a
    fresh install or an edited kernel): the first run compiles for tens of seconds."""
    if not HAVE_NUMBA:
        return False
    import numba
    return not any(Path(numba.config.CACHE_DIR).glob("*.nbi"))
