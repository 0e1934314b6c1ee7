"""A run of the twin's graph from start to end: :func:`run` checks the arguments and the
scene, starts the graph in its layout (:data:`LAYOUTS`), waits for the simulator to finish
or for SIGINT/SIGTERM (:class:`~flexarm_ros.nodes.common.StopFlag`), lets the last
answers and recorded messages arrive, stops the nodes and says how each ended
(:func:`ended_early`), recovers a bag its recorder left unfinished
(:func:`recover_killed_bag`) and returns the :class:`~flexarm_ros.run.result.RunResult`;
:func:`run_with_view` converts the run's bag for rerun afterwards.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from flexarm_ros.nodes.parameters import MODES
from flexarm_ros.run.graphs import (DEFAULT_NAMESPACE, GRAPH_NODES, NODES, InProcessGraph,
                                    ProcessGraph, SplitGraph)
from flexarm_ros.run.result import (RunResult, bag_counts, bag_first_command_s,
                                    bag_rejections, cpu_sampler, read_summary, take_cpu,
                                    take_summary)
from flexarm_ros.scene import DEFAULT_SCENE
from flexarm_ros.twin import topics as T

def _node_rejections(nodes) -> dict:
    """topic -> {reason: count} over the graph's nodes (absolute topic names)."""
    out: dict = {}
    for name in ("simulator", "motor_driver", "controller"):
        node = nodes.get(name)
        rej = getattr(node, "rejections", None)
        for topic, by in (rej.counts.items() if rej is not None else ()):
            out.setdefault(topic, {}).update(by)
    return out


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
            if res is not None and (res.ticks or recorded_data(res.recorded)):
                previous.unlink()
            elif res is not None or not path.exists():
                os.replace(previous, path)
                if res is not None:
                    res.kept_previous = True
            # else: an error after a new bag began: both stay


def recorded_data(recorded: dict | None) -> int:
    """Messages a bag holds besides the twin's diagnostics: a run refused before its first
    tick (another twin on the graph) records its refusals on ``diagnostics/rejected``
    and nothing else, and must not cost the bag that was there (a new-user trial lost a
    12.6 MB bag that way)."""
    return sum(n for topic, n in (recorded or {}).items()
               if not topic.endswith("/" + T.REJECTED))


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
    note = layout_note(layout, mode, cpus)
    if progress and note:
        print(note, file=sys.stderr, flush=True)
    stop = StopFlag()
    try:
        if processes:
            summary_file = _summary_path()
            g = ProcessGraph(scene, mode, duration, record, namespace, progress,
                             nodes=nodes, fidelity=fidelity, sets=sets,
                             simulator={**(simulator or {}),
                                        "summary_file": str(summary_file)},
                             pin=(mode == "realtime") if pin is None else pin)
            sampler = cpu_sampler("run")
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
            sim_summary = read_summary(summary_file)
            summary_file.unlink(missing_ok=True)
            if sim_summary:
                take_summary(res, sim_summary, namespace)
                take_cpu(res, sampler, sim_summary, "simulator", cpus)
            res.conflict = res.conflict or conflict
            if codes.get("simulator") == 3 and not (res.stalled or res.conflict):
                res.diverged = res.diverged or ("the simulator reported a divergence (its "
                                                "message above)")
            if record:
                res.rejected = bag_rejections(record)
                res.recorded = bag_counts(record)
                res.missing = missing_messages(res.published, res.recorded)
                res.first_command_s = bag_first_command_s(record)
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
        sampler = cpu_sampler(roles)
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
            take_summary(res, sim_summary, namespace)
            take_cpu(res, sampler, sim_summary, roles, cpus)
        finally:
            sampler.stop()
            g.close()
        if record:
            res.recorded = bag_counts(record)
            res.missing = missing_messages(res.published, res.recorded)
            res.first_command_s = bag_first_command_s(record)
        return res
    finally:
        stop.restore()


LAYOUTS = ("one", "split", "processes")
TRANSPORTS = ("bus", "dds")


#: how long the end of a lockstep run waits for the controller's answers to the last
#: states, and how long without a command counts as "all arrived" when there were extras
ANSWERS_WAIT_S, ANSWERS_QUIET_S = 2.0, 0.2


def _await_last_answers(driver, spin_until, states: int, stop) -> None:
    """Lockstep, the driver in this process: let the controller's answers to every state
    published (``states``) arrive before the driver counts its commands. With extra
    commands the driver answers from its queue and the twin runs ahead of the controller
    by as many states; their answers were still on their way at the end and the count of
    extra commands came out short (5 of 8 in a test). So: at least one command per state,
    and when the driver ran ahead (a state found a command waiting, ``ran_ahead``) or more
    commands than states came, until none has come for ANSWERS_QUIET_S; at most
    ANSWERS_WAIT_S in all. A run without extras ends as before. (Exactly one command per
    state so far is not enough to stop: with 8 extras the driver had used every command it
    had, the controller's last 8 answers on their way, and the count came out 0 of 8 in 1
    of 6 runs, session 27.)"""
    if driver is None or not driver.lockstep or not states:
        return
    seen = [driver.accepted[T.COMMANDS], time.monotonic()]

    def arrived():
        n, now = driver.accepted[T.COMMANDS], time.monotonic()
        if n != seen[0]:
            seen[:] = [n, now]
        return n >= states and ((n == states and not driver.ran_ahead)
                                or now - seen[1] >= ANSWERS_QUIET_S)
    spin_until(arrived, timeout=ANSWERS_WAIT_S, stop=None if stop.set else stop)


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


#: CPUs below which ``--processes`` in realtime is told it will fall behind (five
#: processes at 2.2 ms of CPU per 1 ms tick on 2 cores; decision 0031)
PROCESSES_REALTIME_CPUS = 4


def layout_note(layout: str, mode: str, cpus: int) -> str | None:
    """The line a run prints before it starts when its layout cannot keep the clock on
    this many CPUs (None: nothing to say)."""
    if layout == "processes" and mode == "realtime" and cpus < PROCESSES_REALTIME_CPUS:
        return (f"note: realtime with one process per node on {cpus} CPUs: measured at "
                f"1 kHz on 2 cores it needs ~2.2 ms of CPU per 1 ms tick and falls behind "
                f"(docs/decisions/0031-three-layouts-kept.md); --layout one keeps the "
                f"clock best here (split only on an otherwise idle machine)")
    return None


def default_layout(mode: str) -> str:
    """One process in every mode: the only layout that keeps the wall clock beside other
    work; split starts a few more ticks on time on an idle host
    (docs/decisions/0031-three-layouts-kept.md); bench/bench_realtime.py compares the
    layouts on the machine at hand."""
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
    sampler = cpu_sampler(_roles(g.graph.nodes))
    try:
        sim = g.simulator
        g.graph.spin_until(lambda: sim.poll() is not None, stop=stop)
        sampler.stop()
        codes = g.procs.stop()
        conflict = g.procs.conflict()
        sim_summary = read_summary(summary_file) or {}
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
            take_summary(res, sim_summary, namespace)
            take_cpu(res, sampler, sim_summary, "simulator", cpus)
        res.conflict = res.conflict or conflict
        if codes.get("simulator") == 3 and not (res.stalled or res.conflict):
            res.diverged = res.diverged or ("the simulator reported a divergence (its "
                                            "message above)")
    finally:
        sampler.stop()
        g.close()
    if record:
        sim_rej = bag_rejections(record)
        if sim_rej:
            res.rejected = sim_rej
        res.recorded = bag_counts(record)
        res.missing = missing_messages(res.published, res.recorded)
        res.first_command_s = bag_first_command_s(record)
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
