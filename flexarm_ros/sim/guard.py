"""The divergence guard of every run: after each step the state must be finite and every
beam's tip deflection within the small-deflection model's validity, |w(L)|/L ≤
``fidelity.max_deflection_ratio``; otherwise :class:`~flexarm_ros.errors.SimulationDiverged`
names what diverged, when, the last finite value and what to change."""

from __future__ import annotations

import numpy as np

from flexarm_ros.errors import SimulationDiverged


class DivergenceGuard:
    """Checks the states of a run (:meth:`check`); ``last`` holds the last state that
    passed (a compiled loop that stops on a bad state sets it to the state before)."""

    def __init__(self, chain, max_ratio, integrator, h):
        self.chain = chain
        self.max_ratio = max_ratio
        self.integrator = integrator
        self.h = h
        self.last = None
        self.lengths = np.array([lm.beam.length for lm in chain.links])
        # the rod rung has no small-deflection bound (its kinematics are exact): its row
        # is zero, as in the compiled loops' check
        self.tip_rows = [(lm.beam.phi_tip * (lm.beam.rod is None), lm.eta)
                         for lm in chain.links]

    def _ratios(self, q):
        return np.array([phi @ q[sl] for phi, sl in self.tip_rows]) / self.lengths

    def _fix(self):
        if self.integrator in ("rk4", "rkn4"):
            return (f"reduce the step (--dt, now {self.h:.3g} s), use --integrator radau, "
                    f"or a coarser rung / fewer modes")
        return "tighten --rtol/--atol or use --integrator radau or bdf"

    def check(self, t, x):
        """Raise :class:`SimulationDiverged` if state x at time t is non-finite or deflects
        a beam beyond the limit; else remember it as the last good state."""
        nf = len(self.chain.free)
        if not np.all(np.isfinite(x)):
            bad = int(np.nonzero(~np.isfinite(x))[0][0])
            name = self.chain.state_labels()[bad]
            kind = "coordinate" if bad < nf else ("rate" if bad < 2 * nf else "actuator state")
            last = float(self.last[bad]) if self.last is not None else float("nan")
            raise SimulationDiverged(f"{kind} {name}", t, last, self._fix(),
                                     detail="state became non-finite")
        q, _ = self.chain.full_state(t, x)
        ratios = self._ratios(q)
        worst = int(np.argmax(np.abs(ratios)))
        if abs(ratios[worst]) > self.max_ratio:
            lm = self.chain.links[worst]
            raise SimulationDiverged(
                f"tip deflection of {lm.name}", t, float(ratios[worst] * self.lengths[worst]),
                "check the input magnitude and damping; keep foreshortening on "
                "(fidelity.foreshortening: true) for fast rotation; or raise "
                "fidelity.max_deflection_ratio if large deflection is intended",
                detail=f"|w(L)|/L = {abs(ratios[worst]):.3g} exceeds "
                       f"fidelity.max_deflection_ratio = {self.max_ratio} (the small-deflection "
                       f"beam model is no longer valid)")
        self.last = np.array(x, copy=True)
