"""Typed errors of the physics core: failure is data with a message that says what to change."""

from __future__ import annotations


class SceneError(ValueError):
    """A scene file or option is invalid; the message names key path, value and expectation."""


class SimulationDiverged(RuntimeError):
    """The integration produced a non-finite or physically invalid state.

    Raised before anything is written or published. Attributes name what diverged, when,
    the last finite value seen and the suggested change (step, integrator, rung).
    """

    def __init__(self, quantity: str, time: float, last_value: float, suggestion: str,
                 detail: str = ""):
        self.quantity = quantity
        self.time = time
        self.last_value = last_value
        self.suggestion = suggestion
        self.detail = detail
        msg = (f"simulation diverged: {quantity} at t = {time:.6g} s "
               f"(last finite value {last_value:.6g})")
        if detail:
            msg += f"; {detail}"
        msg += f". To fix: {suggestion}"
        super().__init__(msg)


class StepTooLarge(SimulationDiverged):
    """A fixed step is above the explicit method's stability limit for this model; raised
    before integrating (nothing diverged yet)."""

    def __init__(self, quantity: str, time: float, last_value: float, suggestion: str,
                 detail: str = ""):
        RuntimeError.__init__(self, f"step refused: {detail}. To fix: {suggestion}")
        self.quantity, self.time, self.last_value = quantity, time, last_value
        self.suggestion = suggestion


class WorkTooLarge(SceneError):
    """A run would take more integrator steps than ``fidelity.max_steps`` (a collapsed step
    or a huge duration); raised before integrating, or as soon as an adaptive run's pace
    projects beyond the budget. The message names the eigenvalue and the coordinate (and
    its scene keys) that set the step, and what to change. Bad input: exit 2."""
