"""``flexarm calibrate``: fit scene values to a record (and/or features), with what the
data can and cannot determine. Exit 0 done, 2 bad input (one line: key, value,
expectation). Samples that diverge inside the bounds are penalized and reported, never a
crash."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

from flexarm_ros.errors import InputError
from flexarm_ros.io.arguments import OPEN_LOOP_HELP, SET_HELP, integer, number, set_option

_TARGET = re.compile(r"^(.+?)=([-+0-9.eE]+)(?:\+-|±)([-+0-9.eE]+)$")


def add_parsers(sub) -> None:
    c = sub.add_parser(
        "calibrate", help="fit scene values to a record or measured features: values, "
                          "standard errors, 95 %% intervals, what the data cannot determine")
    c.add_argument("scene", nargs="?", help="scene YAML path or shipped scene name")
    c.add_argument("record", nargs="?",
                   help="what `flexarm compare` reads: an experiment CSV, a `flexarm "
                        "simulate` CSV, a twin MCAP, a foreign MCAP with --map")
    c.add_argument("--param", action="append", metavar="KEY=LO:HI[@START]",
                   help="a scene key path to fit, its bounds and optionally its start "
                        "(default: the scene's value); repeatable")
    set_option(c, SET_HELP.split("; checked")[0] + "; checked by the scene's schema, "
                  "applied before the fit; not a --param key (that one is fitted); the spec "
                  "form: a case's set: instead; repeatable")
    c.add_argument("--spec", type=Path, metavar="SPEC.yaml",
                   help="the spec form: several (scene, record) cases sharing parameters, "
                        "feature targets with uncertainties (docs/calibration.md)")
    c.add_argument("--channels", metavar="CH[,CH]", action="append",
                   help="the record's channels to fit (default: every one the twin has)")
    c.add_argument("--sigma", action="append", metavar="CH=S",
                   help="noise (1σ) of a channel in its unit; with every channel's σ the "
                        "intervals take the noise as given, else from the residuals")
    c.add_argument("--target", action="append", metavar="METRIC=VALUE+-SIGMA",
                   help="a feature to meet, e.g. impact_time=2.10+-0.005, "
                        "frequency:acc_A_true@2.2:3.4=10.96+-0.2, value:tip_x@1.0=0.3+-1e-3, "
                        "mode:1=2.29+-0.05 (natural frequency, Hz)")
    c.add_argument("--window", metavar="A:B", help="fit the record only in A..B s")
    c.add_argument("--offset", default="none", metavar="none|auto|S",
                   help="the record's clock shift: none (default), auto (cross-correlation "
                        "at the start values, then held), or seconds")
    c.add_argument("--map", type=Path, metavar="MAP.yaml", help="channel map of the record")
    c.add_argument("--duration", type=number, help="simulated seconds (default: the scene's)")
    c.add_argument("--starts", type=integer, default=None,
                   help="fits from this many starts (the given one + a Sobol sample of the "
                        "box); the best wins (default 1)")
    c.add_argument("--seed", type=integer, default=None, help="seed of the extra starts")
    c.add_argument("--diff-step", type=number, default=None,
                   help="finite-difference step as a share of each range (default 1e-3)")
    c.add_argument("--max-evaluations", type=integer, default=None,
                   help="residual evaluations per start (default 30 (n + 1))")
    from flexarm_ros.ensemble.cli import executor_args
    executor_args(c, "the simulations")
    c.add_argument("--out", type=Path, metavar="calibrated.yaml",
                   help="the calibrated scene (spec form: a directory, one scene per case)")
    c.add_argument("--report", type=Path, metavar="DIR",
                   help="Markdown report with overlays before/after, cost history and "
                        "correlation map")
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.add_argument("--quiet", action="store_true", help="no progress on stderr")
    c.add_argument("--open-loop", action="store_true",
                   help=OPEN_LOOP_HELP + "; a twin bag is otherwise fitted with the twin's "
                        "loop (its control rate, efforts held), whatever the scene declares")
    c.set_defaults(func=cmd_calibrate)


def parse_target(text: str) -> dict:
    m = _TARGET.match((text or "").replace(" ", ""))
    if not m:
        raise InputError(f"--target: got {text!r}, expected METRIC=VALUE+-SIGMA (e.g. "
                         f"impact_time=2.10+-0.005)")
    return {"metric": m.group(1), "value": float(m.group(2)), "sigma": float(m.group(3))}


def _pairs(values, flag) -> dict:
    out = {}
    for v in values or ():
        if "=" not in v:
            raise InputError(f"{flag}: got {v!r}, expected CH=VALUE")
        k, x = v.split("=", 1)
        try:
            out[k.strip()] = float(x)
        except ValueError:
            raise InputError(f"{flag}: got {v!r}, expected CH=number") from None
    return out


def _problem(args):
    from flexarm_ros.calibration.fit import Problem
    from flexarm_ros.calibration.parameters import (check_distinct, parse_param,
                                                    start_assignment)
    from flexarm_ros.calibration.setup import load_spec, make_case
    from flexarm_ros.ensemble.keys import set_keys
    from flexarm_ros.scene import load_scene
    if args.spec is not None:
        extra = [f for f, v in (("SCENE", args.scene), ("--param", args.param),
                                ("--target", args.target), ("--channels", args.channels),
                                ("--set", args.set))
                 if v]
        if extra:
            raise InputError(f"--spec: got {extra[0]} too, expected the spec alone (it "
                             f"names the scenes, records, parameters and targets"
                             + ("; a case's set: changes its scene" if extra[0] == "--set"
                                else "") + ")")
        params, cases, opts = load_spec(args.spec)
        return Problem(params, cases), opts
    if not args.scene:
        raise InputError("calibrate: no scene, expected SCENE RECORD --param KEY=LO:HI or "
                         "--spec SPEC.yaml")
    if not args.param:
        raise InputError("--param: none given, expected at least one KEY=LO:HI")
    from flexarm_ros.scene.overrides import apply_sets, parse_sets
    sets = parse_sets(args.set)
    from flexarm_ros.scene.overrides import check_not_set
    check_not_set([str(t).partition("=")[0].strip() for t in args.param], sets)
    scene = apply_sets(load_scene(args.scene), sets)
    params = [parse_param(t, scene) for t in args.param]
    check_distinct(params)
    targets = [parse_target(t) for t in args.target or ()]
    if args.record is None and not targets:
        raise InputError("calibrate: no record and no --target, expected a RECORD (CSV or "
                         "MCAP) or feature targets")
    if args.record is not None and not Path(args.record).exists():
        raise InputError(f"RECORD: {args.record}: no such file, expected a CSV or MCAP "
                         f"record")
    channels = [n.strip() for v in args.channels or () for n in v.split(",") if n.strip()]
    start = start_assignment(params)
    from flexarm_ros.calibration.setup import system_of_record
    scene = system_of_record(scene, args.record, args.open_loop)
    probe = None
    if args.record is not None:
        from flexarm_ros.twin.batch import run_scene
        probe = run_scene(set_keys(scene, start), args.duration or scene.duration,
                          open_loop=args.open_loop)
    case = make_case(Path(str(args.scene)).stem, scene, args.record, args.map, channels,
                     _pairs(args.sigma, "--sigma"), None, args.window, args.offset,
                     args.duration, targets, probe, args.open_loop)
    from flexarm_ros.scene.loading import resolve_scene_path
    # a scene changed by --set is written out whole by --out (as a spec case's set:)
    case.scene_file = None if sets else str(resolve_scene_path(args.scene))
    return Problem(params, [case]), {}


def _check_outputs(args, spec: bool):
    from flexarm_ros.io.paths import check_output_dir, check_output_file
    if args.out is not None:
        if spec:
            check_output_dir("--out", args.out)
        else:
            check_output_file("--out", args.out, (".yaml", ".yml"))
    if args.report is not None:
        check_output_dir("--report", args.report)
    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers: got {args.workers}, expected an integer >= 0")


#: the most fits one calibration starts (each a least-squares fit of the whole record; a
#: Sobol sample of 1e9 starts was an 8 GiB allocation before the first fit)
MAX_STARTS = 10_000


def _option(args, opts, name, default, check):
    v = getattr(args, name)
    if v is None:
        v = opts.get(name, default)
    if v is not None and not check(v):
        raise InputError(f"--{name.replace('_', '-')}: got {v!r}, expected "
                         + {"starts": f"an integer from 1 to {MAX_STARTS}",
                            "seed": "an integer from 0 to 4294967295",
                            "diff_step": "a number in (0, 0.5)",
                            "max_evaluations": "an integer >= 1"}[name])
    return v


def _text(out: dict) -> str:
    lines = [f"calibrated {len(out['parameters'])} parameter(s) on "
             f"{out['residual_count']} residuals: cost {out['cost_before']:.6g} → "
             f"{out['cost_after']:.6g} ({out['evaluations']} simulations, "
             f"{out['wall_s']:.1f} s)"]
    for p in out["parameters"]:
        unit = f" {p['unit']}" if p["unit"] and p["unit"] != "1" else ""
        if p["identifiable"]:
            lo, hi = p["ci95"]
            lines.append(f"  {p['key']} = {p['value']:.6g}{unit} ± {p['stderr']:.3g} "
                         f"(95 %: {lo:.6g} .. {hi:.6g}; start {p['start']:.6g})"
                         + ("  [at a bound]" if p["at_bound"] else ""))
        else:
            lines.append(f"  {p['key']} = {p['value']:.6g}{unit}  not identifiable "
                         f"(start {p['start']:.6g})")
    for name, text in out.get("systems", {}).items():
        lines.append(f"  {name}: {text}")
    for u in out["unidentifiable"]:
        lines.append(f"  ! {u['text']}")
    for w in out["warnings"][:5]:
        lines.append(f"  warning: {w}")
    if len(out["warnings"]) > 5:
        lines.append(f"  ({len(out['warnings']) - 5} more warnings: --json)")
    return "\n".join(lines)


def public(out: dict) -> dict:
    return {k: v for k, v in out.items() if not k.startswith("_")}


def cmd_calibrate(args) -> int:
    from flexarm_ros.calibration.fit import calibrate
    from flexarm_ros.calibration.task import CaseTask
    from flexarm_ros.ensemble.runner import open_executor
    from flexarm_ros.ensemble.limits import SEED_MAX, check_seed, check_workers
    spec = args.spec is not None
    _check_outputs(args, spec)
    check_seed(args.seed)
    check_workers(args.workers)                 # within the cores and the memory
    problem, opts = _problem(args)
    starts = _option(args, opts, "starts", 1,
                     lambda v: isinstance(v, int) and 1 <= v <= MAX_STARTS)
    seed = _option(args, opts, "seed", 0,
                   lambda v: isinstance(v, int) and 0 <= v <= SEED_MAX)
    h = _option(args, opts, "diff_step", 1e-3,
                lambda v: isinstance(v, (int, float)) and 0 < v < 0.5)
    nmax = _option(args, opts, "max_evaluations", None,
                   lambda v: isinstance(v, int) and v >= 1)
    from flexarm_ros.io.progress import ProgressLine
    line = ProgressLine(78)
    log = None if args.quiet else (lambda s: line.show(f"  {s}"))
    ex = open_executor(args.workers, args.scheduler,
                       warm_up=CaseTask(problem.cases).warm_up, timeout_s=args.timeout)
    if not args.quiet:
        print(f"calibrate: {ex.description}"
              + (f"; dashboard {ex.dashboard}" if ex.dashboard else ""), file=sys.stderr)
    try:
        out = calibrate(problem, ex, starts=starts, seed=seed, diff_step=float(h),
                        max_evaluations=nmax, log=log)
    finally:
        ex.close()
        line.clear()
    if not spec:                                # the spec's cases carry their own set:
        from flexarm_ros.scene.overrides import parse_sets
        out["set"] = parse_sets(args.set)
    written = []
    if args.out is not None:
        from flexarm_ros.calibration.output import write_scenes
        written = write_scenes(problem, out, args.out, spec)
    if args.report is not None:
        from flexarm_ros.calibration.report import write_report
        written.append(write_report(problem, out, args.report))
    out["written"] = [str(p) for p in written]
    from flexarm_ros.calibration.setup import describe_system
    out["systems"] = {c.name: describe_system(c) for c in problem.cases}
    if args.json:
        print(json.dumps(_clean(public(out)), indent=1, default=_json_default))
    else:
        print(_text(out))
        if out.get("set"):
            from flexarm_ros.scene.overrides import format_sets
            print(f"  set: {format_sets(out['set'])}")
        for p in written:
            print(f"wrote {p}")
    return 0


def _clean(o):
    """Non-finite floats → None (JSON has no NaN), recursively."""
    import numpy as np
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(o) else None
    return o


def _json_default(o):
    import numpy as np
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
