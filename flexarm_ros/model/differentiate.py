"""Central-difference Jacobians: the one numerical derivative of the model code (tangent
stiffness, spectral radius of the right-hand side, the contact modes' rates, the
state-space model's configuration terms, the trapezoidal rule's iteration matrix).

Column j of ∂f/∂x at x₀ is ``(f(x₀ + d e_j) − f(x₀ − d e_j)) / 2d`` with the step
``d = min(rel_step · max(abs_floor, |x₀_j|), max_step)``: relative to the coordinate so a
large angle or pressure is perturbed in proportion, never below ``rel_step · abs_floor``,
and capped by ``max_step`` where a kink (a backlash dead zone's edge) may lie within reach.
The truncation error is O(d²), the round-off O(ε‖f‖/d).
"""

from __future__ import annotations

import numpy as np

#: default relative step of the central differences
REL_STEP = 1e-6


def jacobian(f, x0, rel_step: float = REL_STEP, abs_floor: float = 1.0,
             max_step: float = np.inf, columns=None) -> np.ndarray:
    """∂f/∂x at ``x0`` by central differences (module doc), shape ``f(x0).shape + (m,)``
    for the m indices of ``columns`` (default: every index of x0, in order). ``f`` gets a
    fresh copy of x0 perturbed in one entry and returns an array (or a float)."""
    x0 = np.asarray(x0, float)
    cols = range(len(x0)) if columns is None else columns
    J = None
    for j, idx in enumerate(cols):
        d = min(rel_step * max(abs_floor, abs(x0[idx])), max_step)
        xp, xm = x0.copy(), x0.copy()
        xp[idx] += d
        xm[idx] -= d
        col = (np.asarray(f(xp)) - np.asarray(f(xm))) / (2 * d)
        if J is None:
            J = np.empty(col.shape + (len(cols),))
        J[..., j] = col
    if J is None:   # no columns: the shape of f alone
        J = np.zeros(np.shape(f(x0.copy())) + (0,))
    return J
