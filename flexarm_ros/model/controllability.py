"""Controllability of a linear model ẋ = A x + B u by the PBH (Popov–Belevitch–Hautus) test.

The pair (A, B) is controllable iff rank [A − λI, B] = n at every eigenvalue λ of A. The
textbook test, the rank of the controllability matrix [B, AB, …, Aⁿ⁻¹B], is numerically
meaningless for a stiff flexible model: its columns are B times powers of A whose
eigenvalues span from about 1 to 10⁵ s⁻¹, its condition number reaches 10²⁰ and beyond
(far past 1/ε ≈ 4.5·10¹⁵), so its computed rank says nothing. The PBH test looks at one
eigenvalue at a time and stays well conditioned.

Procedure: A is balanced first (a diagonal similarity T, :func:`scipy.linalg.matrix_balance`:
controllability is unchanged, and rows in rad, m, A and Pa are evened out so that ‖A‖ is
about the largest |λ| instead of its square), B becomes T⁻¹B with each column scaled to unit
norm (an input's scale changes nothing either); the *margin* of an eigenvalue λ is
σ_min/σ_max of [A − λI, B], and λ is uncontrollable when its margin is below ``tol``.

An exactly uncontrollable mode has a margin of round-off, a few ε (the error of the computed
eigenvalue relative to ‖A‖); a controllable one has the mode's coupling to the inputs
relative to ‖A‖, which shrinks as a mesh adds stiff modes that the hub barely moves. The
default ``tol = 1e-14`` (about 45 ε) sits between the two; a margin within a decade of it
means the answer is at the limit of double precision, and a Gramian or balanced realization
is the better tool (it grades how controllable each direction is, where this test answers
yes or no with the modes that fail). Repeated eigenvalues are handled: a mode repeated more
often than there are independent inputs is uncontrollable, as the rank test says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

#: default relative tolerance of the PBH rank decision
TOL = 1e-14


@dataclass
class PBHResult:
    """``controllable``: every mode passes; ``uncontrollable``: the eigenvalues (complex)
    that fail; ``margins``: σ_min/σ_max of [A − λI, B] per eigenvalue of A (the order of
    ``eigenvalues``); ``tol``: the threshold used."""
    controllable: bool
    eigenvalues: np.ndarray
    margins: np.ndarray
    uncontrollable: list
    tol: float

    def as_dict(self) -> dict:
        return {"controllable": self.controllable, "tol": self.tol,
                "uncontrollable_eigenvalues": [[float(z.real), float(z.imag)]
                                               for z in self.uncontrollable],
                "smallest_margin": float(self.margins.min()) if self.margins.size else None,
                "test": "PBH: rank [A − λI, B] = n at every eigenvalue λ of the balanced A "
                        "(uncontrollable when σ_min/σ_max < tol)"}


def pbh_test(A, B, tol: float = TOL) -> PBHResult:
    """The PBH controllability test of (A, B) (see the module doc); ``A`` is n×n, ``B`` n×m
    (m may be 0: nothing is controllable then, unless n = 0)."""
    A = np.asarray(A, float)
    n = A.shape[0]
    B = np.asarray(B, float).reshape(n, -1)
    if A.shape != (n, n):
        raise ValueError(f"A: got shape {A.shape}, expected a square matrix")
    if not tol > 0.0:
        raise ValueError(f"tol: got {tol}, expected > 0")
    if n == 0:
        return PBHResult(True, np.zeros(0, complex), np.zeros(0), [], tol)
    Ab, (scale, perm) = scipy.linalg.matrix_balance(A, permute=False, separate=True)
    Bb = B / scale[:, None]
    norms = np.linalg.norm(Bb, axis=0)
    Bb = Bb[:, norms > 0] / norms[norms > 0]
    lam = np.linalg.eigvals(Ab)
    eye = np.eye(n)
    margins = np.empty(n)
    for k, z in enumerate(lam):
        sv = np.linalg.svd(np.hstack([Ab - z * eye, Bb]), compute_uv=False)
        margins[k] = sv[n - 1] / sv[0] if sv[0] > 0 else 0.0
    bad = [complex(z) for z, mg in zip(lam, margins) if mg < tol]
    return PBHResult(not bad, lam, margins, bad, tol)
