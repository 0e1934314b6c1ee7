"""The time step: the choice of the step size of a run (:func:`choose_step`), shared by
batch integration, the contact stepper and the plant; the steps themselves (RK4 and RKN4
in numpy, :func:`rk4_step`) and their stability limits live in
:mod:`flexarm_ros.model.explicit` and are re-exported here.

The explicit step limit: RK4 is stable for h·|λ| below ≈ 2.78 on the negative real axis and
2√2 ≈ 2.83 on the imaginary axis, λ the eigenvalues of the linearized system. A fixed step
above that limit is refused up front (:class:`~flexarm_ros.errors.StepTooLarge`); the
automatic step is 1.5/|λ|max, which also keeps the phase error of the highest retained mode
small.
"""

from __future__ import annotations

import numpy as np

from flexarm_ros.errors import StepTooLarge
from flexarm_ros.model.contact import constrained_rate
from flexarm_ros.model.explicit import (admits, nystrom_positions, rk4_step, rkn4_limit,
                                        rkn4_map, stability)
from flexarm_ros.model.linear import RK4_AUTO, RK4_STABILITY, grid_step

#: the automatic step with a wall is this fraction of RK4_AUTO/|λ|max: impacts excite the
#: highest retained mode, which the full automatic step damps by ~6 % per step (|R(1.5i)| =
#: 0.94); at half of it (0.1 %) two_link_case1's accelerometers stay within 0.4 % of a
#: converged run (docs/decisions/0012-contact-stepping-past-the-output-period.md)
CONTACT_STEP_FRACTION = 0.5

__all__ = ["CONTACT_STEP_FRACTION", "RK4_AUTO", "RK4_STABILITY", "choose_step", "grid_step",
           "nystrom_positions", "rk4_step", "rkn4_limit", "rkn4_map", "stability"]


def choose_step(chain, x0, integrator, dt, output_dt, t0=0.0, contact=None, dense=False):
    """The fixed step (RK4, trapezoid) or the max step (adaptive, 0 = unbounded) of a run
    from state x0, given the requested step ``dt`` (0 = automatic) and the output period.

    RK4: a requested step above the stability limit RK4_STABILITY/|λ|max is refused
    (:class:`StepTooLarge` naming the limit and the alternatives); the automatic step is
    RK4_AUTO/|λ|max; either is shortened to divide the output period, except with
    ``dense`` (batch integration, with or without a wall), where the step is kept as it
    is, above or below the output period: the outputs then come from the dense output
    inside steps
    (:func:`~flexarm_ros.sim.integrate.integrate`, :class:`ContactStepper`'s samples), so
    the step is set by stability and accuracy, never by the output grid. With a wall
    ``contact`` of the impulse rung, |λ|max is also taken with the tool held on the wall
    (:func:`~flexarm_ros.model.contact.constrained_rate`: holding it raises the highest
    frequency, and the step must be stable in every contact mode); the compliant rung's
    stepper shortens its own step near the wall. Trapezoid and lawson4: no stability limit
    (lawson4 steps the linearization exactly); automatic = the output period, a given step
    above it refused (InputError: no output lies between), below it shortened to divide
    it (choose --dt for accuracy).
    """
    if integrator in ("trapezoid", "lawson4"):
        if dt > output_dt * (1 + 1e-9):
            from flexarm_ros.errors import InputError
            raise InputError(f"fidelity.dt: got {dt:g} s with the {integrator} integrator, "
                             f"expected at most the output period {output_dt:g} s (it "
                             f"steps on the output grid; --dt 0 steps at the period, or "
                             f"choose rk4 or rkn4 to step past it)")
        h = min(dt, output_dt) if dt > 0 else output_dt
        return output_dt / np.ceil(output_dt / h - 1e-9)
    if integrator not in ("rk4", "rkn4"):
        return dt
    q, qd = chain.full_state(t0, x0)
    z = x0[2 * len(chain.free):]
    if dt > 0:
        # a given step needs only its own stability (RKN4: the scan up to it); the
        # limit itself is computed for the refusal's text
        if not admits(chain, q, qd, z, integrator, dt):
            rate, limit, _ = stability(chain, q, qd, z, integrator)
            raise _refusal(dt, limit, t0, f"the highest model rate {rate / (2 * np.pi):.4g} Hz",
                           implicit=contact is None, integrator=integrator)
        h = dt
    else:
        rate, limit, auto = stability(chain, q, qd, z, integrator)
        h = auto if rate > 0 else output_dt
    h = grid_step(h, output_dt, dense)
    if contact is None or contact.method == "compliant":
        return h
    rate = constrained_rate(contact, x0)
    limit = RK4_STABILITY / rate
    if dt > 0 and dt > limit:
        raise _refusal(dt, limit, t0, f"the highest rate {rate / (2 * np.pi):.4g} Hz of the "
                       f"arm with its tool held on the wall", implicit=False)
    if dt == 0:
        h = grid_step(CONTACT_STEP_FRACTION * min(h, RK4_AUTO / rate), output_dt, dense)
    return h


def floor_sig(x: float, digits: int = 3) -> float:
    """x rounded down to ``digits`` significant digits (a suggested step that is itself
    below the limit it is printed against)."""
    if not (x > 0 and np.isfinite(x)):
        return x
    e = int(np.floor(np.log10(x))) - digits + 1
    return float(np.floor(x / 10.0 ** e) * 10.0 ** e)


def _refusal(dt, limit, t0, source, implicit=True, integrator="rk4") -> StepTooLarge:
    """The refusal of a fixed RK4 step above its stability limit: ``source`` names what
    sets the limit; ``implicit``: offer the implicit integrators (not with a wall, whose
    contact integrator is RK4)."""
    fix = f"use --dt <= {floor_sig(limit):.3g} s (auto: --dt 0), "
    if implicit:
        fix += "an implicit integrator (--integrator trapezoid, radau or bdf), "
    return StepTooLarge(
        "fixed step", t0, dt, fix + "or a coarser rung / fewer modes",
        detail=f"dt = {dt:.3g} s exceeds the {integrator.upper()} stability limit "
               f"{limit:.3g} s set by {source}")
