"""Plumbing shared by the twin's nodes: QoS, parameters, the start barrier, the mapping
from a message stamp to the simulator's float time, and the ``main()`` of every node
(``--help``, rclpy init, spin, clean shutdown on Ctrl-C / SIGTERM)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
import warnings

with warnings.catch_warnings():
    # rclpy loads message type support through rosidl_generator_py, whose parser (lark)
    # imports the deprecated sre_parse / sre_constants modules: load it once, quietly.
    warnings.filterwarnings("ignore", message="module 'sre_.*' is deprecated",
                            category=DeprecationWarning)
    try:
        import rosidl_generator_py  # noqa: F401
    except ImportError:  # pragma: no cover - other ROS installs
        pass

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

import flexarm_ros.nodes.environment as environment
from flexarm_ros.nodes.parameters import COMMON, FIDELITY, MODES, fidelity_overrides
from flexarm_ros.twin.cores import to_ns, control_period

DEPTH = 10000
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
"""Every topic of the twin: reliable, volatile, keep_last DEPTH (deep enough that nothing
is dropped while a subscriber lags by less than DEPTH messages per topic: a recorder
paused for 5 s, docs/decisions/0026-a-history-deep-enough-for-a-paused-reader.md)."""


def wall_clock():
    """A steady clock for the timers that must run before the twin's first /clock (the
    start barriers): with use_sim_time a node's own clock stands still until then."""
    from rclpy.clock import Clock, ClockType
    return Clock(clock_type=ClockType.STEADY_TIME)


def publisher(node, msgtype: str, topic: str):
    """A publisher with :data:`QOS` and no QoS-event handlers: rclpy's default handlers
    add waitables that every executor wait has to scan (a large share of a lockstep tick,
    docs/decisions/0005-a-lean-executor-and-raw-cdr.md)."""
    from flexarm_ros.nodes._msgconv import msg_class
    from flexarm_ros.nodes.intraprocess import BusPublisher, bus_of
    pub = node.create_publisher(msg_class(msgtype), topic, QOS,
                                event_callbacks=PublisherEventCallbacks(
                                    use_default_callbacks=False))
    bus = bus_of(node.context)
    return pub if bus is None else BusPublisher(bus, node, pub)


def subscription(node, msgtype: str, topic: str, callback, raw: bool = False,
                 plain: bool = False, undecodable=None):
    """A subscription with :data:`QOS` and no QoS-event handlers (see :func:`publisher`);
    with ``raw`` the callback gets the serialized CDR bytes (no message object built), with
    ``plain`` a plain object read from them by :mod:`flexarm_ros.bag.cdr_read` (the same
    attribute paths as rclpy's message, sequences as tuples; the twin's nodes) and bytes
    that are not a message of the type go to ``undecodable(data, info, error)`` (see
    :func:`_decoded`). In a
    process whose nodes share an intra-process bus (:mod:`~flexarm_ros.nodes.intraprocess`)
    a topic published by a member node is delivered in-process."""
    from flexarm_ros.nodes._msgconv import msg_class
    from flexarm_ros.nodes.intraprocess import BusSubscription, bus_of
    events = SubscriptionEventCallbacks(use_default_callbacks=False)
    if plain and not raw:
        callback, raw = _decoded(node, msgtype, topic, callback, undecodable), True
    bus = bus_of(node.context)
    if bus is not None:
        name = node.resolve_topic_name(topic)
        if bus.routes(node, name):
            return BusSubscription(bus, node, msg_class(msgtype), name, callback, raw, QOS,
                                   events)
    taken: list = []
    sub = node.create_subscription(msg_class(msgtype), topic, _draining(callback, taken),
                                   QOS, event_callbacks=events, raw=raw)
    taken.append(sub)
    return sub


def _draining(callback, holder: list):
    """``callback`` as a (message, info) callback that, after the message rclpy's executor
    took, takes and handles every further message queued on its subscription
    (``holder[0]``) — with ``take_message``, the call rclpy's executor itself makes per
    message. One executor round per topic and wake-up instead of one per message: the
    recorder takes a batch per wake-up (docs/decisions/0007-realtime-on-two-cores.md), and
    rclpy's executor builds a wait set and a task per round."""
    from rclpy.exceptions import InvalidHandle

    from flexarm_ros.nodes.intraprocess import with_info
    call = with_info(callback)

    def on_message(msg, info):
        call(msg, info)
        sub = holder[0] if holder else None
        while sub is not None:
            try:
                with sub.handle:
                    more = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:              # destroyed by the callback (a crash)
                return
            if more is None:
                return
            call(*more)
    return on_message


def _decoded(node, msgtype: str, topic: str, callback, undecodable=None):
    """``callback`` fed from raw bytes by :mod:`flexarm_ros.bag.cdr_read` (rclpy's message
    objects cost ~44 µs each on the 2-core host). Bytes that are not a message of the type
    change nothing: ``undecodable(data, info, error)`` counts and logs them as a rejection
    where the subscription has one (the simulator's efforts, the driver's commands:
    :func:`~flexarm_ros.nodes._wire.reject_undecodable`); otherwise they are dropped with a
    throttled warning. ``node.undecodable`` counts them either way."""
    from flexarm_ros.bag.cdr_read import READERS, CdrError
    from flexarm_ros.nodes.intraprocess import with_info
    read = READERS[msgtype]
    call = with_info(callback)
    said = [-1e9]
    node.undecodable = getattr(node, "undecodable", 0)

    def on_bytes(data, info):
        try:
            m = read(data)
        except CdrError as exc:
            node.undecodable += 1
            if undecodable is not None:
                undecodable(data, info, exc)
                return
            now = time.monotonic()
            if now - said[0] >= 1.0:
                said[0] = now
                node.get_logger().warning(
                    f"{topic}: dropped {len(data)} bytes that are not a {msgtype} ({exc}); "
                    f"{node.undecodable} dropped so far, nothing changed")
            return
        call(m, info)
    return on_bytes


def subscriber_names(node, pub) -> list:
    """(node name, namespace) of every subscriber of ``pub``'s topic: on the DDS graph and
    on the process's intra-process bus."""
    out = [(i.node_name, i.node_namespace)
           for i in node.get_subscriptions_info_by_topic(pub.topic_name)]
    local = getattr(pub, "local_subscribers", None)
    return out + (local() if local is not None else [])


def declare(node, params: dict) -> dict:
    """Declare ``{name: (default, description)}`` read-only; return the values."""
    out = {}
    for name, (default, text) in params.items():
        desc = ParameterDescriptor(description=text, read_only=True)
        out[name] = node.declare_parameter(name, default, desc).value
    return out


def load(node, params: dict) -> tuple:
    """Common and fidelity parameters (:mod:`~flexarm_ros.nodes.parameters`) and
    ``params`` → (values, scene with the ``set`` values and then the fidelity overrides
    applied, end tick count or None)."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.scene.overrides import apply_sets, decode_sets
    p = declare(node, {**COMMON, **FIDELITY, **params})
    if p["mode"] not in MODES:
        raise ValueError(f"parameter mode: got {p['mode']!r}, expected one of {MODES}")
    scene = apply_sets(load_scene(p["scene"]), decode_sets(p["set"])).with_fidelity(
        **fidelity_overrides(p))
    dur = p["duration"] or scene.duration
    n = None if dur == float("inf") else int(round(dur / control_period(scene)))
    return p, scene, n


def tick_of(scene, t_ns: int) -> int:
    return int(round(t_ns * 1e-9 / control_period(scene)))


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SimTime:
    """The simulator core's time of a tick, bit for bit. The plant advances on its integer
    grid (t = k·g·1e-9, :func:`~flexarm_ros.sim.plant.plant_grid_ns`); replaying that lets
    the controller and driver use the very float the core used (``__call__``: stamp → t)
    and the recorder stamp tick n (``tick_ns``), so a lockstep run equals
    :func:`~flexarm_ros.twin.cosim.cosimulate` exactly."""

    def __init__(self, scene):
        from flexarm_ros.sim.plant import plant_grid_ns
        self.grid = plant_grid_ns(scene)
        self.period = control_period(scene)
        self.per_tick = int(round(self.period * 1e9 / self.grid)) if self.grid else 0
        self._t = self._tick_t = 0.0
        self._ticks = [0]                                  # ns of tick n (no grid)

    def __call__(self, t_ns: int) -> float:
        if self.grid:
            return t_ns * 1e-9
        while to_ns(self._t) < t_ns:
            self._t += self.period
        return self._t if to_ns(self._t) == t_ns else t_ns * 1e-9

    def tick_ns(self, n: int) -> int:
        if self.grid:
            return n * self.per_tick * self.grid
        while len(self._ticks) <= n:
            self._tick_t += self.period
            self._ticks.append(to_ns(self._tick_t))
        return self._ticks[n]


GRAPH = ("simulator", "controller", "motor_driver", "recorder")


class WaitWarning:
    """When a wait for the start should be said at WARN level: first after
    ``after`` s, then every ``every`` s (the start barriers and the driver's wait for a
    controller share it)."""

    def __init__(self, after: float = 3.0, every: float = 5.0):
        self.since, self.after, self.every = time.monotonic(), after, every
        self._said = None                       # when the last WARN was said (waited s)

    def due(self) -> float | None:
        """The seconds waited when a WARN is due now (and counted as said), else None."""
        waited = time.monotonic() - self.since
        if waited > self.after and (self._said is None or waited - self._said > self.every):
            self._said = waited
            return waited
        return None


def other_types(node, topic: str, msgtype: str, kind: str = "publisher") -> str:
    """What a wait for a ``kind`` ("publisher" or "subscription") on ``topic`` should add
    when the graph holds one of another type there: DDS never matches endpoints of
    different types, so such a node waits unseen (a controller publishing
    Float32MultiArray commands, met in a new-user trial); "" when there is none."""
    try:
        infos = (node.get_publishers_info_by_topic(topic) if kind == "publisher" else
                 node.get_subscriptions_info_by_topic(topic))
    except Exception:                            # a graph query is advice, never a failure
        return ""
    wrong = sorted({(i.node_name, i.topic_type) for i in infos if i.topic_type != msgtype})
    if not wrong:
        return ""
    return ("; on it " + ", ".join(f"{name or '?'} has a {kind} of {typ}" for name, typ in wrong)
            + f", which DDS never connects to {msgtype}")


def _type_name(pub) -> str:
    """'pkg/msg/Name' of a publisher's message type (the twin's BusPublisher or rclpy's)."""
    cls = getattr(pub, "msg_type", None) or getattr(getattr(pub, "pub", None), "msg_type", None)
    if cls is None:
        return ""
    mod = cls.__module__.split(".")                 # e.g. std_msgs.msg._float64_multi_array
    return f"{mod[0]}/msg/{cls.__name__}"


#: s a start condition waits at least, so that DDS discovery shows another run's nodes on
#: the domain before this one starts: in one process a twin's own nodes match at once
#: (in-process), and a second twin started beside a running one had started before it
#: saw the first, whose driver then took its commands for up to ALONE_CHECK_S (once
#: seen diverging in CI, issue 39)
DISCOVERY_SETTLE_S = 0.5


class Barrier:
    """The start condition of a node: true once every publisher in ``needs`` — (publisher,
    subscribers it needs, who they are) — has that many matched subscriptions and, with
    ``recorders``, the graph shows the recorder of this namespace subscribed to it (a
    foreign subscriber must not stand in for it); then stays true. A wait longer than
    :data:`WARN_AFTER_S` is logged at WARN level (a need may be a callable of the graph), naming each topic, the subscribers it
    has and needs, and whom it waits for; again every few seconds. ``inputs`` —
    (subscription, who publishes there) — are subscriptions that need a matched publisher
    too (the lockstep simulator's effort input: it must hear the answer to its first
    state, so it does not start before its reader there is open and matched)."""

    WARN_AFTER_S = 3.0

    def __init__(self, node, needs, recorders=0, inputs=()):
        self.inputs = list(inputs)
        self.node, self.ok = node, False
        self.needs = [(p, n, who) for p, n, *rest in needs if callable(n) or n > 0
                      for who in [rest[0] if rest else "subscribers"]]
        self.recorders = recorders
        self._warn = WaitWarning(self.WARN_AFTER_S)
        self.missing: list = []                 # what the last call found missing

    @property
    def since(self) -> float:
        """Monotonic time the wait began."""
        return self._warn.since

    def _missing(self, pub, n, who) -> str | None:
        n = n() if callable(n) else n            # a need that depends on the graph
        who = who() if callable(who) else who    # ... and a text that does
        have = pub.get_subscription_count()
        if have < n:
            return (f"{pub.topic_name} ({have}/{n} subscribers: {who}"
                    + other_types(self.node, pub.topic_name, _type_name(pub), "subscription")
                    + ")")
        if self.recorders:
            ns = self.node.get_namespace()
            if not any(name == "recorder" and nns == ns
                       for name, nns in subscriber_names(self.node, pub)):
                return f"{pub.topic_name} (the recorder in {ns})"
        return None

    conflict = None       # another twin in this namespace and domain: never starts

    def __call__(self) -> bool:
        if not self.ok and self.conflict is None:
            missing = [m for p, n, who in self.needs if (m := self._missing(p, n, who))]
            missing += [f"{sub.topic_name} (0/1 publishers matched: {who})"
                        for sub, who in self.inputs if sub.get_publisher_count() < 1]
            if not missing and time.monotonic() - self.since < DISCOVERY_SETTLE_S:
                return False                # another run's nodes may not be seen yet
            if not missing:                 # what met the needs may be another twin's
                self.conflict = other_twin(self.node)
                if self.conflict:
                    self.node.conflict = f"not started: {self.conflict}"
                    self.node.get_logger().error(self.node.conflict)
                    return False
            self.ok, self.missing = not missing, missing
            waited = missing and self._warn.due()
            if waited:
                self.node.get_logger().warning(
                    f"not started after {waited:.0f} s: waiting for " + ", ".join(missing))
        return self.ok


class ShutdownGuard:
    """Bounds a node process's exit once its work is done (its loop ended; the recorder:
    its bag finalized). Should the rest — the final log line, the executor's and the DDS
    participant's teardown, exit handlers — hang for ``limit_s`` (seen once under a full
    test suite's load: a motor driver that a Ctrl-C had stopped was still alive 15 s
    later, and ``flexarm run --processes`` had to SIGKILL it), the guard prints every
    thread's stack to stderr, saying so, and ends the process with the status the node
    earned (3 after a divergence or a stall, else 0), before the parent's own 15 s."""

    LIMIT_S = 8.0

    def __init__(self, name: str, node, limit_s: float | None = None):
        self.name, self.node = name, node
        self.limit_s = self.LIMIT_S if limit_s is None else limit_s
        t = threading.Timer(self.limit_s, self._fire)
        t.daemon = True
        t.start()

    def _fire(self):
        import faulthandler
        import os
        limit = self.limit_s
        try:
            print(f"{self.name}: its work is done but the process has not exited {limit:g} "
                  f"s later (DDS or executor teardown hung); ending it. Where each thread "
                  f"was:", file=sys.stderr, flush=True)
            faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
            sys.stderr.flush()
        finally:
            bad = getattr(self.node, "diverged", None) or getattr(self.node, "stalled", None)
            os._exit(3 if bad else 0)


class StopFlag:
    """SIGINT / SIGTERM set the flag (the spin loop then shuts down cleanly) instead of
    raising inside a callback; the previous handlers come back with ``restore()``."""

    def __init__(self):
        self.set = False
        self.signum = None
        self._old = {}
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)

    def _handle(self, signum, frame):
        if self.set and signum == signal.SIGINT:      # second Ctrl-C: give up at once
            raise KeyboardInterrupt
        self.set, self.signum = True, signum

    @property
    def signal_name(self) -> str | None:
        """'SIGINT', 'SIGTERM', or None while no signal came."""
        return signal.Signals(self.signum).name if self.signum else None

    def restore(self):
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}


#: the enclave of a run's nodes: this prefix and a random token (run.py, new_run_enclave)
RUN_ENCLAVE_PREFIX = "/flexarm_run_"
#: the names of the twin's nodes
TWIN_NODES = ("simulator", "motor_driver", "controller", "recorder")


def new_run_enclave() -> str:
    """A fresh enclave for the nodes of one run: the prefix, the run's start in ms of
    wall time (which of two runs came first), the pid of the process that started it
    (whether it still runs) and a random token."""
    import secrets
    return (f"{RUN_ENCLAVE_PREFIX}{int(time.time() * 1000)}_{os.getpid()}_"
            f"{secrets.token_hex(3)}")


def _started_ms(enclave: str) -> int:
    """The start time a run enclave carries (0 for one without)."""
    try:
        return int(enclave[len(RUN_ENCLAVE_PREFIX):].split("_")[0])
    except ValueError:
        return 0


def _running(enclave: str) -> bool:
    """Whether the run of ``enclave`` still runs: the process that started it is alive
    (discovery is loopback-only, so it is on this machine). A run killed outright leaves
    its nodes on the graph until their DDS lease ends (~20 s); they are not a twin."""
    try:
        pid = int(enclave[len(RUN_ENCLAVE_PREFIX):].split("_")[1])
    except (ValueError, IndexError):
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def other_twin(node, older_only: bool = False) -> str | None:
    """What the graph shows of another twin in ``node``'s namespace on its domain, else
    None: a twin's node there in another run's enclave (``run_enclave``), or a second node
    named ``simulator`` (twins started by hand). Two twins there would take each other's
    messages — their topics and node names are the same, and neither a user's node nor
    RViz could tell them apart — so a node does not start beside another twin, and a
    running simulator stops its run when it finds a twin that started before it
    (``older_only``: it slipped past its start condition before discovery showed the
    other; docs/decisions/0027-one-twin-per-namespace-and-domain.md)."""
    ns = node.get_namespace()
    mine = getattr(node, "p", {}).get("run_enclave", "")
    here = [(name, enc) for name, nns, enc in node.get_node_names_and_namespaces_with_enclaves()
            if nns == ns and name in TWIN_NODES]
    others = sorted({enc for _, enc in here if mine and enc != mine
                     and enc.startswith(RUN_ENCLAVE_PREFIX) and _running(enc)
                     and not (older_only and (_started_ms(enc), enc) > (_started_ms(mine),
                                                                          mine))})
    # nodes started by hand (no run enclave): a second simulator is the only sign
    sims = 0 if mine else sum(1 for name, _ in here if name == "simulator")
    if not others and sims <= 1:
        return None
    what = (", ".join(f"{sorted(n for n, e in here if e == enc)} of the run in enclave {enc}"
                      for enc in others) if others else f"{sims} nodes named simulator")
    return (f"another twin runs in namespace {ns} on ROS_DOMAIN_ID "
            f"{node.context.get_domain_id()} ({what}): two twins there take each other's "
            f"messages; give one of them another --namespace or ROS_DOMAIN_ID")


def tell_the_run(node, text: str) -> None:
    """For ``flexarm run``, which started this node as a process: one line of why it
    ended, appended to ``<stop_file>.conflict`` (run.ProcessGraph.conflict)."""
    path = getattr(node, "p", {}).get("stop_file")
    if path:
        try:
            with open(path + ".conflict", "a") as f:
                f.write(f"{node.get_name()}: {text}\n")
        except OSError:
            pass


def stopped_from_outside(stop: StopFlag, node) -> str | None:
    """The name of the signal that stopped a node ``flexarm run`` started as a process
    when the run did not send it (its ``stop_file`` does not exist yet: the run creates it
    before it stops its nodes), else None."""
    path = getattr(node, "p", {}).get("stop_file") if node is not None else None
    if not (stop.set and stop.signum and path) or os.path.exists(path):
        return None
    return signal.Signals(stop.signum).name


def make_executor(context, kind="twin"):
    """The executor of the twin's nodes: ``"twin"`` (default),
    :class:`~flexarm_ros.nodes.executor.TwinExecutor` (rclpy's SingleThreadedExecutor that
    also runs the intra-process bus, where one is installed); ``"single"``, rclpy's
    SingleThreadedExecutor; ``"events"``, rclpy's experimental EventsExecutor (fails on
    callbacks that take a MessageInfo, i.e. on the twin's nodes: kept for measurements)."""
    if kind == "twin":
        from flexarm_ros.nodes.executor import TwinExecutor
        return TwinExecutor(context)
    if kind == "events":
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind != "single":
        raise ValueError(f"executor: got {kind!r}; expected 'twin', 'single' or 'events'")
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor(context=context)


PROFILE_ENV = "FLEXARM_PROFILE_DIR"


class profiled:
    """With ``$FLEXARM_PROFILE_DIR`` set, profile the node's spinning (cProfile) and write
    ``<dir>/<executable>.prof`` (``python -m pstats``): where a node process's CPU goes,
    measured in the run itself. A thread profiles itself: the realtime simulator's pacing
    thread writes ``simulator-pacer.prof``."""

    def __init__(self, name: str):
        import os
        self.path = None
        d = os.environ.get(PROFILE_ENV)
        if d:
            try:
                os.makedirs(d, exist_ok=True)
                self.path = os.path.join(d, f"{name}.prof")
            except OSError as exc:        # a profiling aid never stops a node
                print(f"{name}: {PROFILE_ENV}={d!r}: {exc.strerror or exc}; expected a "
                      f"writable directory (not profiling)", file=sys.stderr)
        self.prof = None

    def __enter__(self):
        if self.path:
            import cProfile
            self.prof = cProfile.Profile()
            self.prof.enable()
        return self

    def __exit__(self, *exc):
        if self.prof is not None:
            self.prof.disable()
            self.prof.dump_stats(self.path)
        return False


def node_main(cls, args=None):
    """``main()`` of a node's process: ``--help``, init, spin until done or stopped, shut
    down, then end the process with the exit status (it does not return): exit handlers
    run and streams are flushed, the interpreter's teardown is skipped (1–2 s per node
    on a loaded machine, mostly DDS and extension modules), so the nodes of a stopped
    graph are gone at once."""
    code = _node_main(cls, args)
    import atexit
    import os
    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):
                pass
        os._exit(code if isinstance(code, int) else 1)


def _node_main(cls, args=None) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args
    argv = list(sys.argv if args is None else args)
    params = {**COMMON, **FIDELITY, **getattr(cls, "PARAMS", {})}
    epilog = "parameters (--ros-args -p name:=value):\n" + "\n".join(
        f"  {k} (default {v[0]!r}): {v[1]}" for k, v in params.items())
    mod_doc = (sys.modules[cls.__module__].__doc__ or "").strip().split("\n\n")
    ap = argparse.ArgumentParser(
        prog=cls.EXECUTABLE, formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(cls.__doc__ or "").strip().splitlines()[0] + "\n\n" +
        "\n\n".join(mod_doc[1:2]),
        epilog=epilog + f"\n\nexample: ros2 run flexarm_ros {cls.EXECUTABLE} --ros-args "
                        "-r __ns:=/flexarm -p scene:=two_link_position -p mode:=realtime")
    ap.parse_args(remove_ros_args(argv)[1:])
    environment.use_loopback()
    ctx = Context()
    rclpy.init(args=argv, context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    from flexarm_ros.nodes.bridge import attach_from_environment
    bus = attach_from_environment(ctx)      # `flexarm run --layout split`'s simulator
    stop = StopFlag()
    node = None
    try:
        from rclpy.exceptions import ParameterException
        try:
            node = cls(context=ctx)
        except (ValueError, OSError, ParameterException) as exc:    # InputError: ValueError
            print(f"{cls.EXECUTABLE}: error: {exc}", file=sys.stderr)
            return 2
        exe = make_executor(ctx)
        exe.add_node(node)
        # a node that need not answer at once (the recorder) pauses between drains: one
        # wake-up takes a batch of messages instead of one (measured: the recorder's CPU
        # per tick at 1 kHz fell from 650 to 360 µs,
        # docs/decisions/0007-realtime-on-two-cores.md)
        pause = float(getattr(node, "spin_pause_s", 0.0))
        with profiled(cls.EXECUTABLE):
            while ctx.ok() and not stop.set and not getattr(node, "finished", False) \
                    and not getattr(node, "conflict", None):
                if pause > 0:
                    exe.spin_ready(timeout_sec=0.1)     # the batch, then the pause
                    time.sleep(pause)
                else:
                    exe.spin_once(timeout_sec=0.1)
        # the node's work is done: from here its exit is bounded (the recorder's from
        # when its bag is finalized, below)
        if not hasattr(node, "close"):
            ShutdownGuard(cls.EXECUTABLE, node)
        outside = stopped_from_outside(stop, node)
        if outside:
            node.stopped_by = outside           # the simulator's summary names it
        if hasattr(node, "finish"):
            node.finish(exe)
        if bus is not None:
            bus.flush()
        exe.shutdown()
        diverged = getattr(node, "diverged", None)
        if diverged is not None:                 # like flexarm simulate: the message, 3
            print(f"{cls.EXECUTABLE}: {diverged}", file=sys.stderr)
            return 3
        if getattr(node, "stalled", None):       # lockstep without answers: the message, 3
            print(f"{cls.EXECUTABLE}: {node.stalled}", file=sys.stderr)
            return 3
        if getattr(node, "conflict", None):      # another twin on this graph: 3
            print(f"{cls.EXECUTABLE}: {node.conflict}", file=sys.stderr)
            tell_the_run(node, node.conflict)
            return 3
        if outside:                              # killed from outside the run: say so
            where = getattr(node, "where", None)
            print(f"{cls.EXECUTABLE}: stopped by {outside} from outside the run"
                  + (f" {where()}" if where else ""), file=sys.stderr)
            return 128 + stop.signum
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        # Shutting down: a further SIGINT/SIGTERM (a second Ctrl-C; the SIGTERM with which
        # `flexarm run --processes` stops nodes that a terminal's Ctrl-C already reached)
        # must neither interrupt the recorder finalizing its bag nor kill the exit. This
        # is the process's main, so they stay ignored until the process ends.
        stop.restore()
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                signal.signal(s, signal.SIG_IGN)
        if node is not None:
            if hasattr(node, "close"):
                node.close()
                ShutdownGuard(cls.EXECUTABLE, node)
            node.destroy_node()
        if ctx.ok():
            rclpy.shutdown(context=ctx)
