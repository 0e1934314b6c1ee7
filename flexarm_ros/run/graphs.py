"""The twin's graph, started three ways: :class:`InProcessGraph` (every node in this
process on one executor and a private context), :class:`ProcessGraph` (one child process
per node) and :class:`SplitGraph` (the simulator in a child process of its own, the other
nodes in this one); the nodes' names and parameters (:func:`select_nodes`, :func:`awaits`),
and how a child process is started (:func:`die_with_parent`, :func:`cpu_placement`,
:func:`ros_arg`). :mod:`flexarm_ros.run.supervision` runs a graph to its end.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from flexarm_ros.child_process import python_module
from flexarm_ros.nodes import environment
from flexarm_ros.nodes.parameters import fidelity_parameters
from flexarm_ros.scene import DEFAULT_SCENE

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
    if node == "recorder" and graph is not None and "motor_driver" in graph \
            and "controller" not in graph:
        p["await_command_source"] = True        # a user's controller: its first command
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
        # the run's enclave tells its nodes from another run's (nodes/run_enclave.other_twin)
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
        return rec is None or all_arrived(rec.received, self.nodes.values())

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


def ros_arg(name: str, value) -> str:
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
                    cmd += ["-p", f"{k}:={ros_arg(k, v)}"]
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
        node that found one at its start exits 3 and writes it: nodes/lifecycle.tell_the_run),
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
        return rec is None or all_arrived(rec.received, self.graph.nodes.values(),
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


def all_arrived(received: dict, nodes, published: dict | None = None,
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
