"""Figures of ensembles (PNG, matplotlib's Agg canvas: no display, no pyplot state).

* :func:`plot_sweep`: every metric against every parameter (ok samples as dots, samples
  that are not ok as red crosses on the lower edge), and for two parameters a map of each
  metric over the plane of the two.
* :func:`plot_histograms`: a histogram per metric with the 5/50/95 % percentiles.
* :func:`plot_envelope`: the median and the 5–95 % band of a channel over time.
* :func:`plot_sensitivity`: ranked bars of Sobol S1/ST or Morris μ* with their
  confidence intervals, one panel per metric.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np


def _figure(w, h):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(w, h), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")


def _numeric(col) -> bool:
    try:
        np.asarray(col, float)
        return True
    except (TypeError, ValueError):
        return False


def plot_sweep(table, directory) -> list[Path]:
    """``<metric>.png`` per metric (one panel per parameter) and, with two parameters,
    ``<metric>_map.png``; returns the paths written."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    ok = table.ok
    out = []
    for m in table.metrics:
        y = table.column(m)
        n = max(1, len(table.params))
        fig = _figure(4.2 * n, 3.4)
        for j, p in enumerate(table.params or ["sample"]):
            ax = fig.add_subplot(1, n, j + 1)
            x = table.column(p)
            if not _numeric(x):
                cats = list(dict.fromkeys(x.tolist()))
                ax.set_xticks(range(len(cats)), [str(c) for c in cats])
                x = np.array([cats.index(v) for v in x], float)
            x = np.asarray(x, float)
            good = ok & np.isfinite(y)
            ax.plot(x[good], y[good], "o", ms=4, color="tab:blue", label="ok")
            if np.any(~ok):
                lo = np.nanmin(y[good]) if np.any(good) else 0.0
                ax.plot(x[~ok], np.full(np.count_nonzero(~ok), lo), "x", color="tab:red",
                        label="not ok")
                ax.legend(fontsize=7)
            ax.set_xlabel(p, fontsize=8)
            ax.set_ylabel(m, fontsize=8)
            ax.grid(True, color="0.9")
        fig.suptitle(f"{table.meta.get('scene', '')}: {m}", fontsize=9)
        fig.tight_layout()
        path = d / f"{_safe(m)}.png"
        fig.savefig(str(path))
        out.append(path)
        if len(table.params) == 2:
            out.append(_map(table, m, d))
    return out


def _map(table, m, d: Path) -> Path:
    p, q = table.params
    x, y, z = table.column(p), table.column(q), table.column(m)
    fig = _figure(5.6, 4.6)
    ax = fig.add_subplot(1, 1, 1)
    labels = {}
    for name, v in (("x", x), ("y", y)):
        if not _numeric(v):
            cats = list(dict.fromkeys(v.tolist()))
            labels[name] = cats
    x = np.array([labels["x"].index(v) for v in x], float) if "x" in labels else \
        np.asarray(x, float)
    y = np.array([labels["y"].index(v) for v in y], float) if "y" in labels else \
        np.asarray(y, float)
    good = table.ok & np.isfinite(z)
    if np.count_nonzero(good) >= 3 and len(np.unique(x[good])) > 1 and \
            len(np.unique(y[good])) > 1:
        try:
            cs = ax.tricontourf(x[good], y[good], z[good], levels=12, cmap="viridis")
            fig.colorbar(cs, ax=ax, label=m)
        except (ValueError, RuntimeError):   # collinear points: the dots alone
            pass
    sc = ax.scatter(x[good], y[good], c=z[good], cmap="viridis", edgecolors="k", s=28)
    if not ax.collections[:-1]:
        fig.colorbar(sc, ax=ax, label=m)
    if np.any(~good):
        ax.plot(x[~good], y[~good], "x", color="tab:red", label="not ok / undefined")
        ax.legend(fontsize=7)
    for lim, v in ((ax.set_xlim, x), (ax.set_ylim, y)):     # room for the edge markers
        lo, hi = float(np.min(v)), float(np.max(v))
        pad = 0.05 * (hi - lo) if hi > lo else 0.5
        lim(lo - pad, hi + pad)
    if "x" in labels:
        ax.set_xticks(range(len(labels["x"])), [str(c) for c in labels["x"]])
    if "y" in labels:
        ax.set_yticks(range(len(labels["y"])), [str(c) for c in labels["y"]])
    ax.set_xlabel(p, fontsize=8)
    ax.set_ylabel(q, fontsize=8)
    ax.set_title(f"{table.meta.get('scene', '')}: {m}", fontsize=9)
    fig.tight_layout()
    path = d / f"{_safe(m)}_map.png"
    fig.savefig(str(path))
    return path


def plot_histograms(table, stats: dict, directory) -> Path:
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    n = len(table.metrics)
    fig = _figure(4.2 * n, 3.4)
    for j, m in enumerate(table.metrics):
        ax = fig.add_subplot(1, n, j + 1)
        y = table.column(m)
        y = y[table.ok & np.isfinite(y)]
        if len(y):
            ax.hist(y, bins=min(40, max(5, len(y) // 8)), color="tab:blue", alpha=0.75)
        s = stats.get(m, {})
        for k, ls in (("p5", ":"), ("p50", "-"), ("p95", ":")):
            if s.get(k) is not None:
                ax.axvline(s[k], color="k", ls=ls, lw=1)
        ax.set_xlabel(m, fontsize=8)
        ax.set_ylabel("samples", fontsize=8)
        ax.set_title(f"median {s.get('p50', float('nan')):.4g}, 5–95 % "
                     f"[{s.get('p5', float('nan')):.4g}, {s.get('p95', float('nan')):.4g}]",
                     fontsize=8)
    fig.tight_layout()
    path = d / "histograms.png"
    fig.savefig(str(path))
    return path


def plot_envelope(t, median, p5, p95, channel: str, directory, title: str = "") -> Path:
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    fig = _figure(8.0, 3.8)
    ax = fig.add_subplot(1, 1, 1)
    ax.fill_between(t, p5, p95, color="tab:blue", alpha=0.3, lw=0, label="5–95 %")
    ax.plot(t, median, color="tab:blue", lw=1.2, label="median")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(channel)
    ax.grid(True, color="0.9")
    ax.legend(fontsize=8)
    ax.set_title(title or f"envelope of {channel}", fontsize=9)
    fig.tight_layout()
    path = d / f"envelope_{_safe(channel)}.png"
    fig.savefig(str(path))
    return path


def plot_sensitivity(result: dict, directory) -> Path:
    """Bars per metric: Sobol S1 and ST with confidence intervals, or Morris μ*."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    metrics = list(result["metrics"])
    n = len(metrics)
    fig = _figure(5.0 * n, 0.45 * len(result["unknowns"]) + 2.0)
    for j, m in enumerate(metrics):
        ax = fig.add_subplot(1, n, j + 1)
        rows = result["metrics"][m]["ranked"]
        names = [r["unknown"] for r in rows][::-1]
        yy = np.arange(len(names))
        if result["method"] == "sobol":
            st = [r["ST"] for r in rows][::-1]
            stc = [r["ST_conf"] for r in rows][::-1]
            s1 = [r["S1"] for r in rows][::-1]
            s1c = [r["S1_conf"] for r in rows][::-1]
            ax.barh(yy + 0.2, st, 0.4, xerr=stc, color="tab:orange", label="ST (total)")
            ax.barh(yy - 0.2, s1, 0.4, xerr=s1c, color="tab:blue", label="S1 (first order)")
            ax.set_xlabel("Sobol index", fontsize=8)
        else:
            mu = [r["mu_star"] for r in rows][::-1]
            muc = [r["mu_star_conf"] for r in rows][::-1]
            ax.barh(yy, mu, 0.6, xerr=muc, color="tab:blue", label="μ*")
            ax.set_xlabel(f"Morris μ* [{m} per unit quantile]", fontsize=8)
        ax.set_yticks(yy, names, fontsize=7)
        ax.set_title(m, fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, axis="x", color="0.9")
    fig.tight_layout()
    path = d / f"sensitivity_{result['method']}.png"
    fig.savefig(str(path))
    return path
