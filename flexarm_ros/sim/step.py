"""The time step: one classical RK4 step in numpy (:func:`rk4_step`) and the choice of the
step size of a run (:func:`choose_step`), shared by batch integration, the contact
stepper and the plant.

The explicit step limit: RK4 is stable for h·|λ| below ≈ 2.78 on the negative real axis and
2√2 ≈ 2.83 on the imaginary axis, λ the eigenvalues of the linearized system. A fixed step
above that limit is refused up front (:class:`~flexarm_ros.errors.StepTooLarge`); the
automatic step is 1.5/|λ|max, which also keeps the phase error of the highest retained mode
small.
"""

from __future__ import annotations

import numpy as np

from flexarm_ros.errors import StepTooLarge
from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.model.contact import constrained_rate
from flexarm_ros.model.linear import RK4_AUTO, RK4_STABILITY, grid_step, highest_rate

#: the automatic step with a wall is this fraction of RK4_AUTO/|λ|max: impacts excite the
#: highest retained mode, which the full automatic step damps by ~6 % per step (|R(1.5i)| =
#: 0.94); at half of it (0.1 %) two_link_case1's accelerometers stay within 0.4 % of a
#: converged run (docs/design_notes.md, "Contact stepping past the output period")
CONTACT_STEP_FRACTION = 0.5

__all__ = ["CONTACT_STEP_FRACTION", "RK4_AUTO", "RK4_STABILITY", "choose_step", "grid_step",
           "rk4_step"]


def rk4_step(f, t, x, h, quadrature: bool = False, k1=None):
    """One RK4 step of ẋ = f(t, x) from (t, x) over h (actuator-state bounds are the
    caller's):

        k₁ = f(t + εh, x),            k₂ = f(t + h/2, x + h/2·k₁),
        k₃ = f(t + h/2, x + h/2·k₂),  k₄ = f(t + (1 − ε)h, x + h·k₃),
        x₁ = x + h/6·(k₁ + 2k₂ + 2k₃ + k₄),

    ε = ``STAGE_EPS``: the first and last stages lie just inside the step, so an input that
    jumps on a step boundary is seen with its value on that step (as the compiled loops).

    With ``quadrature``, ``f`` returns (ẋ, g) and the step returns (x₁, ∫g dt), the integral
    by the same stages and weights, h/6·(g₁ + 2g₂ + 2g₃ + g₄) (e.g. the normal impulse from
    the stage contact forces). ``k1``: the first stage, already known (first same as last:
    the previous step's ẋ at its end, no input jump between; not with ``quadrature``)."""
    def stage(ts, xs):
        return f(ts, xs) if quadrature else (f(ts, xs), 0.0)

    k1, g1 = stage(t + STAGE_EPS * h, x) if k1 is None or quadrature else (k1, 0.0)
    k2, g2 = stage(t + 0.5 * h, x + 0.5 * h * k1)
    k3, g3 = stage(t + 0.5 * h, x + 0.5 * h * k2)
    k4, g4 = stage(t + (1.0 - STAGE_EPS) * h, x + h * k3)
    x1 = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return (x1, (h / 6.0) * (g1 + 2 * g2 + 2 * g3 + g4)) if quadrature else x1


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
    stepper shortens its own step near the wall. Trapezoid: no stability limit; automatic =
    the output period (choose --dt for accuracy).
    """
    if integrator == "trapezoid":
        h = min(dt, output_dt) if dt > 0 else output_dt
        return output_dt / np.ceil(output_dt / h - 1e-9)
    if integrator != "rk4":
        return dt
    q, qd = chain.full_state(t0, x0)
    rate = highest_rate(chain, q, qd, x0[2 * len(chain.free):])
    limit = RK4_STABILITY / rate if rate > 0 else np.inf
    if dt > 0:
        if dt > limit:
            raise _refusal(dt, limit, t0, f"the highest model rate {rate / (2 * np.pi):.4g} Hz",
                           implicit=contact is None)
        h = dt
    else:
        h = RK4_AUTO / rate if rate > 0 else output_dt
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


def _refusal(dt, limit, t0, source, implicit=True) -> StepTooLarge:
    """The refusal of a fixed RK4 step above its stability limit: ``source`` names what
    sets the limit; ``implicit``: offer the implicit integrators (not with a wall, whose
    contact integrator is RK4)."""
    fix = f"use --dt <= {floor_sig(limit):.3g} s (auto: --dt 0), "
    if implicit:
        fix += "an implicit integrator (--integrator trapezoid, radau or bdf), "
    return StepTooLarge(
        "fixed step", t0, dt, fix + "or a coarser rung / fewer modes",
        detail=f"dt = {dt:.3g} s exceeds the RK4 stability limit {limit:.3g} s set by "
               f"{source}")
