"""Seed 000: calibrate Case 1, predict Case 2 (held out), fit both, report what they fix.

Calibrate Case 1 alone, predict Case 2 as the held-out check, then fit both cases and
report what the pair determines.

    python tools/calibrate_seed000.py                 # local Dask cluster, 2 workers
    python tools/calibrate_seed000.py --workers 0     # in this process

Writes docs/calibration_seed000.md. The fits are `flexarm calibrate --spec
examples/calibrate_case1.yaml` and `--spec examples/calibrate_case12.yaml` (the same code
path); the prediction runs Case 2's scene with Case 1's fitted values and evaluates the
same metrics.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.calibration.fit import Problem, calibrate  # noqa: E402
from flexarm_ros.calibration.parameters import start_assignment  # noqa: E402
from flexarm_ros.calibration.setup import load_spec  # noqa: E402
from flexarm_ros.ensemble.keys import set_keys  # noqa: E402
from flexarm_ros.ensemble.metrics import evaluate, parse_metric, resolve_metrics  # noqa: E402
from flexarm_ros.ensemble.runner import open_executor, run_tasks  # noqa: E402
from flexarm_ros.scene import load_scene  # noqa: E402

METRICS = ["impact_time", "bounce_height", "frequency:acc_A_true", "frequency:acc_B_true",
           "frequency:acc_C_true", "frequency:acc_D_true"]
EXPERIMENT = {"two_link_case1": {"impact_time": "≈ 2.1", "bounce_height": "≈ 0.005",
                                 "frequency:acc_A_true": "10.96",
                                 "frequency:acc_B_true": "10.94",
                                 "frequency:acc_C_true": "10.56",
                                 "frequency:acc_D_true": "—"},
              "two_link_case2": {"impact_time": "—", "bounce_height": "—",
                                 "frequency:acc_A_true": "9.31–9.71",
                                 "frequency:acc_B_true": "(too noisy)",
                                 "frequency:acc_C_true": "9.31–9.71",
                                 "frequency:acc_D_true": "(too noisy)"}}
DURATION = 3.5


class Features:
    """Task: (scene name, assignment) → the metrics of a 3.5 s run."""

    def __call__(self, item):
        from flexarm_ros.sim.simulate import simulate
        name, assignment = item
        scene = set_keys(load_scene(name), assignment)
        res = simulate(scene, DURATION)
        return evaluate(res, resolve_metrics(METRICS, scene))


def _fmt(x, unit=""):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.4g}{unit}"


def _metric_cell(name, v):
    if name == "bounce_height":
        return _fmt(v * 1e3 if v is not None else None) + " mm"
    if name == "impact_time":
        return _fmt(v) + " s"
    return _fmt(v) + " Hz"


def _params_table(out) -> list[str]:
    L = ["| parameter | start | fitted | ±1σ | 95 % interval | identifiable |",
         "|---|---|---|---|---|---|"]
    for p in out["parameters"]:
        ci = f"{p['ci95'][0]:.4g} .. {p['ci95'][1]:.4g}" if p["ci95"] else "—"
        L.append(f"| `{p['key']}` | {p['start']:.4g} | {p['value']:.4g} | "
                 f"{_fmt(p['stderr'])} | {ci} | {'yes' if p['identifiable'] else '**no**'}"
                 f"{' (at a bound)' if p['at_bound'] else ''} |")
    for u in out["unidentifiable"]:
        L.append("")
        L.append(f"- {u['text']}")
    gof = out.get("goodness_of_fit", {})
    L += ["", f"Cost ½χ² {out['cost_before']:.4g} → {out['cost_after']:.4g} "
              f"(χ² {gof.get('chi2', math.nan):.3g} on {gof.get('degrees_of_freedom')} "
              f"degrees of freedom); {out['evaluations']} simulations, "
              f"{out['wall_s']:.0f} s."]
    for w in out["warnings"]:
        if "does not meet" in w:
            L.append(f"Warning: {w}")
    return L


def _into_reproduction(L, fit1, fit12, full: Path) -> None:
    """docs/reproduction_contact.md: the fitted-vs-predicted table after the uncalibrated
    one (a block tools/reproduce_contact.py keeps when it regenerates the file)."""
    sys.path.insert(0, str(ROOT / "tools"))
    from reproduce_contact import CALIBRATION_BEGIN
    doc = ROOT / "docs" / "reproduction_contact.md"
    text = doc.read_text() if doc.exists() else ""
    if CALIBRATION_BEGIN in text:
        text = text[:text.index(CALIBRATION_BEGIN)].rstrip() + "\n"
    a = L.index("## 2. Case 1 fit, Case 2 predicted (held out)")
    b = L.index("## 3. Fitted on Cases 1 and 2 together")
    fitted = ", ".join(f"{p['key']} = {p['value']:.4g}"
                       + (f" ± {p['stderr']:.2g}" if p["stderr"] is not None else
                          " (not identifiable alone)") for p in fit1["parameters"])
    block = [CALIBRATION_BEGIN, "", "## Calibrated on Case 1, Case 2 predicted", "",
             f"`flexarm calibrate --spec examples/calibrate_case1.yaml` on Case 1's reported "
             f"features (cubic rung): {fitted}. Fitted (Case 1) and predicted (Case 2) "
             f"side by side; details, the fit on both cases and what the data cannot "
             f"separate: [`{full.name}`]({full.name}).", ""] + L[a + 2:b]
    doc.write_text(text + "\n" + "\n".join(block).rstrip() + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "calibration_seed000.md")
    ap.add_argument("--quick", action="store_true",
                    help="3 evaluations per fit (a smoke test of the pipeline, not a result)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    p1, c1, o1 = load_spec(ROOT / "examples" / "calibrate_case1.yaml")
    p12, c12, o12 = load_spec(ROOT / "examples" / "calibrate_case12.yaml")
    if args.quick:
        o1["max_evaluations"] = o12["max_evaluations"] = 3
    with open_executor(args.workers) as ex:
        fit1 = calibrate(Problem(p1, c1), ex, diff_step=o1["diff_step"],
                         max_evaluations=o1["max_evaluations"],
                         log=lambda s: print(f"case 1: {s}", file=sys.stderr))
        sets1 = Problem(p1, c1).assignment(fit1["_z"])
        start = start_assignment(p1)
        items = [(sc, a) for sc in ("two_link_case1", "two_link_case2")
                 for a in (start, sets1)]
        feats = run_tasks(Features(), items, ex)
        fit12 = calibrate(Problem(p12, c12), ex, diff_step=o12["diff_step"],
                          max_evaluations=o12["max_evaluations"],
                          log=lambda s: print(f"cases 1+2: {s}", file=sys.stderr))
        sets12 = Problem(p12, c12).assignment(fit12["_z"])
        feats12 = run_tasks(Features(), [(sc, sets12) for sc in ("two_link_case1",
                                                                   "two_link_case2")], ex)
    wall = time.perf_counter() - t0
    by = {(sc, k): f for (sc, a), f, k in zip(items, feats, ["start", "fit1"] * 2)}
    by[("two_link_case1", "fit12")], by[("two_link_case2", "fit12")] = feats12
    L = ["# Seed 000: calibrated on Case 1, Case 2 predicted", "",
         "Regenerate: `python tools/calibrate_seed000.py` (the fits are `flexarm calibrate "
         "--spec examples/calibrate_case1.yaml` and `examples/calibrate_case12.yaml`; "
         f"{wall / 60:.1f} min here on "
         + (f"a local Dask cluster of {args.workers} worker(s))." if args.workers else
            "this process)."),
         "",
         "The source publishes no time series of the experiment (figures only), so the "
         "observables are the features it reports, with the uncertainty its reading "
         "allows (spec files). The parameters are what remains unknown after the geometry "
         "derived from the source (config/two_link_case1.yaml, assumptions), within the "
         "bounds derived there.", "",
         "## 1. Fitted on Case 1 alone", ""] + _params_table(fit1) + [
         "", "## 2. Case 1 fit, Case 2 predicted (held out)", "",
         "| case | metric | experiment | geometry only | Case 1 fit | fit on both |",
         "|---|---|---|---|---|---|"]
    for sc in ("two_link_case1", "two_link_case2"):
        for m in METRICS:
            col = parse_metric(m).column
            vals = [by[(sc, k)].get(col) for k in ("start", "fit1", "fit12")]
            L.append(f"| {sc[-5:]} | {m} | {EXPERIMENT[sc][m]} | "
                     + " | ".join(_metric_cell(m, v) for v in vals) + " |")
    L += ["", "## 3. Fitted on Cases 1 and 2 together", ""] + _params_table(fit12)
    if args.quick:
        L.insert(1, "")
        L.insert(2, "**Smoke run (--quick: 3 evaluations per fit, not converged) — not a "
                    "result.**")
    args.out.write_text("\n".join(L) + "\n", encoding="utf-8")
    default_out = args.out.resolve() == (ROOT / "docs" / "calibration_seed000.md").resolve()
    if not args.quick and default_out:        # the docs only from a full run to the docs
        _into_reproduction(L, fit1, fit12, args.out)
    print(f"wrote {args.out} in {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
