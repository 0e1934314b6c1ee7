"""``flexarm sweep``, ``flexarm uncertainty`` and ``flexarm sensitivity``: ensembles on
the runner (:mod:`flexarm_ros.ensemble.runner`), local by default, a Dask cluster with
``--scheduler``. Exit 0 done (samples that diverged or were refused are rows of the
table, not failures), 2 bad input (one line: key, value, expectation)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.io.arguments import OPEN_LOOP_HELP, integer, number, set_option

SCENE_HELP = "scene YAML path or shipped scene name (default two_link_case1)"


def _check_duration(value):
    if value is not None and not (math.isfinite(value) and value > 0):
        raise InputError(f"--duration: got {value}, expected a finite number > 0 s")
    return value


def _load_scene(name):
    from flexarm_ros.scene import DEFAULT_SCENE, load_scene
    return load_scene(name or DEFAULT_SCENE)


def executor_args(p, what: str = "the samples"):
    g = p.add_argument_group(f"where {what} run (default: a local Dask cluster, one "
                             f"single-threaded worker process per core, on 127.0.0.1)")
    x = g.add_mutually_exclusive_group()
    x.add_argument("--workers", type=integer, metavar="N",
                   help="local worker processes (0: in this process, no Dask)")
    x.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://127.0.0.1:8786 (dask "
                        "scheduler + dask worker, or dask-jobqueue; docs/ensembles.md)")
    g.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the scheduler and its first worker (default "
                        "10)")


def _output_args(p, series=True):
    p.add_argument("--out", type=Path, metavar="TABLE",
                   help="the table: .csv (numbers read back to the same bits) or .parquet; "
                        "TABLE.meta.json says how it was made")
    if series:
        p.add_argument("--series", action="append", metavar="CHANNEL[,CHANNEL]",
                       help="also write these channels of every ok sample next to the table "
                            "(TABLE-stem.samples/sample_NNNNN.csv)")
    p.add_argument("--png", type=Path, metavar="DIR", help="write the figures here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar or dashboard address on stderr")


def add_parsers(sub) -> None:
    """Register the three commands on ``flexarm``'s subparsers (its parser calls this;
    nothing here imports the command-line module, which sits above every layer)."""
    s = sub.add_parser("sweep", help="a parameter sweep of a scene: one simulation per "
                                     "sample, a table of metrics")
    s.add_argument("scene", nargs="?", help=SCENE_HELP)
    s.add_argument("--param", action="append", metavar="KEY=LO:HI|KEY=v1,v2,...",
                   help="a scene key path (links[0].joint.drive.resistance, "
                        "tool.position[0]) and its range or values; repeatable")
    s.add_argument("--samples", type=integer, metavar="N",
                   help="grid: values per range (default 5); lhs, sobol, random: samples "
                        "(default 16; sobol: a power of two)")
    s.add_argument("--design", choices=("grid", "lhs", "sobol", "random"), default="grid")
    s.add_argument("--seed", type=integer, default=0, help="seed of lhs, sobol, random")
    s.add_argument("--metric", action="append", metavar="NAME",
                   help="impact_time, bounce_height, max_tip_deflection, "
                        "frequency:CHANNEL[@A:B], settling_time:CHANNEL, "
                        "final_error:CHANNEL[=TARGET] (no TARGET: the controller's), "
                        "energy_drift, wall_s_per_sim_s; "
                        "repeatable (impact_time is always in a wall scene's table)")
    s.add_argument("--duration", type=number, help="simulated seconds per sample")
    s.add_argument("--open-loop", action="store_true", help=OPEN_LOOP_HELP)
    set_option(s, "set a scene value of every sample (KEY=VALUE as --param's keys; "
                  "repeatable); the swept keys may not be set")
    executor_args(s)
    _output_args(s)
    s.set_defaults(func=cmd_sweep)

    u = sub.add_parser("uncertainty", help="Monte Carlo over a spec's uncertain keys: "
                                           "percentiles, histograms, envelope")
    u.add_argument("spec", type=Path, metavar="SPEC.yaml")
    u.add_argument("--samples", type=integer, help="Monte Carlo samples (default: the "
                                                   "spec's, else 256)")
    u.add_argument("--seed", type=integer, help="default: the spec's, else 0")
    u.add_argument("--design", choices=("random", "lhs"), default="random")
    u.add_argument("--channel", help="the envelope's channel (default: the spec's)")
    u.add_argument("--open-loop", action="store_true", help=OPEN_LOOP_HELP)
    executor_args(u)
    _output_args(u, series=False)
    u.set_defaults(func=cmd_uncertainty)

    e = sub.add_parser("sensitivity", help="Morris screening or Sobol indices of a spec's "
                                           "uncertain keys on each metric")
    e.add_argument("spec", type=Path, metavar="SPEC.yaml")
    e.add_argument("--method", choices=("morris", "sobol"), default="sobol")
    e.add_argument("--samples", type=integer, metavar="N",
                   help="morris: trajectories (default 8, N (d+1) runs); sobol: base "
                        "sample, a power of two (default 64, N (d+2) runs)")
    e.add_argument("--seed", type=integer)
    e.add_argument("--markdown", type=Path, metavar="FILE.md",
                   help="write the ranked tables as Markdown")
    e.add_argument("--open-loop", action="store_true", help=OPEN_LOOP_HELP)
    executor_args(e)
    _output_args(e, series=False)
    e.set_defaults(func=cmd_sensitivity)


# ------------------------------------------------------------------------------ shared
def _names(values):
    if not values:
        return []
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


def _check_out(args):
    from flexarm_ros.io.paths import check_output_dir, check_output_file
    if args.out:
        check_output_file("--out", args.out, (".csv", ".parquet"))
    if getattr(args, "series", None) and not args.out:
        raise InputError("--series: got channels without --out, expected --out TABLE (the "
                         "series are written next to it)")
    if args.png:
        check_output_dir("--png", args.png)
    if getattr(args, "markdown", None):
        check_output_file("--markdown", args.markdown, (".md",))
    from flexarm_ros.ensemble.limits import check_ensemble, check_timeout
    check_timeout(args.timeout)
    # --samples >= 1, --seed in [0, 2**32 - 1], --workers within the cores and memory,
    # before a scene is loaded or a channel probed (the memory of the runs: per command)
    check_ensemble(samples=args.samples, seed=args.seed, workers=args.workers)
    if args.scheduler is not None:
        from flexarm_ros.ensemble.limits import check_scheduler_address
        check_scheduler_address(args.scheduler)


def _check_runs(args, runs, scene, duration=None, channels: int = 0,
                flag: str = "--samples") -> None:
    """The memory of ``runs`` runs (and the time series of ``channels`` channels each)
    within the machine's (:mod:`flexarm_ros.ensemble.limits`), before any work."""
    from flexarm_ros.ensemble.limits import check_memory, run_bytes
    points = 0
    if channels:
        T = duration if duration is not None else scene.duration
        points = int(T / scene.fidelity.output_dt) + 1
    check_memory(runs, run_bytes(points, channels), flag,
                 args.samples if flag == "--samples" else None)


def check_channels(scene, metrics, series=(), duration=None, open_loop=False) -> None:
    """Every channel a metric or --series names exists in a run of the scene (a probe of
    a few output samples, run as the samples run), else InputError listing the channels."""
    from flexarm_ros.ensemble.metrics import channel
    from flexarm_ros.twin.batch import probe_duration, run_scene
    wanted = [m.channel for m in metrics if m.channel] + list(series) + [
        f"{m.channel}_target" for m in metrics if m.kind == "final_error" and m.target is None]
    if not wanted:
        return
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        res = run_scene(scene, probe_duration(scene, open_loop), open_loop=open_loop)
    for name in wanted:
        try:
            channel(res, name)
        except KeyError as exc:
            flag = "--series" if name in series else "--metric"
            raise InputError(f"{flag}: {exc.args[0]}") from None


def _executor(args, model):
    from flexarm_ros.ensemble.runner import open_executor
    ex = open_executor(args.workers, args.scheduler,
                       warm_up=getattr(model, "warm_up", None), timeout_s=args.timeout)
    if not args.quiet:
        print(f"ensemble: {ex.description}"
              + (f"; dashboard {ex.dashboard}" if ex.dashboard else ""), file=sys.stderr)
    return ex


def _table_text(table, limit=40) -> str:
    cols = table.columns[:-1]
    rows = table.rows

    def cell(v):
        if isinstance(v, float):
            return f"{v:.6g}"
        return str(v)
    cells = [[cell(r[c]) for c in cols] for r in rows[:limit]]
    w = [max(len(c), *(len(r[i]) for r in cells)) if cells else len(c)
         for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w[i]) for i, c in enumerate(cols))]
    for r, raw in zip(cells, rows):
        line = "  ".join(v.ljust(w[i]) for i, v in enumerate(r))
        if raw["status"] != "ok":
            line += "  " + raw["message"][:160]
        lines.append(line.rstrip())
    if len(rows) > limit:
        lines.append(f"... {len(rows) - limit} more rows (--out writes them all)")
    counts = table.counts()
    lines.append(", ".join(f"{v} {k}" for k, v in counts.items() if v) + " of "
                 f"{len(rows)} samples; {table.meta.get('executor')}, "
                 f"{table.meta.get('wall_s', 0):.3g} s")
    return "\n".join(lines)


def _outcome(command: str, table) -> int:
    """The exit status of an ensemble: 0 when a sample ran; when none did, one line on
    stderr with the counts and the first sample's reason, and 2 (every sample refused:
    its values), 3 (every sample diverged) or 1. A warning when every metric came out the
    same in every sample although the parameters varied: they had no effect on them."""
    counts = table.counts()
    rows = table.rows
    if counts["ok"] == 0 and rows:
        first = next((r["message"] for r in rows if r["message"]), "")
        print(f"flexarm {command}: no sample ran: "
              + ", ".join(f"{v} {k}" for k, v in counts.items() if v)
              + f" of {len(rows)}" + (f" (sample 0: {first})" if first else ""),
              file=sys.stderr)
        if counts["refused"] == len(rows):
            return 2
        return 3 if counts["diverged"] == len(rows) else 1
    ok = [r for r in rows if r["status"] == "ok"]
    cols = [c for c in table.metrics if c != "wall_s_per_sim_s"]
    if len(ok) > 1 and cols and table.params:
        varied = any(len({repr(r[p]) for r in ok}) > 1 for p in table.params)
        same = all(len({repr(r[c]) for r in ok}) == 1 for c in cols)
        if varied and same:
            print(f"flexarm {command}: warning: every metric ({', '.join(cols)}) is the "
                  f"same in all {len(ok)} samples: {', '.join(table.params)} had no effect "
                  f"on them in this scene", file=sys.stderr)
    return 0


def _write(args, table):
    if args.out:
        table.write(args.out)
        if not args.quiet:
            print(f"table → {args.out}" + (f", series → {table.series_dir(args.out)}"
                                           if table.series is not None else ""),
                  file=sys.stderr)


# ------------------------------------------------------------------------------ sweep
def cmd_sweep(args):
    from flexarm_ros.ensemble.designs import make_design, parse_param
    from flexarm_ros.ensemble.metrics import resolve_metrics
    from flexarm_ros.ensemble.runner import SceneModel, run_ensemble
    _check_duration(args.duration)
    _check_out(args)
    from flexarm_ros.scene.overrides import apply_sets, parse_sets
    sets = parse_sets(args.set)
    scene = apply_sets(_load_scene(args.scene), sets)
    if not args.param:
        raise InputError("--param: missing, expected at least one KEY=LO:HI or KEY=v1,v2,...")
    params = [parse_param(p, scene) for p in args.param]
    keys = [p.key for p in params]
    from flexarm_ros.scene.overrides import check_not_set
    check_not_set(keys, sets, "sweeps")
    if len(set(keys)) != len(keys):
        raise InputError(f"--param: got {keys}, expected each key once")
    series = _names(args.series)
    from flexarm_ros.ensemble.designs import design_runs
    _check_runs(args, design_runs(params, args.design, args.samples), scene, args.duration,
                len(series))
    assignments = make_design(params, args.design, args.samples, args.seed)
    metrics = resolve_metrics(_names(args.metric), scene, args.open_loop)
    check_channels(scene, metrics, series, args.duration, args.open_loop)
    model = SceneModel(scene, metrics, args.duration, series, args.open_loop)
    meta = {"kind": "sweep", "design": args.design, "seed": args.seed,
            "params": [p.__dict__ for p in params], "set": sets}
    with _executor(args, model) as ex:
        table = run_ensemble(scene, assignments, model=model, params=keys, executor=ex,
                             quiet=args.quiet or args.json, series=series, meta=meta,
                             duration=args.duration)
    _write(args, table)
    if args.png:
        from flexarm_ros.ensemble.plots import plot_sweep
        plot_sweep(table, args.png)
    if args.json:
        print(json.dumps(table.to_json(), indent=1))
    else:
        print(_table_text(table))
    return _outcome("sweep", table)


# ------------------------------------------------------------------------ uncertainty
def _spec(args):
    from flexarm_ros.ensemble.metrics import resolve_metrics
    from flexarm_ros.ensemble.spec import load_spec
    spec = load_spec(args.spec)
    base = spec.base_scene()
    metrics = resolve_metrics(spec.metrics, base, args.open_loop)
    return spec, base, metrics


def cmd_uncertainty(args):
    from flexarm_ros.ensemble.runner import SceneModel
    from flexarm_ros.ensemble.uq import run_uncertainty
    _check_out(args)
    spec, base, metrics = _spec(args)
    channel = args.channel or spec.channel
    _check_runs(args, spec.samples if args.samples is None else args.samples, base,
                spec.duration, 1 if channel else 0,
                "--samples" if args.samples is not None else f"{args.spec}: samples")
    check_channels(base, metrics, [channel] if channel else [], spec.duration,
                   args.open_loop)
    model = SceneModel(base, metrics, spec.duration, (channel,) if channel else (),
                       args.open_loop)
    with _executor(args, model) as ex:
        table, stats, env = run_uncertainty(spec, args.samples, args.seed, args.design,
                                            channel, model=model, executor=ex,
                                            quiet=args.quiet or args.json)
    table.series = None              # the channel served the envelope, written below
    _write(args, table)
    if args.out and env is not None:
        from flexarm_ros.io.tables import write_table
        from flexarm_ros.io.units import table_units
        t, med, p5, p95 = env
        path = Path(args.out).with_name(f"{Path(args.out).stem}.envelope_{channel}.csv")
        unit = table_units({channel: None}, base).get(channel)
        cols = {"t": t, f"{channel}_p5": p5, f"{channel}_p50": med, f"{channel}_p95": p95}
        write_table(path, cols, {"t": "s", **({k: unit for k in list(cols)[1:]}
                                             if unit else {})})
    if args.png:
        from flexarm_ros.ensemble.plots import plot_envelope, plot_histograms
        plot_histograms(table, stats, args.png)
        if env is not None:
            plot_envelope(*env, channel, args.png,
                          title=f"{base.name}: {channel}, median and 5–95 % of "
                                f"{int(table.ok.sum())} samples")
    if args.json:
        print(json.dumps({"statistics": stats, "counts": table.counts(),
                          "meta": table.public_meta}, indent=1, default=str))
    else:
        print(f"{base.name}: {len(table.rows)} Monte Carlo samples ("
              + ", ".join(f"{v} {k}" for k, v in table.counts().items() if v) + ")")
        for m, s in stats.items():
            if s["n"]:
                print(f"  {m}: mean {s['mean']:.6g}, std {s['std']:.3g}; 5/25/50/75/95 % "
                      + " / ".join(f"{s[f'p{p}']:.6g}" for p in (5, 25, 50, 75, 95))
                      + f" ({s['n']} values)")
            else:
                print(f"  {m}: no ok values")
    return _outcome("uncertainty", table)


# ------------------------------------------------------------------------ sensitivity
def cmd_sensitivity(args):
    from flexarm_ros.ensemble.runner import SceneModel
    from flexarm_ros.ensemble.uq import format_sensitivity, run_sensitivity
    _check_out(args)
    spec, base, metrics = _spec(args)
    from flexarm_ros.ensemble.uq import sensitivity_design, sensitivity_runs
    n = args.samples if args.samples is not None else (8 if args.method == "morris" else 64)
    _check_runs(args, sensitivity_runs(spec, args.method, n), base)
    sensitivity_design(spec, args.method, n, 0)   # checks the method's sample size first
    check_channels(base, metrics, (), spec.duration, args.open_loop)
    model = SceneModel(base, metrics, spec.duration, open_loop=args.open_loop)
    with _executor(args, model) as ex:
        result, table = run_sensitivity(spec, args.method, args.samples, args.seed,
                                        model=model, executor=ex,
                                        quiet=args.quiet or args.json)
    _write(args, table)
    result["scene"] = base.name
    result["duration_s"] = spec.duration or base.duration
    if args.png:
        from flexarm_ros.ensemble.plots import plot_sensitivity
        plot_sensitivity(result, args.png)
    if args.markdown:
        args.markdown.write_text(format_sensitivity(result, markdown=True))
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(format_sensitivity(result))
    return _outcome("sensitivity", table)
