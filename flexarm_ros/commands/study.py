"""``flexarm study``: the speed–accuracy table (and Pareto plot) of the fidelity ladder."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from flexarm_ros.commands.common import check_duration, load, open_loop_arg, scene_arg
from flexarm_ros.io.arguments import integer, number


def add_parser(sub) -> None:
    st = sub.add_parser("study", help="speed–accuracy table of the fidelity ladder")
    scene_arg(st)
    st.add_argument("--duration", type=number, help="simulated seconds per run")
    st.add_argument("--quick", action="store_true", help="a small ladder (CI)")
    st.add_argument("--budget", type=number, metavar="S",
                    help="wall-time budget of the study, s (default 240, --quick 60): the "
                         "window is fitted to it by forecasts, rows beyond it are left "
                         "out, a reference beyond it is refused up front")
    st.add_argument("--json", action="store_true")
    st.add_argument("--png", type=Path, help="write the Pareto plot here (.png, .pdf or "
                                             ".svg)")
    st.add_argument("--quiet", action="store_true",
                    help="no progress on stderr (the table is still printed)")
    # rung, refinement, integrator and tolerances are what the ladder varies: not options
    st.add_argument("--no-foreshortening", action="store_true",
                    help="drop the geometric-stiffening terms in every rung")
    open_loop_arg(st)
    st.add_argument("--workers", type=integer, metavar="N",
                    help="run the ladder rows on N local Dask worker processes (default 0: "
                         "in this process, one at a time, so that each row's wall time is "
                         "measured alone)")
    st.add_argument("--scheduler", metavar="ADDRESS",
                    help="run the ladder rows on an existing Dask cluster (docs/ensembles.md)")
    st.set_defaults(func=main)


def main(args):
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.studies.ladder import run_study, plot_pareto
    check_duration(args.duration)
    from flexarm_ros.ensemble.limits import check_workers
    check_workers(args.workers)                  # >= 0, within the cores and the memory
    if args.scheduler is not None:
        from flexarm_ros.ensemble.limits import check_scheduler_address
        check_scheduler_address(args.scheduler)
    if args.png:
        check_output_file("--png", args.png, (".png", ".pdf", ".svg"))
    from flexarm_ros.studies.ladder import DEFAULT_BUDGET_S, QUICK_BUDGET_S
    budget = args.budget
    if budget is None:
        budget = QUICK_BUDGET_S if args.quick else DEFAULT_BUDGET_S
    elif not (budget > 0 and budget < float("inf")):
        from flexarm_ros.errors import InputError
        raise InputError(f"--budget: got {budget}, expected a finite number > 0 s")
    scene = load(args)
    quiet = args.quiet or args.json
    from flexarm_ros.ensemble.runner import open_executor
    with open_executor(args.workers or 0, args.scheduler) as ex:   # rows as runner tasks
        rows = run_study(scene, duration=args.duration, quick=args.quick, executor=ex,
                         open_loop=args.open_loop, budget_s=budget,
                         progress=None if quiet else
                         (lambda text: print(f"  {text}", file=sys.stderr, flush=True)))
    if args.png:
        plot_pareto(rows, args.png, title=scene.name)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        from flexarm_ros.studies.ladder import format_table
        print(format_table(rows))
    meta = getattr(rows, "meta", {})
    if meta.get("warning"):
        print(f"flexarm: warning: {meta['warning']}", file=sys.stderr)
    if meta.get("skipped"):
        print(f"flexarm: {meta['skipped']} row(s) left out to keep the study within "
              f"{budget:g} s (their status says why; --budget S runs them)", file=sys.stderr)
    return 0
