"""The optional numba compiler, in one place: ``jit`` / ``jit_inline`` / ``jit_raw`` compile a scalar
Python function when numba is installed (and ``FLEXARM_NO_NUMBA`` is not set), else return
it unchanged, so every compiled function also runs as plain Python."""

from __future__ import annotations

import hashlib
import os
import shutil
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
    jit = numba.njit(cache=True, error_model="numpy", fastmath=_FLAGS)
    jit_inline = numba.njit(cache=True, error_model="numpy", inline="always",
                            fastmath=_FLAGS)
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
               numba.njit(cache=True, error_model="numpy", fastmath=_FLAGS, _nrt=False))
    # IEEE arithmetic as numpy and Python do it (no contraction into fused multiply-adds):
    # the closed loop's controller and encoder read-out, which must give the bits the
    # Python cores give — an encoder count is a floor, and one ulp can flip it
    jit_exact = numba.njit(cache=True, error_model="numpy")
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
