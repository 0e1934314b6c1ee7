"""The calibration's task on the ensemble runner: (case, parameter values) → residuals.

One task per case and parameter point, so that a Jacobian's columns (and the cases of a
spec) run in parallel on the runner's executor (:mod:`flexarm_ros.ensemble.runner`: this
process, a local Dask cluster, or a scheduler). The task is a pure function of its inputs:
the same point gives the same residuals on any executor.

A sample that diverges, is refused by the scene's checks or fails otherwise returns its
status and message instead of residuals; the fit replaces them by a penalty
(:data:`PENALTY` per residual, in units of σ) and says so, never stops on it.
"""

from __future__ import annotations

import numpy as np

from flexarm_ros.errors import InputError, SimulationDiverged, StepTooLarge

PENALTY = 1.0e3      # residual (in σ) given to every entry of a failed sample or NaN feature


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


class CaseTask:
    """Picklable: ``task((case_index, assignment))`` → ``{"status", "message",
    "residuals", "features", "rms"}``."""

    def __init__(self, cases):
        from flexarm_ros.calibration.observables import parse_feature
        self.cases = list(cases)
        self._parsed = [[parse_feature(f.metric) for f in c.features] for c in self.cases]

    def warm_up(self) -> None:
        from flexarm_ros.twin.batch import probe_duration, run_scene
        c = self.cases[0]
        try:
            with np.errstate(all="ignore"):
                run_scene(c.scene, probe_duration(c.scene, c.open_loop), open_loop=c.open_loop)
        except (InputError, SimulationDiverged):
            pass

    def simulate(self, item):
        """The SimResult of one item (for the report's overlays)."""
        from flexarm_ros.ensemble.keys import set_keys
        from flexarm_ros.twin.batch import run_scene
        k, assignment = item
        case = self.cases[k]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return run_scene(set_keys(case.scene, assignment), case.duration,
                             open_loop=case.open_loop)

    def __call__(self, item) -> dict:
        from flexarm_ros.calibration.observables import case_residuals, only_modes
        k, _ = item
        case = self.cases[k]
        fail = {"residuals": None, "features": [np.nan] * len(case.features),
                "rms": [np.nan] * len(case.series)}
        try:
            from flexarm_ros.ensemble.keys import set_keys
            scene = set_keys(case.scene, item[1])
            res = (None if not case.series and only_modes(self._parsed[k])
                   else self.simulate(item))
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                vec, values, rms = case_residuals(res, case, self._parsed[k], scene)
        except StepTooLarge as exc:
            return {"status": "refused", "message": _one_line(exc), **fail}
        except SimulationDiverged as exc:
            return {"status": "diverged", "message": _one_line(exc), **fail}
        except InputError as exc:
            return {"status": "refused", "message": _one_line(exc), **fail}
        except (ArithmeticError, ValueError, KeyError, np.linalg.LinAlgError) as exc:
            return {"status": "error", "message": f"{type(exc).__name__}: {_one_line(exc)}",
                    **fail}
        bad = ~np.isfinite(vec)
        message = ""
        if bad.any():
            message = (f"{int(bad.sum())} residual(s) undefined (a feature without a value, "
                       f"e.g. no impact, or the run shorter than the record's window)")
        return {"status": "ok", "message": message, "residuals": vec, "features": values,
                "rms": rms}


def penalized(result: dict, size: int) -> tuple[np.ndarray, bool]:
    """The residual vector of a task result, failed entries replaced by ±PENALTY;
    (vector, whether a penalty was applied)."""
    vec = result.get("residuals")
    if vec is None:
        return np.full(size, PENALTY), True
    vec = np.asarray(vec, float).copy()
    bad = ~np.isfinite(vec)
    if bad.any():
        vec[bad] = PENALTY
        return vec, True
    return vec, False
