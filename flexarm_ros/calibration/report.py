"""``flexarm calibrate --report DIR``: Markdown with the fitted values, what the data
cannot determine, the residuals before/after, and PNGs (overlays of each fitted channel
before/after against the record, the cost history, the correlation map)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def _figure(w=7.0, h=3.2):
    from matplotlib.figure import Figure
    return Figure(figsize=(w, h), dpi=110)


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def _g(x, digits=6) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}g}"


def _overlays(problem, out, d: Path) -> list[Path]:
    from flexarm_ros.calibration.task import CaseTask
    from flexarm_ros.ensemble.metrics import channel
    task = CaseTask(problem.cases)
    paths = []
    z0, zb = out["_z0"], out["_z"]
    for k, case in enumerate(problem.cases):
        if not case.series:
            continue
        runs = {}
        for label, z in (("before", z0), ("after", zb)):
            try:
                runs[label] = task.simulate((k, problem.assignment(z)))
            except Exception:  # noqa: BLE001 - a figure is not worth a failed report
                runs[label] = None
        for s in case.series:
            fig = _figure()
            ax = fig.add_subplot(111)
            ax.plot(s.t, s.y, color="0.6", lw=0.8, label="record")
            for label, style in (("before", "C1--"), ("after", "C0-")):
                res = runs[label]
                if res is None:
                    continue
                t, y = channel(res, s.channel)
                sel = (t >= s.t[0] + case.offset_s) & (t <= s.t[-1] + case.offset_s)
                ax.plot(t[sel] - case.offset_s, y[sel], style, lw=1.0, label=label)
            ax.set_xlabel("t [s] (record clock)")
            ax.set_ylabel(f"{s.channel} [{s.unit}]" if s.unit else s.channel)
            ax.legend(loc="best", fontsize=8)
            ax.set_title(f"{case.name}: {s.channel}", fontsize=9)
            fig.tight_layout()
            p = d / f"overlay_{_safe(case.name)}_{_safe(s.channel)}.png"
            fig.savefig(p)
            paths.append(p)
    return paths


def _history(out, d: Path) -> Path:
    fig = _figure(6, 3)
    ax = fig.add_subplot(111)
    for s in sorted({h["start"] for h in out["history"]}):
        pts = [(h["simulations"], h["cost"]) for h in out["history"] if h["start"] == s]
        ax.semilogy([a for a, _ in pts], [max(b, 1e-300) for _, b in pts], "o-", ms=3,
                    label=f"start {s + 1}")
    ax.set_xlabel("simulations")
    ax.set_ylabel("cost ½Σr²")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = d / "cost_history.png"
    fig.savefig(p)
    return p


def _correlation(out, d: Path) -> Path | None:
    names = [p["key"] for p in out["parameters"]]
    if len(names) < 2:
        return None
    c = np.array([[np.nan if x is None else x for x in row]
                  for row in out["statistics"]["correlation"]], float)
    fig = _figure(1.6 + 0.9 * len(names), 1.2 + 0.8 * len(names))
    ax = fig.add_subplot(111)
    im = ax.imshow(c, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(names)), [n.split(".")[-1] for n in names], rotation=45,
                  ha="right", fontsize=7)
    ax.set_yticks(range(len(names)), [n.split(".")[-1] for n in names], fontsize=7)
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, "n/a" if np.isnan(c[i, j]) else f"{c[i, j]:.2f}", ha="center",
                    va="center", fontsize=7)
    fig.colorbar(im, ax=ax)
    fig.tight_layout()
    p = d / "correlation.png"
    fig.savefig(p)
    return p


def write_report(problem, out: dict, directory) -> Path:
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    figs = _overlays(problem, out, d)
    hist = _history(out, d)
    corr = _correlation(out, d)
    st = out["statistics"]
    L = ["# Calibration report", "",
         f"{len(out['parameters'])} parameter(s), {len(problem.cases)} case(s), "
         f"{out['residual_count']} residuals; cost ½Σr² {_g(out['cost_before'])} → "
         f"{_g(out['cost_after'])}; {out['evaluations']} simulations in "
         f"{out['wall_s']:.1f} s.", "",
         "Noise level: " + ("the stated σ of every observable (s² = 1)"
                            if st["absolute_sigma"] else
                            f"from the residuals, per channel (mean s² = "
                            f"{_g(st['noise_variance'], 4)} in units of each channel's "
                            f"scale)") +
         f"; 95 % quantile {st['quantile']:.4g} ({st['degrees_of_freedom']} degrees of "
         f"freedom).", "",
         "## Fitted values", "",
         "| key | value | ±1σ | 95 % interval | start | bounds | identifiable |",
         "|---|---|---|---|---|---|---|"]
    for p in out["parameters"]:
        ci = (f"{_g(p['ci95'][0])} .. {_g(p['ci95'][1])}" if p["ci95"] else "—")
        L.append(f"| `{p['key']}` | {_g(p['value'])} {'' if p['unit'] == '1' else p['unit']} | {_g(p['stderr'], 3)} | "
                 f"{ci} | {_g(p['start'])} | {p['low']:g} .. {p['high']:g} "
                 f"({p['scale']}) | {'yes' if p['identifiable'] else '**no**'}"
                 f"{' (at a bound)' if p['at_bound'] else ''} |")
    L += [""]
    if out["unidentifiable"]:
        L += ["## What these data cannot determine", ""]
        L += [f"- {u['text']}" for u in out["unidentifiable"]]
        L += [""]
    L += ["## Singular values of the Jacobian (box coordinates)", "",
          "| σ | 95 % half-width along it (box = 1) | direction |", "|---|---|---|"]
    for s, h, v in zip(st["singular_values"], st["interval_along_direction"],
                       st["directions"]):
        dirs = ", ".join(f"{k.split('.')[-1]} {x:+.2f}" for k, x in v.items()
                         if abs(x) >= 0.05)
        L.append(f"| {_g(s, 4)} | {_g(h, 3)} | {dirs} |")
    names = [p["key"] for p in out["parameters"]]
    if len(names) > 1:
        L += ["", "## Correlation", "", "| | " + " | ".join(f"`{n}`" for n in names) + " |",
              "|---|" + "---|" * len(names)]
        for n, row in zip(names, st["correlation"]):
            L.append(f"| `{n}` | " + " | ".join("n/a" if x is None else f"{x:+.3f}"
                                                for x in row) + " |")
    L += ["", "## Observables before and after", "",
          "| case | observable | before | after | target / σ |", "|---|---|---|---|---|"]
    for r in out["observables"]:
        if r["kind"] == "series":
            L.append(f"| {r['case']} | {r['observable']} (RMS error, {r['unit']}) | "
                     f"{_g(r['rms_before'], 4)} | {_g(r['rms_after'], 4)} | "
                     f"σ {_g(r['sigma'], 3)}{'' if r['sigma_given'] else ' (scale)'} |")
        else:
            L.append(f"| {r['case']} | {r['observable']} | {_g(r['before'])} | "
                     f"{_g(r['after'])} | {_g(r['target'])} ± {_g(r['sigma'], 3)} |")
    L += ["", "## Starts", "", "| start | from | to | cost | scipy |", "|---|---|---|---|---|"]
    for i, s in enumerate(out["starts"]):
        L.append(f"| {i + 1} | {', '.join(_g(x, 4) for x in s['start'])} | "
                 f"{', '.join(_g(x, 6) for x in s['value'])} | {_g(s['cost'])} | "
                 f"{s['message']} |")
    if out["warnings"]:
        L += ["", "## Warnings", ""] + [f"- {w}" for w in out["warnings"][:50]]
    L += ["", "## Figures", "", f"![cost history]({hist.name})"]
    if corr is not None:
        L.append(f"![correlation]({corr.name})")
    L += [f"![{p.stem}]({p.name})" for p in figs]
    path = d / "calibration.md"
    path.write_text("\n".join(L) + "\n", encoding="utf-8")
    return path
