"""The optional numba compiler, in one place: ``jit`` / ``jit_inline`` compile a scalar
Python function when numba is installed (and ``FLEXARM_NO_NUMBA`` is not set), else return
it unchanged, so every compiled function also runs as plain Python."""

from __future__ import annotations

import os

try:  # pragma: no cover - exercised by whichever environment runs the tests
    if os.environ.get("FLEXARM_NO_NUMBA"):
        raise ImportError("disabled by FLEXARM_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
    # fast-math without 'nnan'/'ninf': the divergence checks must still see NaN and inf
    _FLAGS = {"reassoc", "contract", "arcp", "nsz", "afn"}
    jit = numba.njit(cache=True, error_model="numpy", fastmath=_FLAGS)
    jit_inline = numba.njit(cache=True, error_model="numpy", inline="always",
                            fastmath=_FLAGS)
except ImportError:
    HAVE_NUMBA = False

    def jit(f):
        return f

    jit_inline = jit
