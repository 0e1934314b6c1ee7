"""``flexarm run``: the ROS 2 twin (simulator, motor driver, controller and recorder
nodes; :mod:`flexarm_ros.run`), its pacing flags checked before the graph starts.
Exit 0 done, 1 a node exited with an error or ended before the run (a signal from outside
it), 2 bad input, 3 diverged, stalled or another twin in its namespace and domain, 4 messages missing from the bag, 128 + n a signal
interrupted the run (130 Ctrl-C, 143 SIGTERM)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flexarm_ros.commands.common import (
    check_duration, fidelity_args, overrides, scene_arg, set_values)
from flexarm_ros.io.arguments import number
from flexarm_ros.scene import DEFAULT_SCENE


def add_parser(sub) -> None:
    r = sub.add_parser("run", help="the ROS 2 twin: simulator, motor driver, controller and "
                                    "recorder nodes")
    scene_arg(r)
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
    r.add_argument("--transport", choices=("bus", "dds"), default="bus",
                   help="bus: the nodes of one process hand their messages over in-process "
                        "(DDS still carries them to every other reader; default); dds: "
                        "every message by DDS on rclpy's stock executor path (layouts one "
                        "and processes)")
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
    fidelity_args(r)
    r.set_defaults(func=main)


def main(args):
    """The ROS 2 graph (simulator, motor driver, controller, recorder); see flexarm_ros.run."""
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.run import run
    check_duration(args.duration, allow_inf=True)
    sets = set_values(args)
    if args.tolerance is not None:
        from flexarm_ros.errors import InputError
        raise InputError(f"--tolerance: got {args.tolerance:g} m, expected it with flexarm "
                         f"simulate (the twin's plant steps within its control tick with "
                         f"the held efforts, which the step-halving pilots cannot "
                         f"replay; set --dt)")
    if (args.late_bound is not None or args.ground_truth_rate is not None
            or args.thread_priority is not None or args.start_timeout is not None
            or args.marker_rate is not None):
        _check_pacing_flags(args)
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
        say_domain()                 # the user's own nodes must join this domain
    if args.processes and args.layout not in (None, "processes"):
        from flexarm_ros.errors import InputError
        raise InputError(f"--processes and --layout {args.layout}: choose one layout")
    if args.transport == "dds" and args.layout == "split":
        from flexarm_ros.errors import InputError
        raise InputError("--transport dds with --layout split: the split layout joins its "
                         "two processes by the bus's socket; use --layout one or "
                         "--processes with --transport dds")
    kw = dict(duration=args.duration, mode=args.mode, processes=args.processes, pin=args.pin,
              transport=args.transport,
              layout="processes" if args.processes else args.layout,
              nodes=tuple(n for n in nodes if n != "recorder"),
              namespace=namespace, progress=not args.quiet,
              fidelity={k: v for k, v in overrides(args).items()
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
    # like simulate: the message once, status 3 (another twin: before ended_early, the
    # others were stopped by it)
    why = res.diverged or res.conflict or res.stalled
    if why:
        if not res.processes and res.layout != "split":     # else the node said it
            print(f"flexarm: {why}", file=sys.stderr)
        return 3
    return _exit_status(res)


def _exit_status(res) -> int:
    """After the summary: one line on stderr for what ended the run early, and the status
    (docs/commands.md, *`flexarm run`*): 128 + n when a signal interrupted the run itself
    (130 Ctrl-C, 143 SIGTERM), 1 when a node ended before the run (a signal from outside
    it, a crash) or exited with an error, else 0."""
    kept = f"; {res.record} holds what was recorded until then" if res.record else ""
    at = (f" at t = {res.sim_s:.6g} s" + (f" of {res.end_s:.6g} s" if res.end_s else "")
          if res.sim_s is not None else "")
    if res.interrupted:
        print(f"flexarm run: interrupted by {res.signal or 'a signal'}{at}{kept}",
              file=sys.stderr)
        import signal
        return 128 + (signal.Signals[res.signal].value if res.signal else signal.SIGINT)
    if res.ended_early:
        print("flexarm run: ended early: " + "; ".join(
            f"{n} {how}" for n, how in res.ended_early.items()) + kept, file=sys.stderr)
        return 1
    bad = {k: v for k, v in res.returncodes.items() if v not in (0, None)}
    if bad:
        print(f"flexarm run: nodes exited with {bad}", file=sys.stderr)
        return 1
    if res.missing:
        print("flexarm run: the bag misses messages the simulator published: " + ", ".join(
            f"{t} {v['recorded']} of {v['published']}" for t, v in res.missing.items())
              + f" (written into {res.record}'s missing_messages metadata)", file=sys.stderr)
        return 4
    return 0


def _names(values) -> list | None:
    """Repeatable and comma-separated option values as one list (None: not given)."""
    if values is None:
        return None
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


def say_domain() -> None:
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
    --start-timeout, --marker-rate) checked before the graph starts, with the
    flags' names (the simulator node checks the same values as its parameters)."""
    from flexarm_ros.errors import InputError
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin.pacing import THREAD_PRIORITY, check_settings
    from flexarm_ros.scene.overrides import apply_sets
    period = 1.0 / apply_sets(load_scene(args.scene or DEFAULT_SCENE),
                              set_values(args)).twin_control.rate_hz
    try:
        check_settings(period, args.late_policy or "slow",
                       0.1 if args.late_bound is None else args.late_bound,
                       0.0 if args.ground_truth_rate is None else args.ground_truth_rate,
                       THREAD_PRIORITY if args.thread_priority is None else
                       args.thread_priority,
                       0.0 if args.start_timeout is None else args.start_timeout,
                       30.0 if args.marker_rate is None else args.marker_rate)
    except InputError as exc:
        raise InputError(str(exc).replace("parameter late_bound", "--late-bound").replace(
            "parameter ground_truth_rate_hz", "--ground-truth-rate").replace(
            "parameter thread_priority", "--thread-priority").replace(
            "parameter start_timeout_s", "--start-timeout").replace(
            "parameter marker_rate_hz", "--marker-rate")) from None
