"""The fit: bounded nonlinear least squares on the weighted residuals of every case.

Method: ``scipy.optimize.least_squares`` (trust-region reflective, ``method='trf'``,
bounds = the box [0, 1]ⁿ of the parameters' coordinates z) minimizing ½Σr². The Jacobian
is a forward difference per parameter, step ``diff_step`` in z (backward at the upper
bound, and on the other side when a perturbed sample fails); its n columns × cases are
one batch of tasks on the ensemble runner's executor
(:func:`flexarm_ros.ensemble.runner.run_tasks`), so they run in parallel on a Dask
cluster. Multi-start: the first start is the given (or scene) values, further starts are
a scrambled Sobol sample of the box (seeded); the best final cost wins and every start's
result is reported.

A failed sample (diverged, refused, error) or an undefined feature gets the penalty
residual :data:`~flexarm_ros.calibration.task.PENALTY` with a warning; the fit goes on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.calibration.statistics import analyse
from flexarm_ros.calibration.task import CaseTask, penalized


@dataclass
class Problem:
    params: list
    cases: list

    @property
    def absolute(self) -> bool:
        """Every residual in units of a stated noise σ (then s² = 1)."""
        return all(s.sigma_given for c in self.cases for s in c.series)

    @property
    def size(self) -> int:
        return sum(c.size for c in self.cases)

    def blocks(self) -> list[tuple]:
        """(start, stop, σ given) of every observable's residuals, in vector order."""
        out, a = [], 0
        for c in self.cases:
            for s in c.series:
                out.append((a, a + s.size, s.sigma_given))
                a += s.size
            for f in c.features:
                out.append((a, a + 1, True))
                a += 1
        return out

    def assignment(self, z) -> dict:
        out = {}
        for prm, zz in zip(self.params, z):
            out.update(prm.assignment(float(prm.from_z(min(max(zz, 0.0), 1.0)))))
        return out

    def values(self, z) -> list[float]:
        return [float(prm.from_z(zz)) for prm, zz in zip(self.params, z)]


@dataclass
class Evaluations:
    """Every point evaluated: counts, warnings, a cache by point."""
    task: CaseTask
    problem: Problem
    executor: object = None
    progress: object = None
    simulations: int = 0
    points: int = 0
    warnings: list = field(default_factory=list)
    history: list = field(default_factory=list)     # (simulations, cost) of fun calls
    cache: dict = field(default_factory=dict)

    def many(self, zs) -> list[dict]:
        """Per point: {"r": residual vector, "penalized": bool, "cases": [task result]}."""
        from flexarm_ros.ensemble.runner import run_tasks
        todo = []
        for z in zs:
            key = np.asarray(z, float).tobytes()
            if key not in self.cache and key not in [k for k, _ in todo]:
                todo.append((key, np.asarray(z, float)))
        items = [(k, self.problem.assignment(z)) for _, z in todo
                 for k in range(len(self.problem.cases))]
        if items:
            results = run_tasks(self.task, items, self.executor)
            self.simulations += len(items)
            self.points += len(todo)
            nc = len(self.problem.cases)
            for i, (key, z) in enumerate(todo):
                per = results[i * nc:(i + 1) * nc]
                parts, pen = [], False
                for case, res in zip(self.problem.cases, per):
                    vec, bad = penalized(res, case.size)
                    parts.append(vec)
                    pen |= bad
                    if res["status"] != "ok" or res.get("message"):
                        vals = ", ".join(f"{k}={v:.6g}" for k, v in
                                         zip([p.name for p in self.problem.params],
                                             self.problem.values(z)))
                        self.warnings.append(f"{case.name} at {vals}: {res['status']}"
                                             f"{': ' + res['message'] if res['message'] else ''}"
                                             f" (penalty residual {PENALTY_TEXT})")
                self.cache[key] = {"r": np.concatenate(parts) if parts else np.zeros(0),
                                   "penalized": pen, "cases": per}
        return [self.cache[np.asarray(z, float).tobytes()] for z in zs]

    def one(self, z) -> dict:
        return self.many([z])[0]


PENALTY_TEXT = "1e3 σ per residual"


#: restarts of a start whose stop a Gauss-Newton step shows short of the minimum
MAX_RESTARTS = 3
#: ... when that step lowers the cost by more than this share (and more than 1e-12)
RESTART_GAIN = 1e-4


def _gauss_newton_gain(ev: Evaluations, z, h: float):
    """The point a Gauss-Newton step from ``z`` reaches (within the box) when it lowers the
    actual cost by more than RESTART_GAIN of it; None when it does not."""
    z = np.asarray(z, float)
    r0 = ev.one(z)["r"]
    J = _jacobian(ev, z, h)
    step, *_ = np.linalg.lstsq(J, -r0, rcond=None)
    z1 = np.clip(z + step, 0.0, 1.0)
    c0 = 0.5 * float(r0 @ r0)
    r1 = ev.one(z1)["r"]
    c1 = 0.5 * float(r1 @ r1)
    if c0 - c1 > max(RESTART_GAIN * c0, 1e-12):
        return z1
    return None


def _jacobian(ev: Evaluations, z, h: float):
    z = np.asarray(z, float)
    f0 = ev.one(z)["r"]
    n = len(z)
    steps = np.array([h if z[j] + h <= 1.0 else -h for j in range(n)])
    pts = []
    for j in range(n):
        zj = z.copy()
        zj[j] += steps[j]
        pts.append(zj)
    got = ev.many(pts)
    J = np.empty((len(f0), n))
    retry = [j for j in range(n) if got[j]["penalized"] and not ev.one(z)["penalized"]]
    if retry:
        back = []
        for j in retry:
            zj = z.copy()
            zj[j] -= steps[j]
            back.append(zj)
        got2 = ev.many(back)
        for j, g in zip(retry, got2):
            if not g["penalized"]:
                got[j] = g
                steps[j] = -steps[j]
    for j in range(n):
        if got[j]["penalized"] and not ev.one(z)["penalized"]:
            J[:, j] = 0.0           # both sides fail: the parameter is held this iteration
        else:
            J[:, j] = (got[j]["r"] - f0) / steps[j]
    return J


def starts_in_box(problem: Problem, starts: int, seed: int) -> list[np.ndarray]:
    z0 = np.array([float(p.to_z(p.start)) for p in problem.params])
    out = [np.clip(z0, 0.0, 1.0)]
    if starts > 1:
        from scipy.stats import qmc
        pts = qmc.Sobol(len(problem.params), scramble=True, seed=seed).random(
            2 ** math.ceil(math.log2(starts - 1)) if starts > 2 else 1)
        out += [np.clip(p, 0.0, 1.0) for p in pts[:starts - 1]]
    return out


def calibrate(problem: Problem, executor=None, starts: int = 1, seed: int = 0,
              diff_step: float = 1e-3, max_evaluations: int | None = None,
              log=None) -> dict:
    """Fit ``problem``'s parameters; the result dict of the module doc's CLI keys."""
    from scipy.optimize import least_squares
    task = CaseTask(problem.cases)
    ev = Evaluations(task, problem, executor)
    n = len(problem.params)
    t0 = time.perf_counter()
    first = starts_in_box(problem, starts, seed)
    before = ev.one(first[0])
    runs = []
    for s, z0 in enumerate(first):
        def fun(z):
            r = ev.one(z)["r"]
            cost = 0.5 * float(r @ r)
            ev.history.append({"start": s, "simulations": ev.simulations, "cost": cost})
            if log:
                log(f"start {s + 1}/{len(first)}: cost {cost:.6g} after "
                    f"{ev.simulations} simulations")
            return r

        budget = max_evaluations or 30 * (n + 1)
        sol = least_squares(fun, z0, jac=lambda z: _jacobian(ev, z, diff_step),
                            bounds=(np.zeros(n), np.ones(n)), method="trf", x_scale=1.0,
                            max_nfev=budget, ftol=1e-10, xtol=1e-10, gtol=1e-10)
        # trf stops on a step-size test where a forward-difference Jacobian is too coarse
        # for a sharply determined parameter; a Gauss-Newton step from the stop says
        # whether the cost still falls, and the fit goes on from there (a new-user trial:
        # kp and EI stopped 1e-3 short of a noise-free record, intervals excluding them)
        restarts, pending = 0, _gauss_newton_gain(ev, sol.x, diff_step)
        while pending is not None and restarts < MAX_RESTARTS:
            restarts += 1
            sol = least_squares(fun, pending, jac=lambda z: _jacobian(ev, z, diff_step),
                                bounds=(np.zeros(n), np.ones(n)), method="trf",
                                x_scale=1.0, max_nfev=budget, ftol=1e-10, xtol=1e-10,
                                gtol=1e-10)
            pending = _gauss_newton_gain(ev, sol.x, diff_step)
        if pending is not None:
            ev.warnings.append(
                f"start {s + 1} stopped where a Gauss-Newton step still lowers the cost "
                f"({restarts} restarts): the values may be short of the minimum and the "
                f"intervals too narrow; try another --diff-step or --starts")
        runs.append({"start": problem.values(z0), "value": problem.values(sol.x),
                     "cost": float(sol.cost), "status": int(sol.status),
                     "message": str(sol.message), "nfev": int(sol.nfev),
                     "njev": int(sol.njev or 0), "z": sol.x, "restarts": restarts})
    best = min(runs, key=lambda r: r["cost"])
    zb = best["z"]
    after = ev.one(zb)
    J = _jacobian(ev, zb, diff_step)
    stats = analyse(J, after["r"], problem.params, zb, problem.absolute, problem.blocks())
    wall = time.perf_counter() - t0
    for i, r in enumerate(runs):
        if r["status"] == 0:
            ev.warnings.append(f"start {i + 1} stopped at the evaluation limit "
                               f"({r['nfev']}) before converging: raise --max-evaluations")
    fit = goodness_of_fit(after["r"], n, problem.absolute)
    if fit.get("warning"):
        ev.warnings.append(fit["warning"])
    spread = disagreeing_starts(runs, best, stats["parameters"])
    if spread:
        ev.warnings.append(spread)
    return {"parameters": stats["parameters"],
            "cost_before": 0.5 * float(before["r"] @ before["r"]),
            "cost_after": 0.5 * float(after["r"] @ after["r"]),
            "unidentifiable": stats["unidentifiable"],
            "evaluations": ev.simulations,
            "points": ev.points,
            "wall_s": wall,
            "statistics": {k: v for k, v in stats.items()
                           if k not in ("parameters", "unidentifiable")},
            "observables": observables_table(problem, before, after),
            "goodness_of_fit": fit,
            "starts": [{k: v for k, v in r.items() if k != "z"} for r in runs],
            "history": ev.history,
            "warnings": list(dict.fromkeys(ev.warnings)),
            "residual_count": problem.size,
            "_z": zb, "_z0": first[0]}


def disagreeing_starts(runs, best, params) -> str:
    """A warning when other starts ended outside the best one's 95 % intervals: the cost
    has several valleys (an oscillating record's phase wraps), the best found is reported,
    and a deeper one may exist that no start reached."""
    if len(runs) < 2:
        return ""
    out = []
    for i, r in enumerate(runs):
        if r is best:
            continue
        for p, v in zip(params, r["value"]):
            lo_hi = p["ci95"]
            if lo_hi is None or not lo_hi[0] <= v <= lo_hi[1]:
                out.append(f"start {i + 1}: {p['key']} = {v:.6g}, cost {r['cost']:.6g}")
                break
    if not out:
        return ""
    return (f"{len(out)} of {len(runs)} starts ended in other valleys ({'; '.join(out)}; "
            f"best cost {best['cost']:.6g}): the cost has several minima, the best found is "
            f"reported and its intervals describe that valley only — a deeper one may exist; "
            f"add observables that separate them (a frequency, mode:K) or narrow the bounds")


def goodness_of_fit(r, n: int, absolute: bool) -> dict:
    """χ² = Σr² against m − n degrees of freedom when every σ is stated: a fit far worse
    than the noise (p < 0.001) means the model cannot meet the data within their σ, and
    the intervals (which assume it can) are too narrow."""
    from scipy import stats
    m = len(r)
    chi2 = float(np.asarray(r) @ np.asarray(r))
    dof = m - n
    out = {"chi2": chi2, "degrees_of_freedom": dof, "p_value": None, "warning": ""}
    if absolute and dof > 0:
        p = float(stats.chi2.sf(chi2, dof))
        out["p_value"] = p
        if p < 1e-3:
            out["warning"] = (f"the fit leaves χ² = {chi2:.4g} on {dof} degrees of freedom "
                              f"(p = {p:.2g}): the model does not meet the data within their "
                              f"σ at any value in the bounds; the intervals assume it does "
                              f"and are too narrow (a missing effect, or σ too small)")
    return out


def observables_table(problem: Problem, before: dict, after: dict) -> list[dict]:
    """Per case and observable: before/after (series: RMS error in the channel's unit;
    features: the value, the target and σ)."""
    rows = []
    for k, case in enumerate(problem.cases):
        b, a = before["cases"][k], after["cases"][k]
        for i, s in enumerate(case.series):
            rows.append({"case": case.name, "observable": s.channel, "kind": "series",
                         "unit": s.unit, "samples": s.size, "sigma": s.sigma,
                         "sigma_given": s.sigma_given,
                         "rms_before": _f(b["rms"][i]), "rms_after": _f(a["rms"][i])})
        for i, f in enumerate(case.features):
            rows.append({"case": case.name, "observable": f.metric, "kind": "feature",
                         "target": f.value, "sigma": f.sigma,
                         "before": _f(b["features"][i]), "after": _f(a["features"][i])})
    return rows


def _f(x):
    return None if x is None or not math.isfinite(x) else float(x)
