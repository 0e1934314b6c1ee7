"""The ``flexarm`` command: simulate, modes, linearize, explain, study, run, replay, compare,
sweep, uncertainty, sensitivity (the ensembles: :mod:`flexarm_ros.ensemble.cli`).

``simulate``, ``modes``, ``linearize``, ``explain`` and ``study`` need no ROS; ``run`` and
``replay`` use ROS 2 (loopback-only discovery unless set, see
:mod:`flexarm_ros.nodes.environment`); ``compare`` reads bags and CSV files.

Every command that builds a model (simulate, modes, linearize, explain, run) takes the
fidelity overrides ``--rung``, ``--refine``, ``--integrator``, ``--rtol``, ``--atol``,
``--dt``, ``--no-foreshortening`` and ``--max-steps`` (the work budget,
:mod:`flexarm_ros.sim.budget`), and ``--set KEY=VALUE`` (any scene key path,
:mod:`flexarm_ros.scene.overrides`; applied before the fidelity flags, which win);
``study`` varies rung, refinement and integrator itself and takes only
``--no-foreshortening``. ``SCENE`` is a YAML path or the name of a shipped scene
(``flexarm simulate link_tipmass``); without it every command uses
:data:`flexarm_ros.scene.DEFAULT_SCENE` (``two_link_case1``). ``--quiet`` hides progress
(``t = simulated / total s`` on stderr, at most once a second), never the final summary
line.

Exit codes: 0 done, 1 failed (``run``: a node exited with an error; ``compare``: a check
failed; ``replay``: no subscriber in time), 2 bad input (one line on stderr naming the key,
the value and the expectation; arguments, scene, output paths and the work budget are
checked before the work starts), 3 the simulation diverged, 130 interrupted.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import sys
from pathlib import Path

import numpy as np

from flexarm_ros.io.arguments import integer, number, set_option
from flexarm_ros.nodes import environment
from flexarm_ros.scene import DEFAULT_SCENE

SCENE_HELP = f"scene YAML path or shipped scene name (default {DEFAULT_SCENE})"


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (exit 2), like every other bad input."""

    def error(self, message):
        # argparse's "(choose from 'a', 'b')" in the words of every other bad input
        message = message.replace("(choose from ", "(expected one of ")
        if "expected" not in message:
            message += f" (expected the usage that {self.prog} --help shows)"
        self.exit(2, f"{self.prog}: error: {message}\n")


def _fail(text):
    from flexarm_ros.errors import InputError
    raise InputError(text)


def check_duration(value, allow_inf=False):
    """``--duration``: None (the scene's) or a number > 0 s, finite unless ``allow_inf``
    (``run``: inf = until Ctrl-C)."""
    if value is None:
        return None
    if math.isnan(value) or not value > 0 or (math.isinf(value) and not allow_inf):
        _fail(f"--duration: got {value}, expected a "
              + ("number > 0 s (inf: until Ctrl-C)" if allow_inf else
                 "finite number > 0 s"))
    return value


def _scene_arg(p):
    p.add_argument("scene", nargs="?", help=SCENE_HELP)


def _open_loop_arg(p):
    from flexarm_ros.io.arguments import OPEN_LOOP_HELP
    p.add_argument("--open-loop", action="store_true", help=OPEN_LOOP_HELP)


def _fidelity_args(p):
    """The fidelity overrides, and ``--set KEY=VALUE`` (every command that takes them
    builds a model from the scene)."""
    from flexarm_ros.scene import INTEGRATORS, RUNG_CHOICES
    set_option(p.add_argument_group("scene overrides"))
    g = p.add_argument_group("fidelity overrides (default: the scene's)")
    g.add_argument("--rung", choices=RUNG_CHOICES,
                   help="beam discretization rung; auto: the cheapest rung, refinement and "
                        "RK4 step estimated to meet --tolerance (default 1e-5 m tip)")
    g.add_argument("--refine", type=integer,
                   help="modes / elements / FD segments (0: the rung's default)")
    g.add_argument("--integrator", choices=INTEGRATORS, help="time integrator")
    g.add_argument("--rtol", type=number, help="relative tolerance (adaptive integrators)")
    g.add_argument("--atol", type=number, help="absolute tolerance (adaptive integrators)")
    g.add_argument("--dt", type=number, help="fixed step (rk4) or max step, s; 0 = automatic")
    g.add_argument("--tolerance", type=number, metavar="M",
                   help="tip-position error bound, m: with --rung auto the model and step "
                        "are chosen for it; with a named rung the step (simulate): rk4's "
                        "(the contact stepper's with a wall) or the trapezoid's; 0: none "
                        "(the automatic step; rung auto's default 1e-5 m), e.g. to clear a "
                        "scene's fidelity.tolerance")
    g.add_argument("--tolerance-metric", choices=("position", "deflection", "both"),
                   help="what --tolerance bounds: the tip position in the world frame, "
                        "the elastic tip deflection of every link in its hub frame, or both "
                        "(default); checked against the geometrically exact rung over the "
                        "whole run (docs/accuracy.md)")
    g.add_argument("--no-foreshortening", action="store_true",
                   help="drop the geometric-stiffening (foreshortening) terms")
    g.add_argument("--max-steps", type=number, metavar="N",
                   help="work budget: refuse a run needing more integrator steps "
                        "(fidelity.max_steps, default 1e8)")


def _overrides(args) -> dict:
    """The fidelity options given → ``Scene.with_fidelity`` keywords (None: not given)."""
    over = {k: getattr(args, k, None) for k in
            ("rung", "refine", "integrator", "rtol", "atol", "dt", "max_steps",
             "tolerance", "tolerance_metric")}
    if getattr(args, "no_foreshortening", False):
        over["foreshortening"] = False
    if getattr(args, "estimate", False):
        over["estimate"] = True
    return over


def _sets(args) -> dict:
    """The ``--set KEY=VALUE`` options → ``{key: value}`` (InputError: one line)."""
    from flexarm_ros.scene.overrides import parse_sets
    return parse_sets(getattr(args, "set", None))


def _load(args):
    """The scene with the ``--set`` values, then the fidelity flags (an explicit flag
    wins over a ``--set fidelity.…``)."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.scene.overrides import apply_sets
    return apply_sets(load_scene(args.scene or DEFAULT_SCENE), _sets(args)).with_fidelity(
        **_overrides(args))


def _set_line(sets: dict) -> str | None:
    """The text summaries' ``  set: KEY=VALUE, ...`` line (None: nothing set)."""
    from flexarm_ros.scene.overrides import format_sets
    return f"  set: {format_sets(sets)}" if sets else None


class _Progress:
    """The progress line on stderr (simulated time / total), at most once per wall second
    (the integrators call it), cleared at the end; nothing with ``quiet``
    (:class:`~flexarm_ros.io.progress.ProgressLine`)."""

    WIDTH = 48

    def __init__(self, total_s, quiet):
        from flexarm_ros.io.progress import ProgressLine
        self.total = total_s
        self.quiet = quiet
        self.line = ProgressLine(self.WIDTH)

    @property
    def callback(self):
        return None if self.quiet else self

    def __call__(self, frac):
        self.line.show(f"  t = {frac * self.total:.4g} / {self.total:.4g} s "
                       f"({100 * frac:5.1f} %)")

    def clear(self):
        """Blank the progress line, if one was drawn."""
        if not self.quiet:
            self.line.clear()


def cmd_simulate(args):
    from flexarm_ros.twin.batch import run_scene
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.io.tables import write_table
    from flexarm_ros.io.units import table_units
    check_duration(args.duration)
    if args.out:
        check_output_file("--out", args.out, (".csv", ".npz"))
    scene = _load(args)
    progress = _Progress(scene.duration if args.duration is None else args.duration,
                         args.quiet or args.json)
    from flexarm_ros.io.progress import CompileNotice
    try:
        with CompileNotice(enabled=not args.quiet):
            res = run_scene(scene, args.duration, progress=progress.callback,
                            open_loop=args.open_loop)
    finally:
        progress.clear()
    summ = res.summary()
    summ["set"] = _sets(args)
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
        print(f"{scene.name}: {summ['message']}; {summ['sim_time_s']:.3g} s simulated in "
              f"{summ['wall_time_s']:.3g} s (real-time factor {summ['real_time_factor']:.3g}, "
              f"rung {summ['rung']}, {summ['integrator']}, {summ['steps']} steps, "
              f"{summ['rhs_evaluations']} RHS evaluations)"
              + (f" → {args.out}" if args.out else ""))
        if summ["set"]:
            print(_set_line(summ["set"]))
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
            print(f"  rung auto: {summ['rung']} {summ['refine']}, {summ['integrator']} step "
                  f"{summ['step_s']:.3g} s, estimated tip error "
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
    if summ.get("warning"):
        print(f"flexarm: warning: {summ['warning']}", file=sys.stderr)
    return 0


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


def sensor_table_path(out, rate_hz) -> Path:
    """``run.csv`` → ``run.sensors_4000hz.csv``: one table per sensor sample rate."""
    out = Path(out)
    return out.with_name(f"{out.stem}.sensors_{rate_hz:g}hz{out.suffix}")


def cmd_modes(args):
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.linear import natural_modes
    from flexarm_ros.model.statics import initial_state
    if args.count < 1:
        _fail(f"--count: got {args.count}, expected an integer >= 1 (modes to print)")
    scene = _load(args)
    chain = Chain(scene)
    q0 = initial_state(chain)[0]
    joints = args.joints or ("locked" if scene.inputs else "free")
    m = natural_modes(chain, q0, joints)
    n = min(args.count, len(m.frequencies_hz))
    out = {"scene": scene.name, "rung": chain.fidelity.rung, "joints": joints,
           "coordinates": list(m.coordinates),
           "frequencies_hz": [float(f) for f in m.frequencies_hz[:n]],
           "mode_shapes": [[float(v) for v in m.shapes[:, k]] for k in range(n)],
           "set": _sets(args)}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{scene.name}: rung {out['rung']}, joints {joints}")
        if out["set"]:
            print(_set_line(out["set"]))
        for k, f in enumerate(out["frequencies_hz"], 1):
            print(f"  mode {k:2d}: {f:12.5f} Hz")
    return 0


LINEARIZE_EPILOG = """\
units: --json and --out give state_units, input_units and output_units aligned with
states, inputs and outputs (rad, m, rad/s, m/s, A, Pa for the state; N·m, V or A per input;
rad, m, counts, m/s², m/m for the outputs).

controllability: do not take the rank of the controllability matrix [B, AB, ...]: for a
flexible model its condition number is 1e20 or more and its computed rank is meaningless.
"controllable" in --json is the PBH test instead: rank [A - λI, B] = n at every eigenvalue
λ of the balanced A, a mode failing when σ_min/σ_max of that matrix is below tol = 1e-14;
"controllability" gives tol, the eigenvalues that fail and the smallest margin. A margin
near tol is at the limit of double precision, where a controllability Gramian or a
balanced realization grades the answer (flexarm_ros.model.controllability)."""


def cmd_linearize(args):
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.controllability import pbh_test
    from flexarm_ros.model.statespace import linearize
    from flexarm_ros.io.paths import check_output_file
    if args.out:
        check_output_file("--out", args.out, (".npz",))
    scene = _load(args)
    ss = linearize(Chain(scene))
    pbh = pbh_test(ss.A, ss.B)
    if args.out:
        out = Path(args.out)
        np.savez(out, A=ss.A, B=ss.B, C=ss.C, D=ss.D, x0=ss.x0,
                 states=np.array(ss.states), inputs=np.array(ss.inputs),
                 outputs=np.array(ss.outputs), state_units=np.array(ss.state_units),
                 input_units=np.array(ss.input_units),
                 output_units=np.array(ss.output_units))
    if args.json:
        print(json.dumps({**ss.as_dict(), "controllable": pbh.controllable,
                          "controllability": pbh.as_dict(), "set": _sets(args)}, indent=1))
    else:
        eig = np.linalg.eigvals(ss.A)
        osc = np.sort(np.abs(eig[eig.imag > 0].imag)) / (2 * np.pi)

        def named(names, units):
            return ", ".join(f"{n} [{u}]" for n, u in zip(names, units)) or "none"
        print(f"{scene.name}: {len(ss.states)} states, {len(ss.inputs)} inputs, "
              f"{len(ss.outputs)} outputs" + (f" → {args.out}" if args.out else ""))
        if _sets(args):
            print(_set_line(_sets(args)))
        print("  states: " + named(ss.states, ss.state_units))
        print("  inputs: " + named(ss.inputs, ss.input_units))
        print("  outputs: " + named(ss.outputs, ss.output_units))
        print("  oscillatory eigenvalues (Hz): " + ", ".join(f"{f:.4g}" for f in osc[:10]))
        print(f"  controllable (PBH, tol {pbh.tol:g}): "
              + ("yes" if pbh.controllable else
                 f"no, {len(pbh.uncontrollable)} of {len(ss.states)} eigenvalues fail")
              + (f"; smallest margin {pbh.margins.min():.2g}" if pbh.margins.size else ""))
    return 0


def cmd_explain(args):
    from flexarm_ros.model.explain import explain
    scene = _load(args)
    chain = None
    if scene.fidelity.tolerance and scene.fidelity.rung != "auto":
        # what simulate would refuse is refused here too, before the choice is described
        from flexarm_ros.model.chain import Chain
        from flexarm_ros.model.contact import build_contact
        from flexarm_ros.sim.simulate import check_tolerance_applies
        chain = Chain(scene)
        check_tolerance_applies(chain, build_contact(chain) if scene.walls else None)
    print(explain(scene, chain))
    if _sets(args):
        print(_set_line(_sets(args)).strip())
    return 0


def cmd_study(args):
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.studies.ladder import run_study, plot_pareto
    check_duration(args.duration)
    if args.png:
        check_output_file("--png", args.png, (".png", ".pdf", ".svg"))
    scene = _load(args)
    quiet = args.quiet or args.json
    from flexarm_ros.ensemble.runner import open_executor
    if args.workers is not None and args.workers < 0:
        _fail(f"--workers: got {args.workers}, expected an integer >= 0 (0: in this process)")
    with open_executor(args.workers or 0, args.scheduler) as ex:   # rows as runner tasks
        rows = run_study(scene, duration=args.duration, quick=args.quick, executor=ex,
                         open_loop=args.open_loop,
                         progress=None if quiet else
                         (lambda text: print(f"  {text}", file=sys.stderr, flush=True)))
    if args.png:
        plot_pareto(rows, args.png, title=scene.name)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        from flexarm_ros.studies.ladder import format_table
        print(format_table(rows))
    return 0


def _names(values) -> list | None:
    """Repeatable and comma-separated option values as one list (None: not given)."""
    if values is None:
        return None
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


def _say_domain() -> None:
    """On stderr: the ROS domain of the run and how a user's own node joins it (the run
    picks a private domain unless ROS_DOMAIN_ID is set, so a node started in another
    terminal would not see the twin)."""
    import os

    from flexarm_ros.nodes import environment
    mine = environment.DOMAIN not in os.environ
    env = environment.private_graph()
    d = env[environment.DOMAIN]
    print(f"flexarm run: ROS domain {d}" + (
        f" (chosen for this run; start your own nodes with ROS_DOMAIN_ID={d} "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, or set ROS_DOMAIN_ID before flexarm run)"
        if mine else " (from ROS_DOMAIN_ID)"), file=sys.stderr)


def _check_pacing_flags(args) -> None:
    """The pacing flags (--late-bound, --ground-truth-rate, --thread-priority,
    --start-timeout) checked before the graph starts, with the
    flags' names (the simulator node checks the same values as its parameters)."""
    from flexarm_ros.errors import InputError
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin.pacing import THREAD_PRIORITY, check_settings
    from flexarm_ros.scene.overrides import apply_sets
    period = 1.0 / apply_sets(load_scene(args.scene or DEFAULT_SCENE),
                              _sets(args)).twin_control.rate_hz
    try:
        check_settings(period, args.late_policy or "slow",
                       0.1 if args.late_bound is None else args.late_bound,
                       0.0 if args.ground_truth_rate is None else args.ground_truth_rate,
                       THREAD_PRIORITY if args.thread_priority is None else
                       args.thread_priority,
                       0.0 if args.start_timeout is None else args.start_timeout)
    except InputError as exc:
        raise InputError(str(exc).replace("parameter late_bound", "--late-bound").replace(
            "parameter ground_truth_rate_hz", "--ground-truth-rate").replace(
            "parameter thread_priority", "--thread-priority").replace(
            "parameter start_timeout_s", "--start-timeout")) from None


def cmd_run(args):
    """The ROS 2 graph (simulator, motor driver, controller, recorder); see flexarm_ros.run."""
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.run import run
    check_duration(args.duration, allow_inf=True)
    sets = _sets(args)
    if args.tolerance is not None:
        from flexarm_ros.errors import InputError
        raise InputError(f"--tolerance: got {args.tolerance:g} m, expected it with flexarm "
                         f"simulate (the twin's plant steps within its control tick with "
                         f"the held efforts, which the step-halving pilots cannot "
                         f"replay; set --dt)")
    if (args.late_bound is not None or args.ground_truth_rate is not None
            or args.thread_priority is not None or args.start_timeout is not None):
        _check_pacing_flags(args)
    if args.marker_rate is not None and not (math.isfinite(args.marker_rate)
                                             and args.marker_rate >= 0):
        from flexarm_ros.errors import InputError
        raise InputError(f"--marker-rate: got {args.marker_rate:g}, expected a finite rate "
                         f"≥ 0 Hz (0: no arm_markers)")
    from flexarm_ros.nodes.names import check_namespace
    namespace = check_namespace("--namespace", args.namespace)
    record = None if args.no_record else args.record
    if record is not None:
        check_output_file("--record", record, (".mcap",))   # what replay/compare read
    if args.rerun:
        check_output_file("--rerun", args.rerun, (".rrd",))
    from flexarm_ros.run import select_nodes
    try:
        nodes = select_nodes(_names(args.nodes), _names(args.without))
    except ValueError as exc:
        from flexarm_ros.errors import InputError
        raise InputError(f"{'--nodes' if args.nodes else '--without'}: {exc}") from None
    if "recorder" not in nodes:
        record = None
    if set(nodes) != set(select_nodes()) and not args.quiet:
        _say_domain()                 # the user's own nodes must join this domain
    if args.processes and args.layout not in (None, "processes"):
        from flexarm_ros.errors import InputError
        raise InputError(f"--processes and --layout {args.layout}: choose one layout")
    kw = dict(duration=args.duration, mode=args.mode, processes=args.processes, pin=args.pin,
              layout="processes" if args.processes else args.layout,
              nodes=tuple(n for n in nodes if n != "recorder"),
              namespace=namespace, progress=not args.quiet,
              fidelity={k: v for k, v in _overrides(args).items()
                        if k not in ("tolerance", "tolerance_metric")},
              sets=sets,
              simulator={"late_policy": args.late_policy, "late_bound": args.late_bound,
                         "ground_truth_rate_hz": args.ground_truth_rate,
                         "thread_priority": args.thread_priority,
                         "start_timeout_s": args.start_timeout,
                         "marker_rate_hz": args.marker_rate})
    if args.rerun or args.rerun_spawn:            # convert the run's bag afterwards
        from flexarm_ros.run import run_with_view
        from flexarm_ros.viz.rerun_view import RerunUnavailable
        try:
            res, view = run_with_view(args.rerun, args.rerun_spawn, record,
                                      scene=args.scene or DEFAULT_SCENE, **kw)
        except RerunUnavailable as exc:
            print(f"flexarm run: error: {exc}", file=sys.stderr)
            return 2
        print(res.summary())
        print(f"rerun: {view.text()}" + (" (viewer spawned)" if args.rerun_spawn else ""))
    else:
        res = run(args.scene or DEFAULT_SCENE, record=record, **kw)
        if args.json:
            import json
            print(json.dumps(res.to_json(), indent=2))
        else:
            print(res.summary())
    if res.diverged or res.stalled:           # like simulate: the message once, status 3
        if not res.processes and res.layout != "split":     # else the node said it
            print(f"flexarm: {res.diverged or res.stalled}", file=sys.stderr)
        return 3
    bad = {k: v for k, v in res.returncodes.items() if v not in (0, None)}
    if bad:
        print(f"flexarm run: nodes exited with {bad}", file=sys.stderr)
        return 1
    return 0


def cmd_replay(args):
    """Publish a bag on ROS 2 with /clock, and/or convert it to rerun; see flexarm_ros.replay."""
    from flexarm_ros.replay import command
    return command(args)


def cmd_compare(args):
    """Twin run vs reference (docs/compare.md): 0 pass, 1 fail, 2 bad input."""
    from flexarm_ros.analysis.compare_cli import run_cli
    return run_cli(args)


def cmd_bag_repair(args):
    """A damaged or unfinished bag rewritten complete; see flexarm_ros.bag.repair."""
    from flexarm_ros.bag.repair import cli
    return cli(args)


def cmd_bag_export(args):
    """A twin bag's channels as name [unit] CSV tables; see flexarm_ros.analysis.export."""
    from flexarm_ros.analysis.export import cli
    return cli(args)


def _bag_parser(sub):
    b = sub.add_parser("bag", help="bag tools (repair, export)")
    bsub = b.add_subparsers(dest="bag_command", required=True, metavar="{repair,export}")
    br = bsub.add_parser("repair", help="rewrite what is readable of a damaged or unfinished "
                                        "MCAP bag (killed recorder, corrupt chunks) into a "
                                        "complete file")
    br.add_argument("bag", type=Path, metavar="IN.mcap", help="the damaged bag (kept as is)")
    br.add_argument("--out", type=Path, metavar="OUT.mcap",
                    help="the complete bag to write (default: IN.repaired.mcap)")
    br.add_argument("--json", action="store_true", help="print the report as JSON")
    br.set_defaults(func=cmd_bag_repair)
    be = bsub.add_parser("export", help="write a twin bag's channels as 'name [unit]' CSV "
                                        "tables (what flexarm compare and calibrate read)")
    be.add_argument("bag", type=Path, metavar="BAG.mcap", help="a bag of flexarm run --record")
    be.add_argument("--out", type=Path, metavar="run.csv", required=True,
                    help="the main table (control ticks); batch sensors go to "
                         "run.sensors_<rate>hz.csv beside it")
    be.add_argument("--topics", nargs="+", metavar="TOPIC",
                    help="only the channels of these topics (absolute, or relative to the "
                         "bag's namespace; spaces or commas)")
    be.add_argument("--json", action="store_true", help="print what was written as JSON")
    be.set_defaults(func=cmd_bag_export)


def build_parser():
    p = _Parser(prog="flexarm", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="batch simulation without ROS")
    _scene_arg(s)
    s.add_argument("--duration", type=number, help="simulated seconds (default: the scene's)")
    s.add_argument("--out", type=Path, help="output .csv or .npz")
    s.add_argument("--json", action="store_true", help="print the run summary as JSON")
    s.add_argument("--quiet", action="store_true",
                   help="no progress on stderr (the summary is still printed)")
    _fidelity_args(s)
    s.add_argument("--estimate", action="store_true",
                   help="estimate the run's tip error as --rung auto does, for the named "
                        "rung (rk4; rung auto always does): a-priori analysis, then a check "
                        "with a finer model; 0.1-1 s more, up to a few s on a busy machine "
                        "(fidelity.estimate; docs/accuracy.md)")
    _open_loop_arg(s)
    s.set_defaults(func=cmd_simulate)

    m = sub.add_parser("modes", help="natural frequencies of the linearized chain")
    _scene_arg(m)
    m.add_argument("--joints", choices=("locked", "free"),
                   help="drives clamped or free (default: locked when the scene drives a "
                        "joint, else free)")
    m.add_argument("--count", type=integer, default=10, help="number of modes to print (>= 1)")
    m.add_argument("--json", action="store_true")
    _fidelity_args(m)
    m.set_defaults(func=cmd_modes)

    li = sub.add_parser("linearize", help="state-space model (A, B, C, D) about the initial "
                                          "state", epilog=LINEARIZE_EPILOG,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    _scene_arg(li)
    li.add_argument("--out", type=Path, help="write A, B, C, D, x0, names and units to this "
                                             ".npz")
    li.add_argument("--json", action="store_true",
                    help="print A, B, C, D, x0, states, inputs, outputs, their units and the "
                         "PBH controllability as JSON")
    _fidelity_args(li)
    li.set_defaults(func=cmd_linearize)

    e = sub.add_parser("explain", help="print the model built from the scene")
    _scene_arg(e)
    _fidelity_args(e)
    e.set_defaults(func=cmd_explain)

    st = sub.add_parser("study", help="speed–accuracy table of the fidelity ladder")
    _scene_arg(st)
    st.add_argument("--duration", type=number, help="simulated seconds per run")
    st.add_argument("--quick", action="store_true", help="a small ladder (CI)")
    st.add_argument("--json", action="store_true")
    st.add_argument("--png", type=Path, help="write the Pareto plot here (.png, .pdf or "
                                             ".svg)")
    st.add_argument("--quiet", action="store_true",
                    help="no progress on stderr (the table is still printed)")
    # rung, refinement, integrator and tolerances are what the ladder varies: not options
    st.add_argument("--no-foreshortening", action="store_true",
                    help="drop the geometric-stiffening terms in every rung")
    _open_loop_arg(st)
    st.add_argument("--workers", type=integer, metavar="N",
                    help="run the ladder rows on N local Dask worker processes (default 0: "
                         "in this process, one at a time, so that each row's wall time is "
                         "measured alone)")
    st.add_argument("--scheduler", metavar="ADDRESS",
                    help="run the ladder rows on an existing Dask cluster (docs/ensembles.md)")
    st.set_defaults(func=cmd_study)
    r = sub.add_parser("run", help="the ROS 2 twin: simulator, motor driver, controller and "
                                    "recorder nodes")
    _scene_arg(r)
    r.add_argument("--duration", type=number,
                   help="simulated seconds (default: the scene's; inf: until Ctrl-C); Ctrl-C "
                        "stops earlier")
    r.add_argument("--mode", choices=("lockstep", "realtime", "fast"), default="lockstep",
                   help="lockstep: message-driven, deterministic, equal to the batch "
                        "co-simulation (default); realtime: paced by the wall clock; fast: "
                        "free-running with /clock")
    r.add_argument("--record", type=Path, default=Path("run.mcap"), metavar="FILE.mcap",
                   help="rosbag2-compatible MCAP of every topic, log time = simulation time, "
                        "finalized on Ctrl-C too (default: run.mcap)")
    r.add_argument("--no-record", action="store_true", help="run without the recorder")
    r.add_argument("--processes", action="store_true",
                   help="one process per node (--layout processes)")
    r.add_argument("--layout", choices=("one", "split", "processes"), default=None,
                   help="one: every node in this process; split: the simulator in a "
                        "process of its own, the other nodes in this one, joined by a "
                        "socket (the plant's tick on one core, the rest on the other); "
                        "processes: one per node (default: one)")
    r.add_argument("--pin", action=argparse.BooleanOptionalAction, default=None,
                   help="with --processes or --layout split: the simulator alone on the "
                        "last CPU, the other nodes on the rest (default: on in realtime, off "
                        "otherwise)")
    r.add_argument("--namespace", default="/flexarm", help="node namespace (default /flexarm)")
    r.add_argument("--quiet", action="store_true",
                   help="no progress and no node info log on stderr (the summary is still "
                        "printed; warnings and errors too)")
    r.add_argument("--without", action="append", metavar="NODE",
                   help="leave out a node of the twin (controller, motor_driver or recorder;"
                        " repeatable or comma-separated) to put your own in its place: the "
                        "topic contract is docs/topic_contract.md")
    r.add_argument("--nodes", action="append", metavar="NODE,...",
                   help="the twin's nodes to start (default simulator,motor_driver,"
                        "controller,recorder)")
    r.add_argument("--json", action="store_true",
                   help="print the run summary as JSON (real_time_factor, ticks, "
                        "late_ticks, lateness_p50_s/p99_s/max_s, messages recorded per "
                        "topic, rejected commands, ...)")
    r.add_argument("--late-policy", choices=("skip", "slow"),
                   help="realtime, when a tick is later than --late-bound: skip = keep the "
                        "wall clock (the due ticks are stepped with the held effort, only "
                        "the last is published); slow = publish every tick and fall behind "
                        "the wall clock (default: slow)")
    r.add_argument("--late-bound", type=number, metavar="S",
                   help="realtime: seconds of lateness before --late-policy acts "
                        "(default 0.1)")
    r.add_argument("--thread-priority", type=int, metavar="N",
                   help="realtime only (lockstep and fast ignore it): SCHED_FIFO priority "
                        "of the simulator's pacing thread (1..99; default 0, normal "
                        "scheduling: under FIFO the plant takes the CPU from a "
                        "controller of yours on the same host). "
                        "Where the kernel refuses it the run goes on at normal priority "
                        "and says so")
    r.add_argument("--start-timeout", type=number, metavar="S",
                   help="end the run as stalled (exit 3) when the twin has not started "
                        "after S seconds — its driver, in lockstep a controller on "
                        "joint_states, the recorder — naming what it waited for (default "
                        "0: wait for ever, as a bench waits for its controller)")
    r.add_argument("--ground-truth-rate", type=number, metavar="HZ",
                   help="rate of ground_truth/tip and ground_truth/coordinates (default: "
                        "every control tick; 100 Hz in realtime; 0: every tick)")
    r.add_argument("--marker-rate", type=number, metavar="HZ",
                   help="rate of arm_markers, the deformed arm for RViz2 and Foxglove "
                        "(visualization_msgs/MarkerArray, in simulation time; default 30; "
                        "0: none; see docs/viewing.md)")
    r.add_argument("--rerun", type=Path, metavar="FILE.rrd",
                   help="after the run, convert its bag to this rerun recording (needs "
                        "rerun-sdk: pip install -e .[viz]; see docs/viewing.md)")
    r.add_argument("--rerun-spawn", action="store_true",
                   help="after the run, show its bag in a spawned rerun viewer (needs a "
                        "display)")
    _fidelity_args(r)
    r.set_defaults(func=cmd_run)

    rp = sub.add_parser("replay", help="publish a recorded bag on ROS 2 with /clock (no "
                                       "rosbag2 needed) and/or convert it to rerun")
    rp.add_argument("bag", type=Path, metavar="BAG.mcap", help="MCAP bag (flexarm run's or "
                                                               "any ROS 2 MCAP)")
    rp.add_argument("--rate", type=number, default=1.0,
                    help="pace factor on the log times: 1 real time (default), 2 twice as "
                         "fast, 0 as fast as possible")
    rp.add_argument("--namespace", help="republish the recording namespace's topics under "
                                        "this one instead")
    rp.add_argument("--topics", nargs="+", metavar="TOPIC",
                    help="only these topics (absolute, or relative to the recording "
                         "namespace); /clock is always published")
    rp.add_argument("--loop", action="store_true", help="start over at the end until Ctrl-C")
    rp.add_argument("--wait-subscribers", type=integer, default=0, metavar="N",
                    help="before publishing, wait up to 30 s until every topic has N "
                         "subscribers (default 0: do not wait)")
    rp.add_argument("--delay", type=number, default=0.5, metavar="S",
                    help="wall seconds between creating the publishers and the first "
                         "message, for discovery (default 0.5)")
    rp.add_argument("--rerun", type=Path, metavar="FILE.rrd",
                    help="convert the bag to this rerun recording instead of publishing "
                         "(no ROS needed; with --publish: both)")
    rp.add_argument("--publish", action="store_true", help="with --rerun: also publish")
    rp.add_argument("--shape-rate", type=number, default=100.0, metavar="HZ",
                    help="--rerun: at most this many arm drawings per simulated second "
                         "(default 100; 0: every coordinates message)")
    rp.add_argument("--samples", type=integer, default=21,
                    help="--rerun: points per beam centerline (default 21)")
    rp.add_argument("--force-scale", type=number, metavar="M_PER_N",
                    help="--rerun: contact force arrow length per newton (default: the "
                         "largest force draws a quarter of the arm's reach)")
    rp.add_argument("--json", action="store_true", help="print the counts as JSON")
    rp.add_argument("--quiet", action="store_true",
                    help="no progress on stderr (the summary is still printed)")
    rp.set_defaults(func=cmd_replay)

    c = sub.add_parser("compare", help="a twin run beside an experiment or another run: "
                                       "frequencies, errors, pass/fail, report")
    c.add_argument("run", help="the twin's bag (flexarm run --record), or a CSV")
    c.add_argument("reference", help="MCAP bag (twin, or foreign with --map) or CSV "
                                     "('t [s]', 'name [unit]', ...)")
    c.add_argument("--report", metavar="DIR", help="write DIR/report.md and PNG figures")
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.add_argument("--map", metavar="MAP.yaml", help="channel map for the reference "
                   "(foreign bag topics/fields, or renamed/rescaled CSV columns)")
    c.add_argument("--offset", default="auto", metavar="auto|none|SECONDS",
                   help="run(t + offset) = reference(t); auto: cross-correlation (default)")
    c.add_argument("--max-shift", type=number, metavar="S",
                   help="search range of --offset auto, s (default 0.5)")
    c.add_argument("--threshold", type=number, help="pass mark on |relative error| "
                                                   "(default 0.10 = ±10 %%)")
    c.add_argument("--channels", nargs="+", metavar="NAME",
                   help="only these channels (default: every common one)")
    c.add_argument("--window", metavar="START:END",
                   help="analyse only this span of the reference clock, s (e.g. 2.1:2.5)")
    c.set_defaults(func=cmd_compare)
    _bag_parser(sub)
    from flexarm_ros.ensemble.cli import add_parsers    # sweep, uncertainty, sensitivity
    add_parsers(sub)
    from flexarm_ros.calibration.cli import add_parsers as add_calibrate
    add_calibrate(sub)
    return p


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


#: GC thresholds of a batch command's process (Python's default: 700, 10, 10)
BATCH_GC_THRESHOLD = (200_000, 10, 10)


def _startup_gc():
    """Collector settings of a batch process (:func:`main` with the process's own command
    line, ``_BATCH_COMMANDS``). Start-up creates ~120 000 long-lived objects (imports,
    numba's typing and lowering registries) and almost no cyclic garbage; at the default
    thresholds the collector walks them ~250 times (~0.1 s of a 1 s ``flexarm simulate``).
    A young generation of 200 000 objects makes a short run collect almost never and keeps
    a long one bounded (a first-run numba compile leaves ~10⁶ objects of cyclic garbage).
    Everything alive at the end is frozen (:func:`gc.freeze`, in :func:`main`) just before
    the process exits, which spares the interpreter's final collection over the whole heap
    (~0.2 s). Not for ``run`` / ``replay`` (a large young collection is a pause inside a
    realtime tick; a frozen heap skips the exit-time finalizers of objects in cycles) nor
    ``study`` / ``compare`` (long, plotting)."""
    gc.set_threshold(*BATCH_GC_THRESHOLD)


def main(argv=None) -> int:
    """Exit 0 done, 1 failed (see the module doc), 2 bad input (one line: the key, the
    value, the expectation), 3 diverged, 130 interrupted."""
    environment.use_loopback()
    from flexarm_ros.errors import InputError, SimulationDiverged
    args = build_parser().parse_args(argv)
    batch = argv is None and args.func in _BATCH_COMMANDS
    if batch:
        _startup_gc()
    try:
        # overflow / invalid arithmetic of a diverging state is reported by the guard in
        # one line (exit 3), not as numpy RuntimeWarnings on the way there
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return args.func(args)
    except InputError as exc:
        print(f"flexarm: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SimulationDiverged as exc:
        print(f"flexarm: {_one_line(exc)}", file=sys.stderr)
        return 3
    except OSError as exc:          # the environment, not the program: a disk filled up
        print(f"flexarm: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("flexarm: interrupted", file=sys.stderr)
        return 130
    finally:
        if batch:
            gc.freeze()


_BATCH_COMMANDS = (cmd_simulate, cmd_modes, cmd_linearize, cmd_explain)

if __name__ == "__main__":
    sys.exit(main())
