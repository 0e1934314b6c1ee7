"""Uncertainty (Monte Carlo) and sensitivity (Morris, Sobol) over a spec's unknowns, on
the ensemble runner.

Uncertainty
    ``N`` points of the unit cube (independent uniform draws, or a Latin hypercube), sent
    through each unknown's inverse CDF (:mod:`flexarm_ros.ensemble.spec`), one simulation
    each. Per metric over the ok samples: mean, standard deviation and the 5, 25, 50, 75
    and 95 % percentiles (``numpy.percentile``, linear interpolation between order
    statistics); the envelope of a channel is the median and the 5–95 % band at every
    output time (the samples' own grid, which every sample of one spec shares).

Sensitivity (SALib, Herman & Usher 2017)
    Morris screening (Morris 1991; μ* of Campolongo et al. 2007): ``r`` trajectories of
    ``d + 1`` points on a 4-level grid of the unit cube; per unknown ``μ* = mean |EE|``
    and ``σ`` of the elementary effects ``EE = (f(u + Δ e_i) − f(u)) / Δ``, ``Δ = 2/3``,
    in metric units per unit of quantile, with a bootstrap confidence interval of μ*.
    Sobol indices (Sobol' 2001; Saltelli 2002, Saltelli et al. 2010 estimators): ``N (d +
    2)`` points of the Saltelli scheme on a Sobol' sequence; ``S1`` (first order) and
    ``ST`` (total) with 95 % bootstrap confidence intervals (100 resamples, seeded).
    Both are taken in the unit cube of quantiles: the map to the unknowns is monotone per
    coordinate, so the Sobol indices are those of the unknowns themselves.

    A sample that is not ok (diverged, refused) has no metric value; the analyses need
    every point of their design, so such values are replaced by the mean of the ok ones
    and the count is reported (``n_imputed``): with more than a few percent imputed the
    indices are not to be trusted.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.ensemble.runner import run_ensemble

PERCENTILES = (5, 25, 50, 75, 95)
MORRIS_LEVELS = 4
CONF_LEVEL = 0.95
RESAMPLES = 100


def _model(spec, base, series=()):
    from flexarm_ros.ensemble.metrics import resolve_metrics
    from flexarm_ros.ensemble.runner import SceneModel
    return SceneModel(base, resolve_metrics(spec.metrics, base), spec.duration, series)


def _run(spec, unit, model, base, meta, **kw):
    assignments = spec.assignments(unit)
    names = spec.names
    labels = [spec.named(a) for a in assignments]
    table = run_ensemble(base, assignments, model=model, params=names, labels=labels,
                         meta=meta, **kw)
    return table


# ------------------------------------------------------------------------ uncertainty
def statistics(table) -> dict:
    """``{metric: {n_ok, mean, std, p5, p25, p50, p75, p95}}`` over the ok, finite
    values (None where there are none)."""
    out = {}
    for m in table.metrics:
        y = table.column(m)
        y = y[table.ok & np.isfinite(y)]
        s = {"n": int(len(y))}
        if len(y):
            s["mean"] = float(np.mean(y))
            s["std"] = float(np.std(y, ddof=1)) if len(y) > 1 else 0.0
            for p, v in zip(PERCENTILES, np.percentile(y, PERCENTILES)):
                s[f"p{p}"] = float(v)
        else:
            s.update({k: None for k in ["mean", "std"] + [f"p{p}" for p in PERCENTILES]})
        out[m] = s
    return out


def envelope(table, channel: str):
    """``(t, median, p5, p95)`` of a channel over the ok samples (None if none)."""
    runs = [s for s, r in zip(table.series or [], table.rows) if s and r["status"] == "ok"]
    if not runs:
        return None
    t = np.asarray(runs[0]["t"], float)
    ys = np.vstack([np.interp(t, s["t"], s[channel]) if len(s["t"]) != len(t)
                    else np.asarray(s[channel], float) for s in runs])
    p5, med, p95 = np.percentile(ys, [5, 50, 95], axis=0)
    return t, med, p5, p95


def run_uncertainty(spec, samples=None, seed=None, design="random", channel=None,
                    model=None, **kw):
    """Monte Carlo over the spec; returns ``(table, stats, envelope or None)``."""
    from flexarm_ros.ensemble.designs import unit_points
    from flexarm_ros.ensemble.limits import check_samples, check_seed
    n = spec.samples if samples is None else samples
    seed = spec.seed if seed is None else seed
    check_samples(n)
    check_seed(seed)
    if design not in ("random", "lhs"):
        raise InputError(f"--design: got {design!r}, expected random or lhs")
    base = spec.base_scene() if model is None else None
    channel = channel or spec.channel
    model = model or _model(spec, base, (channel,) if channel else ())
    unit = unit_points(design, len(spec.unknowns), n, seed)
    meta = {"kind": "uncertainty", "design": design, "seed": seed, "samples": n,
            "unknowns": _describe(spec)}
    table = _run(spec, unit, model, base, meta, **kw)
    env = envelope(table, channel) if channel else None
    return table, statistics(table), env


def _describe(spec) -> list[dict]:
    return [{"name": u.name, "keys": list(u.keys), "dist": u.dist, **u.par}
            for u in spec.unknowns]


# ------------------------------------------------------------------------ sensitivity
def _problem(spec) -> dict:
    for k, u in enumerate(spec.unknowns):
        if not u.bounded:
            raise InputError(f"unknowns[{k}] ({u.name}): got {u.describe()} without "
                             f"low/high, expected a bounded distribution for sensitivity "
                             f"analysis (the designs reach the ends of the quantile range)")
    return {"num_vars": len(spec.unknowns), "names": spec.names,
            "bounds": [[0.0, 1.0]] * len(spec.unknowns)}


def sensitivity_runs(spec, method: str, n: int) -> int:
    """Runs of the method's design of ``n``: Morris ``n (d + 1)``, Sobol ``n (d + 2)``."""
    d = len(spec.unknowns)
    return int(n) * (d + (1 if method == "morris" else 2))


def sensitivity_design(spec, method: str, n: int, seed: int) -> np.ndarray:
    """The unit-cube points of the method: Morris ``n`` trajectories (``n (d + 1)``
    points), Sobol base ``n`` (``n (d + 2)`` points, first and total order)."""
    problem = _problem(spec)
    if method == "morris":
        from SALib.sample import morris
        return morris.sample(problem, n, num_levels=MORRIS_LEVELS, seed=seed)
    if method == "sobol":
        if n < 2 or n & (n - 1):
            lo = 2 ** max(1, math.floor(math.log2(max(n, 2))))
            raise InputError(f"--samples: got {n} with --method sobol, expected a power of "
                             f"two (e.g. {lo} or {2 * lo}): the base sample of the Saltelli "
                             f"scheme on a Sobol' sequence")
        from SALib.sample import sobol
        return sobol.sample(problem, n, calc_second_order=False, seed=seed)
    raise InputError(f"--method: got {method!r}, expected morris or sobol")


def analyse(spec, method: str, unit: np.ndarray, table, seed: int) -> dict:
    """SALib analysis of every metric column of ``table`` (see module doc)."""
    problem = _problem(spec)
    out = {"method": method, "unknowns": _describe(spec), "samples": len(table.rows),
           "seed": seed, "conf_level": CONF_LEVEL, "metrics": {}}
    for m in table.metrics:
        y = table.column(m).astype(float)
        good = table.ok & np.isfinite(y)
        entry = {"n_imputed": int(np.count_nonzero(~good))}
        if np.count_nonzero(good) < 2 or np.ptp(y[good]) == 0.0:
            entry["ranked"] = []
            entry["note"] = ("no variation" if np.count_nonzero(good) >= 2 else
                             "fewer than two ok samples")
            out["metrics"][m] = entry
            continue
        y = np.where(good, y, np.mean(y[good]))
        with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            if method == "sobol":
                from SALib.analyze import sobol
                si = sobol.analyze(problem, y, calc_second_order=False,
                                   num_resamples=RESAMPLES, conf_level=CONF_LEVEL, seed=seed)
                rows = [{"unknown": n, "S1": float(si["S1"][i]),
                         "S1_conf": float(si["S1_conf"][i]), "ST": float(si["ST"][i]),
                         "ST_conf": float(si["ST_conf"][i])}
                        for i, n in enumerate(problem["names"])]
                rows.sort(key=lambda r: -r["ST"])
            else:
                from SALib.analyze import morris
                si = morris.analyze(problem, unit, y, num_resamples=RESAMPLES,
                                    conf_level=CONF_LEVEL, num_levels=MORRIS_LEVELS, seed=seed)
                rows = [{"unknown": n, "mu_star": float(si["mu_star"][i]),
                         "mu_star_conf": float(si["mu_star_conf"][i]),
                         "mu": float(si["mu"][i]), "sigma": float(si["sigma"][i])}
                        for i, n in enumerate(problem["names"])]
                rows.sort(key=lambda r: -r["mu_star"])
        for k, r in enumerate(rows, 1):
            r["rank"] = k
        entry["ranked"] = rows
        out["metrics"][m] = entry
    return out


def run_sensitivity(spec, method="sobol", samples=None, seed=None, model=None, **kw):
    """Morris or Sobol over the spec's unknowns; returns ``(result, table)``."""
    from flexarm_ros.ensemble.limits import check_samples, check_seed
    seed = spec.seed if seed is None else seed
    n = samples if samples is not None else (8 if method == "morris" else 64)
    check_samples(n)
    check_seed(seed)
    unit = sensitivity_design(spec, method, n, seed)
    base = spec.base_scene() if model is None else None
    model = model or _model(spec, base)
    meta = {"kind": "sensitivity", "method": method, "seed": seed, "base_samples": n,
            "unknowns": _describe(spec)}
    table = _run(spec, unit, model, base, meta, **kw)
    return analyse(spec, method, unit, table, seed), table


def format_sensitivity(result: dict, markdown: bool = False) -> str:
    """The ranked table per metric (text or Markdown)."""
    lines = []
    conf = f"{100 * result['conf_level']:.0f} %"
    for m, e in result["metrics"].items():
        head = (f"{m}: {result['method']} over {result['samples']} samples"
                + (f", {e['n_imputed']} not ok (imputed with the mean)" if e["n_imputed"]
                   else ""))
        if not e["ranked"]:
            lines += [head + f": {e.get('note')}", ""]
            continue
        if result["method"] == "sobol":
            cols = ["rank", "unknown", "ST", f"ST ± ({conf})", "S1", f"S1 ± ({conf})"]
            vals = [[r["rank"], r["unknown"], f"{r['ST']:.3f}", f"{r['ST_conf']:.3f}",
                     f"{r['S1']:.3f}", f"{r['S1_conf']:.3f}"] for r in e["ranked"]]
        else:
            cols = ["rank", "unknown", "mu*", f"mu* ± ({conf})", "mu", "sigma"]
            vals = [[r["rank"], r["unknown"], f"{r['mu_star']:.4g}",
                     f"{r['mu_star_conf']:.3g}", f"{r['mu']:.4g}", f"{r['sigma']:.4g}"]
                    for r in e["ranked"]]
        if markdown:
            lines += [f"**{head}**", "", "| " + " | ".join(cols) + " |",
                      "|" + "---|" * len(cols)]
            lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in vals]
        else:
            w = [max(len(str(c)), *(len(str(r[i])) for r in vals)) for i, c in
                 enumerate(cols)]
            lines += [head, "  ".join(str(c).ljust(w[i]) for i, c in enumerate(cols))]
            lines += ["  ".join(str(v).ljust(w[i]) for i, v in enumerate(row)) for row in vals]
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
