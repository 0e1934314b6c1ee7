"""Start the twin's ROS 2 graph: simulator, motor driver, controller and (optionally) the
recorder, in one process (all nodes on one executor, the default) or one process per
node, for a duration or until Ctrl-C; always leaves a finalized MCAP when recording.

``flexarm run`` is :func:`run`; tests and benchmarks use :class:`InProcessGraph` and
:class:`ProcessGraph` directly to reach into a running graph (kill a node, publish a bad
command, read counters).

The scene is a YAML path or shipped name (default :data:`flexarm_ros.scene.DEFAULT_SCENE`);
``fidelity`` overrides (``Scene.with_fidelity`` keywords: rung, refine, integrator, rtol,
atol, dt, foreshortening) reach every node as the parameters of
:mod:`flexarm_ros.nodes.parameters`; ``sets`` (``flexarm run --set KEY=VALUE``: scene key
paths and values, :mod:`flexarm_ros.scene.overrides`) reach every node as its string
parameter ``set`` (JSON), which the node applies to the scene it loads before the fidelity
parameters — in every layout, whether the node runs in this process or in a child, it
builds the same modified scene, and nothing is left on disk (the recorder embeds the
modified scene in the bag and the sets in its ``flexarm_ros`` metadata).

Environment: :func:`flexarm_ros.nodes.environment.private_graph` (loopback-only discovery
and a private ``ROS_DOMAIN_ID``, each unless set) before rclpy initializes, inherited by
every child process.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from flexarm_ros.child_process import python_module
from flexarm_ros.nodes import environment
from flexarm_ros.nodes.parameters import MODES, fidelity_parameters
from flexarm_ros.scene import DEFAULT_SCENE
from flexarm_ros.twin import topics as T

DEFAULT_NAMESPACE = "/flexarm"
NODES = ("recorder", "motor_driver", "controller", "simulator")   # start order
GRAPH_NODES = ("simulator", "motor_driver", "controller")        # the recorder: record=


def select_nodes(nodes=None, without=()) -> tuple:
    """The twin's nodes to start: ``nodes`` (default every node) minus ``without``; names
    from :data:`NODES`; the simulator cannot be left out. A ValueError names the value
    and the allowed names."""
    chosen = list(NODES if nodes is None else nodes)
    without = list(without or ())
    for name in chosen + without:
        if name not in NODES:
            raise ValueError(f"node {name!r}: expected one of {', '.join(NODES)}")
    chosen = [n for n in NODES if n in chosen and n not in without]
    if "simulator" not in chosen:
        given = ", ".join(without if "simulator" in without else (nodes or ()))
        raise ValueError(f"got {given or 'none'}, which leaves the simulator out; expected "
                         f"the simulator among the nodes (it is the twin; leave out any of "
                         f"{', '.join(n for n in NODES if n != 'simulator')})")
    return tuple(chosen)


@dataclass
class RunResult:
    scene: str
    mode: str
    processes: bool
    record: Path | None
    wall_s: float
    sim_s: float | None = None              # in-process runs only
    ticks: int | None = None
    real_time_factor: float | None = None
    overruns: int | None = None
    rejected_commands: int | None = None     # on both command topics
    rejected: dict | None = None              # topic -> {reason: count}, every node input
    extra_commands: int | None = None         # lockstep, driver in this process: beyond 1/state
    diverged: str | None = None               # the divergence message (exit status 3)
    stalled: str | None = None                # lockstep ended without answers (status 3)
    interrupted: bool = False
    signal: str | None = None                 # what interrupted the run (SIGINT, SIGTERM)
    ended_early: dict | None = None           # node -> how it ended before the run did
    end_s: float | None = None                # the simulated time the run was to reach
    missing: dict | None = None               # topic -> published, recorded: bag short
    conflict: str | None = None               # another twin in the namespace (status 3)
    twin_seen: str | None = None              # a newer twin appeared and stopped itself
    returncodes: dict = field(default_factory=dict)
    recovered: str | None = None            # what recover_killed_bag() did, if anything
    nodes: tuple = ()                         # the nodes that ran
    pacing: dict | None = None                # realtime: the simulator's Pacer.summary()
    published: dict | None = None             # simulator: messages per absolute topic
    recorded: dict | None = None              # the bag's message count per topic
    cpus: dict | None = None                  # --processes with pinning: node -> CPUs
    first_command_s: float | None = None      # sim time of the first recorded command
    layout: str = ""                          # "one", "split" or "processes"
    integrator: str | None = None             # what the plant stepped with (rk4, rkn4)
    step_s: float | None = None               # ... and its step
    cpu: dict | None = None                   # twin/cpu_load.cpu_budget over the ticking
    kept_previous: bool = False               # no tick: the bag already at `record` kept
    sets: dict = field(default_factory=dict)  # --set: {key path: value} every node applied

    @property
    def ticking_s(self) -> float | None:
        """Wall time of the ticking alone (what the real-time factor divides by); the
        rest of ``wall_s`` is start-up (processes, imports, discovery) and the end."""
        rtf = self.real_time_factor
        return self.sim_s / rtf if self.sim_s is not None and rtf else None

    def to_json(self) -> dict:
        """The summary as JSON-ready numbers (``flexarm run --json``)."""
        p = self.pacing or {}
        return {"scene": self.scene, "set": dict(self.sets), "mode": self.mode,
                "processes": self.processes,
                "layout": self.layout or ("processes" if self.processes else "one"),
                "nodes": list(self.nodes), "record": str(self.record) if self.record else None,
                "wall_time_s": self.wall_s, "ticking_wall_time_s": self.ticking_s,
                "sim_time_s": self.sim_s, "ticks": self.ticks,
                "integrator": self.integrator, "step_s": self.step_s,
                "real_time_factor": self.real_time_factor,
                "first_command_s": self.first_command_s,
                "late_ticks": p.get("late_ticks"),
                "lateness_p50_s": p.get("lateness_p50_s"),
                "lateness_p99_s": p.get("lateness_p99_s"),
                "lateness_max_s": p.get("lateness_max_s"),
                "late_policy": p.get("late_policy"), "skipped_ticks": p.get("skipped_ticks"),
                "scheduling": p.get("scheduling"),
                "slowed_s": p.get("slowed_s"),
                "effort_waits": p.get("effort_waits"),
                "effort_wait_timeouts": p.get("effort_wait_timeouts"),
                "published": self.published, "recorded": self.recorded,
                "rejected_commands": (self.rejected_commands if self.rejected_commands
                                      is not None else
                                      (sum(sum(by.values()) for by in self.rejected.values())
                                       if self.rejected is not None else None)),
                "rejected": self.rejected, "extra_commands": self.extra_commands,
                "record_kept_previous": self.kept_previous,
                "diverged": self.diverged,
                "stalled": self.stalled,
                "interrupted": self.interrupted, "signal": self.signal,
                "end_s": self.end_s, "ended_early": self.ended_early,
                "missing": self.missing, "conflict": self.conflict,
                "twin_seen": self.twin_seen,
                "returncodes": self.returncodes,
                "recovered": self.recovered,
                "cpus": ({n: sorted(c) for n, c in self.cpus.items()} if self.cpus
                         else None),
                **(self.cpu or {"cpu_ms_per_tick": None, "cpu_ms_per_tick_total": None,
                                "cpu_share": None, "cpus_available": None})}

    def summary(self) -> str:
        from flexarm_ros.twin.pacing import short_scheduling
        how = ("one process per node" if self.processes else
               "the simulator in a process of its own" if self.layout == "split" else
               "one process")
        s = f"{self.scene}: {self.mode} run ({how}"
        left = [n for n in NODES if self.nodes and n not in self.nodes]
        s += f"; without {', '.join(left)})" if left else ")"
        if self.sim_s is not None:
            tick = self.ticking_s
            s += (f", {self.sim_s:.3f} s simulated in "
                  + (f"{tick:.3g} s of ticking, {self.wall_s:.3g} s with start-up "
                     if tick is not None else f"{self.wall_s:.3g} s ")
                  + f"(real-time factor {self.real_time_factor:.3g}")
            p = self.pacing
            s += (f", {p['late_ticks']} of {p['ticks']} ticks late, lateness p99 "
                  f"{p['lateness_p99_s'] * 1e3:.3g} ms" + (
                      f"; pacing thread {short_scheduling(p['scheduling'])}"
                      if p.get("scheduling") else "") + ")" if p else ")")
        else:
            s += f", {self.wall_s:.3g} s wall"
        if self.cpu and self.cpu["cpu_ms_per_tick"]:
            c = self.cpu
            s += ("; CPU per tick " + ", ".join(
                f"{k} {v:.2f}" for k, v in sorted(c["cpu_ms_per_tick"].items(),
                                                  key=lambda kv: -kv[1]))
                  + f" ms ({100 * c['cpu_share']:.0f} % of {c['cpus_available']} CPUs)")
            p = self.pacing
            if p and p["ticks"] and p["late_ticks"] > 0.01 * p["ticks"]:
                s += _busy_hint(c, 1e3 * self.sim_s / self.ticks,
                                self.layout or ("processes" if self.processes else "one"))
        if self.first_command_s is not None and self.first_command_s > 0:
            s += (f"; the first command came at {self.first_command_s:.3f} s (the drives "
                  f"held 0 before it)")
        if self.interrupted:
            s += f", interrupted by {self.signal}" if self.signal else ", interrupted"
        if self.ended_early:
            s += "; " + "; ".join(f"{n} {how}" for n, how in self.ended_early.items())
        if self.diverged:
            s += ", diverged"
        if self.stalled:
            s += ", stalled"
        if self.conflict:
            s += ", stopped: another twin in its namespace and domain"
        if self.twin_seen:
            s += f"; {self.twin_seen}"
        if self.extra_commands:
            s += (f"; {self.extra_commands} command(s) beyond one per state (lockstep: the "
                  f"pairing shifted from the first on)")
        if self.rejected:
            s += "; rejected: " + "; ".join(
                f"{t} {sum(by.values())} (" + ", ".join(f"{n} {r}" for r, n in
                                                        sorted(by.items())) + ")"
                for t, by in sorted(self.rejected.items()))
        elif self.rejected is not None:
            s += "; no message rejected"
        if self.missing:
            s += "; MISSING from the bag: " + ", ".join(
                f"{t} {v['recorded']} of {v['published']}" for t, v in self.missing.items())
        if self.record and self.kept_previous:
            s += (f"; no tick recorded: {self.record} keeps the bag that was there (the "
                  f"empty one discarded)")
        elif self.record:
            s += f" → {self.record}"
        s += f" ({self.recovered})" if self.recovered else ""
        if self.sets:
            from flexarm_ros.scene.overrides import format_sets
            s += f"\n  set: {format_sets(self.sets)}"
        return s


def _bag_rejections(path) -> dict | None:
    """The recorder's ``rejected_messages`` metadata of a finalized bag (None: none)."""
    import json

    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            for rec in make_reader(f).iter_metadata():
                if rec.name == "rejected_messages":
                    return json.loads(rec.metadata["by_topic"])
    except Exception:                         # a truncated bag has no summary: no counts
        return None
    return None


def _bag_counts(path) -> dict | None:
    """Messages per topic in a finalized bag's summary (None: no summary)."""
    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:                         # a truncated bag has no summary
        return None
    if summary is None or summary.statistics is None:
        return None
    by_id = summary.statistics.channel_message_counts
    return {ch.topic: int(by_id.get(cid, 0)) for cid, ch in summary.channels.items()}


def _first_command_s(path) -> float | None:
    """Log time (sim s) of the first message on the motor driver's command topic of a
    finalized bag (None: no such message or no summary)."""
    from mcap.reader import make_reader

    from flexarm_ros.twin import topics as T
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                return None
            topics = [c.topic for c in summary.channels.values()
                      if c.topic.endswith("/" + T.COMMANDS)]
            for _, _, m in reader.iter_messages(topics=topics):
                return m.log_time * 1e-9
    except Exception:                         # a truncated bag: not known
        return None
    return None


def _read_summary(path) -> dict | None:
    import json
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def _node_rejections(nodes) -> dict:
    """topic -> {reason: count} over the graph's nodes (absolute topic names)."""
    out: dict = {}
    for name in ("simulator", "motor_driver", "controller"):
        node = nodes.get(name)
        rej = getattr(node, "rejections", None)
        for topic, by in (rej.counts.items() if rej is not None else ()):
            out.setdefault(topic, {}).update(by)
    return out


def _params(scene, mode, duration, record, node, progress, fidelity=None,
            simulator=None, sets=None, graph=None) -> dict:
    """ROS parameters of ``node``: the common ones, the ``--set`` values (``set``, JSON),
    the fidelity overrides, the recorder's output, the simulator's progress and
    ``simulator`` parameters (``late_policy``, ``late_bound``, ``ground_truth_rate_hz``;
    None values: the node's defaults), sim time for the others in fast mode; ``graph``:
    the names of the nodes the run starts (:func:`awaits`)."""
    from flexarm_ros.scene.overrides import encode_sets
    p = {"scene": _scene_arg(scene), "mode": mode, "duration": float(duration or 0.0),
         "recorders": 1 if record else 0, **fidelity_parameters(fidelity)}
    if sets:
        p["set"] = encode_sets(sets)
    if node == "recorder":
        p["output"] = str(record)
    sim_awaits, driver_awaits = awaits(mode, graph)
    if node == "simulator":
        p["progress"] = bool(progress)
        if sim_awaits:
            p["await_first_effort"] = True
        p.update({k: v for k, v in (simulator or {}).items() if v is not None})
    elif mode == "fast":
        p["use_sim_time"] = True
    if node == "motor_driver" and driver_awaits:
        p["await_first_command"] = True
    return p


def awaits(mode, graph) -> tuple:
    """(the simulator awaits its first effort, the driver its first command): in realtime
    and fast, where the run does not start the controller or the driver (a user's takes
    its place), the twin's clock starts at the answer to its first state, as in lockstep
    (issue 38: a foreign controller's first command had come 1.3–2 s after the start, the
    arm unpowered meanwhile, and a fast run whose controller never answered exited 0)."""
    if mode == "lockstep" or graph is None:
        return False, False
    return (not {"controller", "motor_driver"} <= set(graph),
            "controller" not in graph)


def _scene_arg(scene) -> str:
    """A path given as such becomes absolute (children may run elsewhere)."""
    p = Path(str(scene))
    return str(p.resolve()) if p.is_file() else str(scene)


class InProcessGraph:
    """All nodes in this process on one executor and a private context.

    ``executor="twin"`` (default): :class:`~flexarm_ros.nodes.executor.TwinExecutor`
    (rclpy's SingleThreadedExecutor that also runs the bus), and with ``intraprocess``
    (default; ``flexarm run --transport bus``) the nodes exchange their messages through an
    intra-process bus (:mod:`~flexarm_ros.nodes.intraprocess`; DDS still carries every
    message to other processes); without it every message goes by DDS (``--transport
    dds``). ``"single"``: rclpy's SingleThreadedExecutor; ``"events"``: the
    experimental EventsExecutor, whose C++ event queue spends less time per lockstep tick,
    but it still dispatches events queued for a node that was removed or destroyed (used by
    ``bench/bench_realtime.py --executor events`` only). ``progress``: the simulator's
    progress line and the nodes' info log; without it warnings and errors only."""

    def __init__(self, scene=DEFAULT_SCENE, mode="lockstep", duration=None, record=None,
                 namespace=DEFAULT_NAMESPACE, progress=False, nodes=("simulator", "motor_driver",
                                                                       "controller"),
                 executor="twin", fidelity=None, simulator=None, intraprocess=True,
                 writer_process=True, remote=(), sets=None, enclave=None):
        import rclpy
        from rclpy.context import Context
        from rclpy.logging import LoggingSeverity
        from rclpy.parameter import Parameter
        from rclpy.signals import SignalHandlerOptions

        from flexarm_ros.nodes import node_classes
        from flexarm_ros.nodes.common import make_executor, new_run_enclave
        environment.private_graph()
        self.context = Context()
        # the run's enclave tells its nodes from another run's (nodes/common.other_twin)
        self.enclave = enclave or new_run_enclave()
        rclpy.init(args=["flexarm", "--ros-args", "--enclave", self.enclave],
                   context=self.context, domain_id=environment.domain_id(),
                   signal_handler_options=SignalHandlerOptions.NO)
        self.executor = make_executor(self.context, executor)
        self.nodes = {}
        names = list(nodes) + (["recorder"] if record else [])
        self.bus = None
        if intraprocess and executor == "twin":
            from flexarm_ros.nodes.intraprocess import install
            # ``remote``: members in another process, joined by SplitGraph's bridge
            self.bus = install(self.context, [(namespace, n) for n in names + list(remote)])
        try:
            for name in NODES:
                if name not in names:
                    continue
                p = _params(scene, mode, duration, record, name, progress, fidelity,
                            simulator, sets, graph=names + list(remote))
                p["run_enclave"] = self.enclave
                if name == "recorder":
                    # the bag's stamping and writing on the other core (bag/writer_process.py)
                    p["writer_process"] = bool(writer_process)
                node = node_classes()[name](
                    context=self.context, namespace=namespace,
                    parameter_overrides=[Parameter(k, value=v) for k, v in p.items()])
                node.get_logger().set_level(LoggingSeverity.INFO if progress
                                            else LoggingSeverity.WARN)
                self.nodes[name] = node
                self.executor.add_node(node)
        except BaseException:
            self.close()
            raise

    def __getitem__(self, name):
        return self.nodes[name]

    def spin_until(self, condition, timeout=None, stop=None) -> bool:
        """Spin until ``condition()`` (True), ``timeout`` s of wall time or ``stop.set``."""
        t0 = time.monotonic()
        while not condition():
            if (timeout is not None and time.monotonic() - t0 > timeout) or \
                    (stop is not None and stop.set) or not self.context.ok():
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def recorded_all(self) -> bool:
        """Every message published by this process's nodes, and every effort the
        simulator accepted (an outside driver's included), has reached the recorder."""
        rec = self.nodes.get("recorder")
        return rec is None or _all_arrived(rec.received, self.nodes.values())

    def remove(self, name):
        """Take a node out of the graph (what a crash does), without closing the others."""
        node = self.nodes.pop(name)
        if self.bus is not None:
            self.bus.remove_node(node)
        self.executor.remove_node(node)
        node.destroy_node()

    def close(self):
        import rclpy
        rec = self.nodes.get("recorder")
        if rec is not None:
            rec.close()
        self.executor.shutdown()            # releases the handles its wait set holds
        for node in self.nodes.values():
            node.destroy_node()
        self.nodes = {}
        if self.context.ok():
            rclpy.shutdown(context=self.context)


PR_SET_PDEATHSIG = 1        # linux/prctl.h


def die_with_parent(sig: int = signal.SIGTERM):
    """A ``preexec_fn`` that makes the child get ``sig`` when this process dies, however
    it dies (SIGKILL included), or None where that cannot be done.

    Linux's parent-death signal (``prctl(PR_SET_PDEATHSIG)``, set in the child between
    fork and exec, kept across exec) through ctypes; right after setting it the child
    checks that its parent is still this process, which closes the race of a parent
    dying before the call (the child then exits at once).  The signal follows the
    *thread* that forks: create the children from a thread that lives as long as the
    graph (the main thread in ``flexarm run``).  Elsewhere (macOS, Windows, a libc
    without prctl) this returns None: the children then outlive a SIGKILLed parent,
    as any subprocess does; SIGINT/SIGTERM to the parent still stop them."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong,
                      ctypes.c_ulong]
    prctl.restype = ctypes.c_int
    parent = os.getpid()

    def bind():                 # runs in the child, before exec: keep it minimal
        if prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0 and os.getppid() != parent:
            os._exit(1)         # the parent is already gone
    return bind


def cpu_placement(names, cpus=None) -> dict:
    """``{node: CPUs}`` for a realtime graph of one process per node: the simulator alone
    on the last CPU the caller may use, every other node on the rest; ``{}`` with fewer
    than two CPUs or where the platform has no CPU affinity.

    Why (measured, bench/bench_realtime.py, two_link_case1 at 1 kHz on 2 cores): the
    simulator's process is the twin's critical path (its tick holds the GIL for physics,
    encoding and publishing); left to the scheduler, every message it publishes wakes a
    receiving process that preempts it on its own core. Pinned, the real-time factor rose
    from 0.83 to 0.91 with the same work per tick. ros2_control's controller manager
    offers the same knob (``cpu_affinity``)."""
    if not hasattr(os, "sched_getaffinity"):
        return {}
    allowed = sorted(os.sched_getaffinity(0) if cpus is None else cpus)
    if len(allowed) < 2 or "simulator" not in names:
        return {}
    sim, rest = {allowed[-1]}, set(allowed[:-1])
    return {n: (sim if n == "simulator" else rest) for n in names}


def _preexec(die, cpus):
    """The child's ``preexec_fn``: the parent-death signal, then the CPU set (threads made
    later, DDS's included, inherit it)."""
    if die is None and not cpus:
        return None

    def setup():
        if die is not None:
            die()
        if cpus:
            os.sched_setaffinity(0, cpus)
    return setup


def _ros_arg(name: str, value) -> str:
    """A parameter's value on a node's command line (``-p name:=value``, which rcl reads
    as YAML): booleans in YAML's spelling; the JSON text of ``set`` as a double-quoted
    YAML string (JSON's string escapes are YAML's), else rcl would read it as a mapping."""
    if isinstance(value, bool):
        return str(value).lower()
    if name == "set":
        import json
        return json.dumps(value)
    return str(value)


class ProcessGraph:
    """One child process per node: ``python -m flexarm_ros.nodes.<node> --ros-args ...``
    (``progress``: as :class:`InProcessGraph`).

    On Linux every child gets SIGTERM when this process dies, however it dies (SIGKILL
    included; :func:`die_with_parent`), and stops as on Ctrl-C: the recorder finalizes
    its bag.  The children stay in the caller's process group, so a terminal's Ctrl-C
    reaches all of them; each stops cleanly on its own and :meth:`stop` finds them done.
    """

    def __init__(self, scene=DEFAULT_SCENE, mode="lockstep", duration=None, record=None,
                 namespace=DEFAULT_NAMESPACE, progress=False, nodes=("simulator", "motor_driver",
                                                                       "controller"),
                 stderr=None, fidelity=None, simulator=None, pin=False, extra_env=None,
                 pass_fds=(), start_recorder=True, controllers=None, sets=None,
                 enclave=None, graph=None):
        from flexarm_ros.nodes.common import new_run_enclave
        self.enclave = enclave or new_run_enclave()
        env = {**environment.child_environment(), **(extra_env or {})}
        names = list(nodes) + (["recorder"] if record and start_recorder else [])
        self.placement = cpu_placement(names) if pin else {}
        self.procs = {}
        # created by stop() before it signals the nodes: a node stopped by a signal while
        # it does not exist was stopped from outside the run, and says so (exit 128 + n)
        fd, path = tempfile.mkstemp(prefix="flexarm-stop-")
        os.close(fd)
        os.unlink(path)
        self.stop_file = Path(path)
        try:
            for name in NODES:
                if name not in names:
                    continue
                # the simulator's first state waits for the controller this graph starts
                # (in realtime it would not wait for a controller of its own accord)
                sim = {**(simulator or {}), "controllers": (
                    1 if "controller" in names else -1) if controllers is None else controllers}
                p = _params(scene, mode, duration, record and Path(record).resolve(), name,
                            progress, fidelity, sim, sets,
                            graph=names if graph is None else graph)
                p["stop_file"] = str(self.stop_file)
                p["run_enclave"] = self.enclave
                if name == "recorder" and (simulator or {}).get("summary_file"):
                    p["published_file"] = simulator["summary_file"]
                cmd = python_module(f"flexarm_ros.nodes.{name}") + [
                    "--ros-args", "--enclave", self.enclave, "-r", f"__ns:={namespace}"]
                if not progress:
                    cmd += ["--log-level", "warn"]
                for k, v in p.items():
                    cmd += ["-p", f"{k}:={_ros_arg(k, v)}"]
                self.procs[name] = subprocess.Popen(
                    cmd, env=env, stderr=stderr, pass_fds=tuple(pass_fds),
                    preexec_fn=_preexec(die_with_parent(), self.placement.get(name)))
        except BaseException:
            self.stop(timeout=5.0)
            raise

    def failed(self) -> list:
        """Nodes that exited with an error."""
        return [n for n, p in self.procs.items() if p.poll() not in (None, 0)]

    def signal(self, name, sig=signal.SIGTERM):
        proc = self.procs.get(name)
        if proc is not None and proc.poll() is None:
            proc.send_signal(sig)

    def stop(self, timeout=15.0) -> dict:
        """SIGTERM the nodes (simulator, controller, driver, then the recorder, which
        drains and finalizes), kill what does not exit; the return codes."""
        self.stop_file.touch()
        for group in (("simulator", "controller", "motor_driver"), ("recorder",)):
            for name in group:
                self.signal(name)
            for name in group:
                proc = self.procs.get(name)
                if proc is None:
                    continue
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        self.stop_file.unlink(missing_ok=True)
        return {name: p.returncode for name, p in self.procs.items()}

    def conflict(self) -> str | None:
        """The first node's word that another twin shares the namespace and domain (a
        node that found one at its start exits 3 and writes it: nodes/common.tell_the_run),
        once read; None if none did."""
        path = Path(str(self.stop_file) + ".conflict")
        try:
            lines = path.read_text().splitlines()
        except OSError:
            return None
        path.unlink(missing_ok=True)
        return lines[0] if lines else None

    def ended(self) -> list:
        """Nodes whose process has ended (before stop(): on their own or by a signal
        from outside the run)."""
        return [n for n, p in self.procs.items() if p.poll() is not None]


class SplitGraph:
    """The simulator in a child process of its own, the other nodes in this one
    (:class:`InProcessGraph`), their buses joined over a Unix socket
    (:mod:`~flexarm_ros.nodes.bridge`): the plant's tick on one core, the driver,
    controller and recorder on the other, messages between them as bytes written once
    per tick (docs/decisions/0009-the-bag-writer-process-and-the-split-layout.md). With
    ``pin`` the simulator's process runs alone on the last CPU."""

    def __init__(self, scene=DEFAULT_SCENE, mode="lockstep", duration=None, record=None,
                 namespace=DEFAULT_NAMESPACE, progress=False, nodes=GRAPH_NODES,
                 fidelity=None, simulator=None, pin=False, sets=None):
        from flexarm_ros.nodes import bridge
        local = tuple(n for n in nodes if n != "simulator")
        self.graph = InProcessGraph(scene, mode, duration, record, namespace, progress,
                                    nodes=local, fidelity=fidelity, remote=("simulator",),
                                    sets=sets)
        self.procs = None
        self._affinity = None
        try:
            mine, theirs = bridge.socket_pair()
            members = [(namespace, n) for n in list(nodes) + (["recorder"] if record else [])]
            bridge.attach(self.graph.bus, mine)
            self.procs = ProcessGraph(
                scene, mode, duration, record, namespace, progress, nodes=("simulator",),
                fidelity=fidelity, simulator=simulator, start_recorder=False,
                controllers=1 if "controller" in nodes else -1, sets=sets,
                enclave=self.graph.enclave, graph=list(nodes),
                extra_env=bridge.child_environment(theirs, members),
                pass_fds=(theirs.fileno(),))
            self._affinity = None
            if pin:
                place = cpu_placement(["simulator", "rest"])
                if place:
                    os.sched_setaffinity(self.procs.procs["simulator"].pid, place["simulator"])
                    # this thread (the executor's) on the rest until close() (a pytest
                    # process calling run() gets its CPUs back); the bag writer floats
                    self._affinity = os.sched_getaffinity(0)
                    os.sched_setaffinity(0, place["rest"])
                    self.procs.placement = {"simulator": place["simulator"],
                                            "others": place["rest"]}
            theirs.close()
        except BaseException:
            self.close()
            raise

    @property
    def simulator(self):
        return self.procs.procs["simulator"]

    def recorded_all(self, sim_published: dict, sim_accepted: dict | None = None) -> bool:
        """Every message of this process's nodes and the simulator's ``sim_published``
        (its summary's counts), and what the nodes accepted (``sim_accepted``: the
        simulator's), has reached the recorder."""
        rec = self.graph.nodes.get("recorder")
        return rec is None or _all_arrived(rec.received, self.graph.nodes.values(),
                                           sim_published, sim_accepted)

    def close(self):
        if self.procs is not None:
            self.procs.stop(timeout=15.0)
        bus = self.graph.bus
        self.graph.close()
        if bus is not None and bus.bridge is not None:
            bus.bridge.close()
        if getattr(self, "_affinity", None):
            os.sched_setaffinity(0, self._affinity)
            self._affinity = None


def _all_arrived(received: dict, nodes, published: dict | None = None,
                 accepted: dict | None = None) -> bool:
    """The recorder's ``received`` counts cover what the ``nodes`` published per topic
    (plus ``published``, a node elsewhere's counts) and what they accepted from their
    inputs (their ``accepted`` {topic: n}, plus ``accepted``: the simulator's efforts, the
    driver's commands) — those come from whichever node publishes them, the twin's own or
    one outside the run, and the recorder validates them alike (found in session 13: the
    last effort of an outside driver was missing from 1 bag in 5 — the run had ended
    before the recorder took it)."""
    nodes = list(nodes)
    need = dict(published or {})
    for node in nodes:
        for t, n in getattr(node, "published", {}).items():
            need[t] = need.get(t, 0) + n
    for acc in [accepted or {}] + [getattr(node, "accepted", {}) for node in nodes]:
        for t, n in acc.items():
            need[t] = max(need.get(t, 0), n)
    return all(received.get(t, 0) >= n for t, n in need.items())


def recover_killed_bag(path: Path, returncode) -> str | None:
    """After the recorder process died without finalizing its bag (killed, crashed), make
    ``path`` a complete bag again: the unfinished file is kept as ``<stem>.killed.mcap``
    and what is readable of it is rewritten to ``path`` by ``flexarm bag repair``.
    Returns what was done (None when there was nothing to do)."""
    from flexarm_ros.bag.reader import BagError
    from flexarm_ros.bag.repair import repair
    if returncode in (0, None) or not path.is_file():
        return None
    with open(path, "rb") as f:
        f.seek(max(0, path.stat().st_size - 8))
        if f.read() == b"\x89MCAP0\r\n":
            return None                         # it finalized the file before dying
    how = (f"was killed by {signal.Signals(-returncode).name}" if returncode < 0 and
           -returncode in signal.valid_signals() else f"exited with status {returncode}")
    killed = path.with_name(f"{path.stem}.killed{path.suffix}")
    os.replace(path, killed)
    try:
        report = repair(killed, path)
    except (BagError, OSError) as exc:
        os.replace(killed, path)
        return f"the recorder {how}; its bag could not be repaired: {exc}"
    return (f"the recorder {how}: {report.messages} messages recovered into {path}, "
            f"the unfinished file kept as {killed}")


def run(scene=DEFAULT_SCENE, duration=None, mode="lockstep", record="run.mcap",
        processes=False, namespace=DEFAULT_NAMESPACE, progress=True,
        fidelity=None, simulator=None, nodes=GRAPH_NODES, pin=None,
        layout=None, sets=None, transport="bus") -> RunResult:
    """:func:`_run`, and a bag already at ``record`` is not lost to a run that never
    ticked (a twin whose controller never came, a bad argument, Ctrl-C before the start):
    it is set aside as ``<name>.previous.mcap`` while the graph runs and put back when the
    run recorded no tick (a new-user trial lost a good run.mcap to an empty one that
    way); after a run that ticked it is removed, as an overwrite would. Should this
    process die meanwhile, it stays there under that name."""
    path = Path(record) if record else None
    previous = None
    if path is not None and path.is_file():
        previous = path.with_name(path.stem + ".previous" + path.suffix)
        os.replace(path, previous)
    res = None
    try:
        res = _run(scene, duration, mode, record, processes, namespace, progress, fidelity,
                   simulator, nodes, pin, layout, sets, transport)
        return res
    finally:
        if previous is not None and previous.exists():
            if res is not None and (res.ticks or sum((res.recorded or {}).values())):
                previous.unlink()
            elif res is not None or not path.exists():
                os.replace(previous, path)
                if res is not None:
                    res.kept_previous = True
            # else: an error after a new bag began: both stay


def _run(scene=DEFAULT_SCENE, duration=None, mode="lockstep", record="run.mcap",
         processes=False, namespace=DEFAULT_NAMESPACE, progress=True,
         fidelity=None, simulator=None, nodes=GRAPH_NODES, pin=None,
         layout=None, sets=None, transport="bus") -> RunResult:
    """Run the graph for ``duration`` s of simulated time (None: the scene's) or until
    SIGINT/SIGTERM; with ``record`` the MCAP is finalized in every case but SIGKILL.
    ``fidelity``: ``Scene.with_fidelity`` keywords for every node (None values: the
    scene's); ``sets``: ``{key path: value}`` written into the scene before the fidelity
    overrides, by every node (``flexarm run --set``); ``progress``: progress line and
    the nodes' info log on stderr; ``nodes``:
    which of simulator, motor_driver, controller to start (a user's own node replaces
    the others: see docs/topic_contract.md); ``pin``: with ``processes``, the simulator
    alone on one CPU and the other nodes on the rest (:func:`cpu_placement`; None: in
    ``realtime`` only); ``layout``: ``"one"`` process, ``"split"`` (the simulator in a
    process of its own, :class:`SplitGraph`) or ``"processes"`` (one per node; also
    ``processes=True``); None: :func:`default_layout`. ``transport``: ``"bus"``, the nodes
    of one process exchange their messages in-process (:mod:`~flexarm_ros.nodes.intraprocess`,
    DDS still carries them to everyone else); ``"dds"``, every message by DDS on rclpy's
    stock path (layouts one and processes; split is joined by the bus's socket)."""
    t0 = time.monotonic()                    # the summary's "with start-up" counts from here
    from flexarm_ros.scene import load_scene
    from flexarm_ros.nodes.common import StopFlag
    from flexarm_ros.twin.recording import missing_messages
    if mode not in MODES:
        raise ValueError(f"mode: got {mode!r}, expected one of {MODES}")
    if layout is None:
        layout = "processes" if processes else default_layout(mode)
    if layout not in LAYOUTS:
        raise ValueError(f"layout: got {layout!r}, expected one of {LAYOUTS}")
    processes = layout == "processes"
    if transport not in TRANSPORTS:
        raise ValueError(f"transport: got {transport!r}, expected one of {TRANSPORTS}")
    if transport == "dds" and layout == "split":
        raise ValueError("transport 'dds' with layout 'split': the split layout joins its "
                         "two processes by the bus's socket; use layout 'one' or "
                         "'processes' with transport 'dds'")
    # fails early on a bad scene, set or override (SceneError, an InputError: exit 2)
    from flexarm_ros.scene.overrides import apply_sets
    sets = dict(sets or {})
    loaded = apply_sets(load_scene(scene), sets).with_fidelity(**(fidelity or {}))
    name = loaded.name
    _compile_once(loaded, progress)
    from flexarm_ros.sim.plant import check_plant_work
    check_plant_work(loaded, duration)          # the work budget, before any node starts
    from flexarm_ros.twin.cores import control_period
    from flexarm_ros.twin.pacing import check_settings
    check_settings(control_period(loaded), **{k: v for k, v in (simulator or {}).items()
                                              if v is not None and k in (
                                                  "late_policy", "late_bound",
                                                  "ground_truth_rate_hz", "thread_priority",
                                                  "start_timeout_s", "marker_rate_hz")})
    record = Path(record) if record else None
    cpus = len(os.sched_getaffinity(0))       # before a split graph pins this process
    stop = StopFlag()
    try:
        if processes:
            summary_file = _summary_path()
            g = ProcessGraph(scene, mode, duration, record, namespace, progress,
                             nodes=nodes, fidelity=fidelity, sets=sets,
                             simulator={**(simulator or {}),
                                        "summary_file": str(summary_file)},
                             pin=(mode == "realtime") if pin is None else pin)
            sampler = _cpu_sampler("run")
            sim = g.procs["simulator"]
            try:
                while sim.poll() is None and not stop.set and not g.failed():
                    try:
                        sim.wait(0.1)
                    except subprocess.TimeoutExpired:
                        pass
            finally:
                sampler.stop()
            codes = g.stop()
            conflict = g.conflict()
            recovered = recover_killed_bag(record, codes.get("recorder")) if record else None
            res = RunResult(name, mode, True, record, time.monotonic() - t0,
                            interrupted=stop.set, signal=stop.signal_name,
                            ended_early=ended_early(codes, stop.set),
                            returncodes=codes, recovered=recovered,
                            nodes=tuple(g.procs), cpus=g.placement or None, sets=sets)
            sim_summary = _read_summary(summary_file)
            summary_file.unlink(missing_ok=True)
            if sim_summary:
                _take_summary(res, sim_summary, namespace)
                _take_cpu(res, sampler, sim_summary, "simulator", cpus)
            res.conflict = res.conflict or conflict
            if codes.get("simulator") == 3 and not (res.stalled or res.conflict):
                res.diverged = res.diverged or ("the simulator reported a divergence (its "
                                                "message above)")
            if record:
                res.rejected = _bag_rejections(record)
                res.recorded = _bag_counts(record)
                res.missing = missing_messages(res.published, res.recorded)
                res.first_command_s = _first_command_s(record)
            return res
        if layout == "split":
            return _run_split(scene, mode, duration, record, namespace, progress, fidelity,
                              simulator, nodes, (mode == "realtime") if pin is None else pin,
                              stop, name, t0, cpus, sets)
        from flexarm_ros.io.progress import CompileNotice
        with CompileNotice(enabled=progress):   # a scene's first use of other kernels
            g = InProcessGraph(scene, mode, duration, record, namespace, progress,
                               nodes=nodes, fidelity=fidelity, simulator=simulator,
                               sets=sets, intraprocess=transport == "bus")
        roles = _roles(g.nodes)
        sampler = _cpu_sampler(roles)
        try:
            sim = g["simulator"]
            if "recorder" in g.nodes:       # its bag says what it misses, if anything
                g["recorder"].published_counts = lambda: sim.summary()["published"]
            g.spin_until(lambda: sim.finished, stop=stop)
            sim.finish(g.executor)
            sampler.stop()
            if record:
                g.spin_until(g.recorded_all, timeout=10.0, stop=None if stop.set else stop)
            _await_last_answers(g.nodes.get("motor_driver"), g.spin_until,
                                sim.published.get(T.JOINT_STATES, 0), stop)
            for other in ("motor_driver", "controller"):
                if other in g.nodes:
                    g[other].finish(g.executor)           # their final log lines
            driver = g.nodes.get("motor_driver")
            res = RunResult(name, mode, False, record, time.monotonic() - t0,
                            rejected_commands=(driver.rejected if driver else 0) +
                            sim.rejected,
                            rejected=_node_rejections(g.nodes),
                            extra_commands=driver.extra_commands if driver else None,
                            interrupted=stop.set, signal=stop.signal_name,
                            nodes=tuple(g.nodes), sets=sets)
            sim_summary = sim.summary()
            _take_summary(res, sim_summary, namespace)
            _take_cpu(res, sampler, sim_summary, roles, cpus)
        finally:
            sampler.stop()
            g.close()
        if record:
            res.recorded = _bag_counts(record)
            res.missing = missing_messages(res.published, res.recorded)
            res.first_command_s = _first_command_s(record)
        return res
    finally:
        stop.restore()


LAYOUTS = ("one", "split", "processes")
TRANSPORTS = ("bus", "dds")

#: the graph's share of the CPUs above which the summary says why ticks are late: with
#: the busiest CPU at load u a stall of the host of S seconds makes S/(T·(1 − u)) late
#: ticks of period T, four per stalled period at u = 0.75 (twin/cpu_load.py)
BUSY_SHARE = 0.75


#: how long the end of a lockstep run waits for the controller's answers to the last
#: states, and how long without a command counts as "all arrived" when there were extras
ANSWERS_WAIT_S, ANSWERS_QUIET_S = 2.0, 0.2


def _await_last_answers(driver, spin_until, states: int, stop) -> None:
    """Lockstep, the driver in this process: let the controller's answers to every state
    published (``states``) arrive before the driver counts its commands. With extra
    commands the driver answers from its queue and the twin runs ahead of the controller
    by as many states; their answers were still on their way at the end and the count of
    extra commands came out short (5 of 8 in a test). So: at least one command per state,
    and with more than that (extras) until none has come for ANSWERS_QUIET_S; at most
    ANSWERS_WAIT_S in all. A run without extras ends as before."""
    if driver is None or not driver.lockstep or not states:
        return
    seen = [driver.accepted[T.COMMANDS], time.monotonic()]

    def arrived():
        n, now = driver.accepted[T.COMMANDS], time.monotonic()
        if n != seen[0]:
            seen[:] = [n, now]
        return n >= states and (n == states or now - seen[1] >= ANSWERS_QUIET_S)
    spin_until(arrived, timeout=ANSWERS_WAIT_S, stop=None if stop.set else stop)


def _busy_hint(cpu: dict, period_ms: float, layout: str) -> str:
    """Why a realtime run with late ticks had them, where its CPU budget says so: the
    graph took more than BUSY_SHARE of the CPUs, or one process more than BUSY_SHARE of
    a period per tick (a process's Python runs one thread at a time); "" otherwise."""
    busiest, ms = max(cpu["cpu_ms_per_tick"].items(), key=lambda kv: kv[1])
    if cpu["cpu_share"] > BUSY_SHARE:
        why = f"the graph takes {100 * cpu['cpu_share']:.0f} % of the CPUs"
    elif ms > BUSY_SHARE * period_ms:
        why = f"{busiest} takes {ms:.2f} ms of each {period_ms:.3g} ms tick"
    else:
        return ""
    fix = ("--layout one, " if layout == "processes" else "") + \
        "a lower control rate, a coarser model or more CPUs"
    return f" — {why}, so every stall of the host makes a run of late ticks: {fix}"


def _roles(nodes) -> str:
    """The role of a process that runs ``nodes``: their names joined by '+', the
    simulator first."""
    order = GRAPH_NODES + ("recorder",)
    return "+".join(sorted(nodes, key=lambda n: order.index(n) if n in order else 9))


def _compile_once(scene, progress: bool) -> None:
    """On a cold numba cache (a fresh install), compile the plant's and the driver's
    kernels here, once, saying so after 2 s (``progress``): else every node process of
    the graph compiled them at once on a first run (a new-user trial waited 80 s with
    nothing on the screen), and the nodes' start barriers waited on each other meanwhile.
    A warm cache costs nothing here (its loads would cost ~0.9 s: not done)."""
    from flexarm_ros.model.compiled import cache_is_cold
    if not cache_is_cold():
        return
    from flexarm_ros.io.progress import CompileNotice
    from flexarm_ros.twin.cores import DriverCore, SimulatorCore, control_period
    with CompileNotice(enabled=progress):
        SimulatorCore(scene, control_period(scene))
        DriverCore(scene)


def _cpu_sampler(root_role: str):
    from flexarm_ros.twin.cpu_load import CpuSampler
    return CpuSampler(root_role=root_role).start()


def _take_cpu(res: RunResult, sampler, sim: dict | None, sim_role: str,
              cpus: int) -> None:
    """``res.cpu`` from the (stopped) ``sampler``'s readings over the simulator's ticking
    (its summary ``sim``), the simulator's own process taken exactly from its
    ``process_cpu_s`` (``sim_role``: the role its process has in the sampler); ``cpus``:
    how many the graph could run on (this process's affinity when the run began)."""
    from flexarm_ros.twin.cpu_load import cpu_budget
    span = (sim or {}).get("ticking_monotonic_s")
    if not span or not res.ticks or not sampler.samples:
        return
    cpu_s = sampler.between(*span)
    if sim.get("process_cpu_s") is not None:
        cpu_s[sim_role] = sim["process_cpu_s"]
    res.cpu = cpu_budget(cpu_s, res.ticks, span[1] - span[0], cpus)


def default_layout(mode: str) -> str:
    """One process in every mode: on the 2-core host "split" did not keep the wall clock
    measurably better in realtime
    (docs/decisions/0009-the-bag-writer-process-and-the-split-layout.md);
    bench/bench_realtime.py compares the layouts on the machine at hand."""
    return "one"


def _summary_path() -> Path:
    """A fresh path for the simulator process's summary_file (not yet existing)."""
    import tempfile
    tmp = tempfile.NamedTemporaryFile(prefix="flexarm_sim_", suffix=".json", delete=False)
    tmp.close()
    path = Path(tmp.name)
    path.unlink()
    return path


def _run_split(scene, mode, duration, record, namespace, progress, fidelity, simulator,
               nodes, pin, stop, name, t0, cpus, sets=None) -> RunResult:
    """:func:`run` with a :class:`SplitGraph`."""
    from flexarm_ros.twin.recording import missing_messages
    summary_file = _summary_path()
    g = SplitGraph(scene, mode, duration, record, namespace, progress, nodes=nodes,
                   fidelity=fidelity, simulator={**(simulator or {}),
                                                 "summary_file": str(summary_file)},
                   pin=pin, sets=sets)
    sampler = _cpu_sampler(_roles(g.graph.nodes))
    try:
        sim = g.simulator
        g.graph.spin_until(lambda: sim.poll() is not None, stop=stop)
        sampler.stop()
        codes = g.procs.stop()
        conflict = g.procs.conflict()
        sim_summary = _read_summary(summary_file) or {}
        summary_file.unlink(missing_ok=True)
        if "recorder" in g.graph.nodes:
            g.graph["recorder"].published_counts = lambda: sim_summary.get("published")
        if record:           # what the simulator sent is on its way: let it arrive
            g.graph.spin_until(lambda: g.recorded_all(sim_summary.get("published"),
                                                      sim_summary.get("accepted")),
                               timeout=10.0)
        _await_last_answers(g.graph.nodes.get("motor_driver"), g.graph.spin_until,
                            (sim_summary.get("published") or {}).get(T.JOINT_STATES, 0), stop)
        for other in ("motor_driver", "controller"):
            if other in g.graph.nodes:
                g.graph[other].finish(g.graph.executor)
        driver = g.graph.nodes.get("motor_driver")
        res = RunResult(name, mode, False, record, time.monotonic() - t0,
                        rejected_commands=(driver.rejected if driver else 0) + sum(
                            (sim_summary.get("rejected_efforts") or {}).values()),
                        rejected=_node_rejections(g.graph.nodes),
                        extra_commands=driver.extra_commands if driver else None,
                        interrupted=stop.set, signal=stop.signal_name,
                        ended_early=ended_early(codes, stop.set), returncodes=codes,
                        nodes=tuple(n for n in NODES if n in nodes or
                                    (n == "recorder" and record)),
                        cpus=g.procs.placement or None, layout="split",
                        sets=dict(sets or {}))
        if sim_summary:
            _take_summary(res, sim_summary, namespace)
            _take_cpu(res, sampler, sim_summary, "simulator", cpus)
        res.conflict = res.conflict or conflict
        if codes.get("simulator") == 3 and not (res.stalled or res.conflict):
            res.diverged = res.diverged or ("the simulator reported a divergence (its "
                                            "message above)")
    finally:
        sampler.stop()
        g.close()
    if record:
        sim_rej = _bag_rejections(record)
        if sim_rej:
            res.rejected = sim_rej
        res.recorded = _bag_counts(record)
        res.missing = missing_messages(res.published, res.recorded)
        res.first_command_s = _first_command_s(record)
    return res


def ended_early(codes: dict, interrupted: bool) -> dict | None:
    """node -> how it ended, for the nodes a signal from outside the run ended (a node
    stopped so exits 128 + n, see ``stop_file``; one killed outright, -n): not when the
    run itself was interrupted (a terminal's Ctrl-C reaches every node too)."""
    out = {}
    for name, code in codes.items():
        if code is None or interrupted:
            continue
        n = code - 128 if code > 128 else -code if code < 0 else None
        try:
            sig = signal.Signals(n).name if n else None
        except ValueError:
            sig = None
        if sig and code > 128:
            out[name] = f"stopped by {sig} from outside the run (exit status {code})"
        elif sig:
            out[name] = f"killed by {sig}"
    return out or None


def _take_summary(res: RunResult, sim: dict, namespace: str) -> None:
    """Fill ``res`` from the simulator's :meth:`SimulatorNode.summary`; ``published`` under
    the topics' absolute names, as ``recorded``."""
    from flexarm_ros.twin.topics import resolve
    res.sim_s, res.ticks = sim["sim_time_s"], sim["ticks"]
    res.integrator, res.step_s = sim.get("integrator"), sim.get("step_s")
    res.real_time_factor = sim["real_time_factor"]
    res.published = {resolve(namespace, t): n for t, n in sim["published"].items()}
    res.diverged = res.diverged or sim.get("diverged")
    res.end_s = sim.get("end_s")
    if sim.get("stopped_by"):
        res.ended_early = {"simulator": f"stopped by {sim['stopped_by']} from outside the run "
                                        f"at t = {res.sim_s:.6g} s" + (
                                            f" of {res.end_s:.6g} s" if res.end_s else ""),
                           **{k: v for k, v in (res.ended_early or {}).items()
                              if k != "simulator"}}
    res.stalled = res.stalled or sim.get("stalled")
    res.conflict = res.conflict or sim.get("conflict")
    res.twin_seen = sim.get("twin_seen")
    if sim.get("mode") == "realtime":
        res.pacing = {k: sim[k] for k in ("ticks", "late_ticks", "lateness_p50_s",
                                          "lateness_p99_s", "lateness_max_s", "late_policy",
                                          "late_bound_s", "skipped_ticks", "slowed_s",
                                          "effort_waits", "effort_wait_timeouts",
                                          "scheduling")}
        res.overruns = sim["late_ticks"]


def run_with_view(rerun=None, spawn=False, record=None, view_options=None, **kw):
    """:func:`run`, then its bag converted to a rerun recording: the file ``rerun``
    (.rrd) and/or a spawned viewer (``spawn``); see :mod:`flexarm_ros.viz.rerun_view`.
    Without ``record`` the bag is a temporary file, deleted afterwards. rerun-sdk is
    checked, and the viewer started, before the run: ``RerunUnavailable``.
    Returns (RunResult, RerunSummary)."""
    import tempfile

    from flexarm_ros.viz.rerun_view import bag_to_rerun, require_rerun, start_viewer
    start_viewer() if spawn else require_rerun()      # fail before the run, not after
    with tempfile.TemporaryDirectory(prefix="flexarm_run_") as tmp:
        bag = Path(record) if record else Path(tmp) / "run.mcap"
        res = run(record=bag, **kw)
        view = bag_to_rerun(bag, rerun, spawn=spawn, options=view_options)
        if not record:
            res.record = None
    return res, view
