"""``flexarm simulate``: a batch simulation without ROS, its summary line (or JSON) and
optionally its table (.csv or .npz) with the sensor tables beside it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from flexarm_ros.commands.common import (
    Progress, check_duration, fidelity_args, load, open_loop_arg, scene_arg, set_line,
    set_values, tolerance_status)
from flexarm_ros.io.arguments import number
from flexarm_ros.io.tables import sensor_table_path


def add_parser(sub) -> None:
    s = sub.add_parser("simulate", help="batch simulation without ROS")
    scene_arg(s)
    s.add_argument("--duration", type=number, help="simulated seconds (default: the scene's)")
    s.add_argument("--out", type=Path, help="output .csv or .npz")
    s.add_argument("--json", action="store_true", help="print the run summary as JSON")
    s.add_argument("--quiet", action="store_true",
                   help="no progress on stderr (the summary is still printed)")
    fidelity_args(s)
    s.add_argument("--estimate", action="store_true",
                   help="estimate the run's tip error as --rung auto does, for the named "
                        "rung (rk4; rung auto always does): a-priori analysis, then a check "
                        "with a finer model; 0.1-1 s more, up to a few s on a busy machine "
                        "(fidelity.estimate; docs/accuracy.md)")
    open_loop_arg(s)
    s.set_defaults(func=main)


def main(args):
    from flexarm_ros.twin.batch import run_scene
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.io.tables import write_table
    from flexarm_ros.io.units import table_units
    check_duration(args.duration)
    if args.out:
        check_output_file("--out", args.out, (".csv", ".npz"))
    scene = load(args)
    progress = Progress(scene.duration if args.duration is None else args.duration,
                        args.quiet or args.json)
    from flexarm_ros.io.progress import CompileNotice
    from flexarm_ros.sim import budget
    budget.FORECAST_STREAM = sys.stderr     # a run of over a minute says so, even --quiet
    from flexarm_ros.sim import truth
    truth.ANNOUNCE_STREAM = None if (args.quiet or args.json) else sys.stderr
    try:
        with CompileNotice(enabled=not args.quiet):
            res = run_scene(scene, args.duration, progress=progress.callback,
                            open_loop=args.open_loop)
    finally:
        budget.FORECAST_STREAM = None
        truth.ANNOUNCE_STREAM = None
        progress.clear()
    summ = res.summary()
    summ["set"] = set_values(args)
    if args.out:
        write_table(args.out, res.columns, table_units(res.columns, scene))
        summ["out"] = str(args.out)
        summ["sensor_tables"] = {}
        for rate, table in (res.sensor_tables or {}).items():
            path = sensor_table_path(args.out, rate)
            write_table(path, table, table_units(table, scene))
            summ["sensor_tables"][f"{rate:g}"] = str(path)
    if args.json:
        print(json.dumps(summ, indent=2))
    else:
        # the rod on fewer bending modes than its terms (fidelity.rod_modes)
        fewer = summ.get("rod_modes", summ["refine"]) != summ["refine"]
        print(f"{scene.name}: {summ['message']}; {summ['sim_time_s']:.3g} s simulated in "
              f"{summ['wall_time_s']:.3g} s (real-time factor {summ['real_time_factor']:.3g}, "
              f"rung {summ['rung']}"
              + (f" (lowest {summ['rod_modes']} modes of {summ['refine']} terms)"
                 if fewer else "")
              + f", {summ['integrator']}, {summ['steps']} steps, "
              f"{summ['rhs_evaluations']} RHS evaluations)"
              + (f" → {args.out}" if args.out else ""))
        if summ["set"]:
            print(set_line(summ["set"]))
        if summ.get("loop") == "closed":
            print(f"  closed loop: control.mode {summ['control_mode']} at "
                  f"{summ['control_rate_hz']:.6g} Hz, efforts held over each period, "
                  f"{summ['control_ticks']} ticks ({summ['lane']} lane; --open-loop: the "
                  f"input programs alone)")
            if summ.get("tool_error_m") is not None:
                e, g = summ["tool_end_m"], summ["tool_target_m"]
                print(f"  the tool ends at ({e[0]:.4g}, {e[1]:.4g}) m, "
                      f"{1e3 * summ['tool_error_m']:.3g} mm from its target "
                      f"({g[0]:.4g}, {g[1]:.4g}) m (columns tool_x, tool_y, tool_x_target, "
                      f"tool_y_target)")
        for rate, path in summ.get("sensor_tables", {}).items():
            print(f"  sensors at {rate} Hz → {path}")
        if summ.get("check"):
            _print_check(summ)
        if summ.get("auto"):
            modes = f" (lowest {summ['rod_modes']} modes)" if fewer else ""
            print(f"  rung auto: {summ['rung']} {summ['refine']}{modes}, "
                  f"{summ['integrator']} step {summ['step_s']:.3g} s, estimated tip error "
                  f"{summ['estimated_tip_error_m']:.2g} m for a tolerance of "
                  f"{summ['tolerance_m']:.2g} m (flexarm explain: why)")
        else:
            if summ.get("tolerance_m") and res.accuracy:   # the tolerance chose the step
                step_est = summ.get("step_estimate_m", res.accuracy.estimated_tip_error_m)
                above = (f" ({res.accuracy.above()})"
                         if res.accuracy.method == "pilot above the stable step" else "")
                default = (" (the default: the trapezoid's automatic step)"
                           if summ.get("tolerance_source") == "default" else "")
                print(f"  step {summ['step_s']:.4g} s{above} chosen for a tip tolerance of "
                      f"{summ['tolerance_m']:.2g} m{default}, its estimated temporal error "
                      f"{step_est:.2g} m")
            if summ.get("assessment"):
                print(f"  estimated tip error {summ['estimated_tip_error_m']:.2g} m "
                      f"({summ['estimate'].split(':')[0]}; --json: how)")
    status = tolerance_status(summ, args)
    if summ.get("warning") and not status:
        print(f"flexarm: warning: {summ['warning']}", file=sys.stderr)
    return status


def _print_check(summ) -> None:
    """The check against the top rung, in two lines."""
    chk = summ["check"]
    if chk["status"] != "ok":
        print(f"  not checked against the top rung: {chk['status']}")
        return
    est = chk["estimate"]
    share = max(est["deflection_share"], default=0.0)
    print(f"  checked against {chk['reference']} over the whole run ({chk['wall_s']:.2g} s): "
          f"tip position within {est['position_m']:.2g} m, tip deflection within "
          f"{max(est['deflection_m'], default=0.0):.2g} m ({100 * share:.3g} % of its peak)")
    for tried in summ.get("escalated") or ():
        print(f"    rung auto tried {tried['model']}: {tried['estimated_tip_error_m']:.2g} m "
              f"tip position, {tried['estimated_deflection_error_m']:.2g} m deflection")
    if summ.get("tolerance_met") is not None:
        print(f"  tolerance {summ['tolerance_m']:.2g} m ({summ['tolerance_metric']}): "
              + ("met" if summ["tolerance_met"] else "NOT met")
              + f", bound by the {summ['bound_by']}")
