"""Typed errors of the physics core: failure is data with a message that says what to change."""

from __future__ import annotations


class InputError(ValueError):
    """Bad input of any kind — a command-line option, a file or path, a calibration or
    ensemble spec, pacing settings, a bag that cannot be read — refused before anything is
    run or written. The message names the key (or option), the value and what was expected;
    the CLI prints it on one line and exits 2."""


class SceneError(InputError):
    """A scene is invalid — a scene file, a key set with ``--set`` or an override: the
    message names the key path, the value and the expectation (exit 2, as every InputError)."""


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
