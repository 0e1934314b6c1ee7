"""The optional numba compiler, in one place: ``jit`` / ``jit_inline`` / ``jit_raw`` compile a scalar
Python function when numba is installed (and ``FLEXARM_NO_NUMBA`` is not set), else return
it unchanged, so every compiled function also runs as plain Python."""

from __future__ import annotations

import os

try:  # pragma: no cover - exercised by whichever environment runs the tests
    if os.environ.get("FLEXARM_NO_NUMBA"):
        raise ImportError("disabled by FLEXARM_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
    # fast-math without 'nnan'/'ninf': the divergence checks must still see NaN and inf;
    # and without 'reassoc': with it a process that compiled the kernel and one that loaded
    # it from numba's cache rounded differently (ensembles' tables differed between Dask
    # workers in the last bits); without it the kernel costs the same within the host's
    # noise (bench/bench_kernel.py; docs/design_notes.md, "Why not 'reassoc'")
    _FLAGS = {"contract", "arcp", "nsz", "afn"}
    jit = numba.njit(cache=True, error_model="numpy", fastmath=_FLAGS)
    jit_inline = numba.njit(cache=True, error_model="numpy", inline="always",
                            fastmath=_FLAGS)
    # the hot loops without numba's reference counting (NRT): every array the kernel
    # reads through the model and workspace tuples is otherwise incref'd and decref'd
    # (an atomic instruction each) at every inlined call, per point, per stage — perf
    # showed NRT_incref/NRT_decref taking about two thirds of a rigid rung's chain_terms.
    # Such a function allocates nothing and returns no array it made: its callers (plain
    # ``jit`` wrappers) hand it its scratch arrays (docs/design_notes.md, "The kernel
    # without reference counting")
    # ``FLEXARM_KERNEL_NRT=1`` compiles them with it, as before (bench/bench_kernel.py's
    # comparison; a fallback should a numba release refuse the option)
    jit_raw = (jit if os.environ.get("FLEXARM_KERNEL_NRT") else
               numba.njit(cache=True, error_model="numpy", fastmath=_FLAGS, _nrt=False))
except ImportError:
    HAVE_NUMBA = False

    def jit(f):
        return f

    jit_inline = jit
    jit_raw = jit
