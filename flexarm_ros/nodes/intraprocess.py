"""Intra-process delivery between the twin's nodes when they share one process.

Why (measured, ``docs/decisions/0008-an-intra-process-bus.md``): on the 2-core host, a
DDS publish with one reliable reader cost 25 µs of CPU back to back and 70–90 µs at a
1 kHz pace (5 µs with no reader), and each reader pays again to take the message. The
twin's tick sends ~12 messages, most to two readers (a consumer and the recorder): the
one-process graph reached a real-time factor of 0.34 with the recorder and 0.60 without,
where the same cores without ROS run at 1700 ticks/s. rclcpp solves this with its
intra-process manager (a publisher hands the message to the subscriptions of its own
process; DDS carries it only to other processes); rclpy has none, so this module is the
twin's.

Rule: a topic whose source node (:data:`flexarm_ros.twin.topics.SOURCE`) is a member of
the process's :class:`Bus` is delivered in-process to the subscribers of that process:
the publisher still publishes every message on DDS while the graph shows a DDS reader of
the topic (a foreign ``ros2 topic echo``, a user's node, another process see everything,
unchanged; the readers are looked up every :data:`GRAPH_POLL_S`, so one that joins misses
at most that much more than any late-joining volatile reader), and the in-process subscriber
gets the same bytes with the same kind of ``MessageInfo`` (a source timestamp from the
host's real-time clock, as DDS's, and the publisher's GID), so the nodes' source rule,
validation and the recorder's stamping do not change. Such a subscription has no DDS
reader while only the process's own node publishes the topic; when the graph shows
another publisher (a stray ``ros2 topic pub``, a user's second controller), it opens its
DDS reader — which drops the in-process publisher's copies by GID — so a foreign
message is still taken, refused or rejected exactly as before (checked every
:data:`GRAPH_POLL_S` of wall time; like any late-joining DDS reader it misses what the
foreign node sent before the match).

Deliveries are queued and run by :class:`~flexarm_ros.nodes.executor.TwinExecutor`
(never inside ``publish``: a lockstep tick would otherwise recurse through the whole
run), first in, first out across topics; a publish from another thread (the realtime
pacing thread) wakes the executor (rclpy's public ``Executor.wake``).
"""

from __future__ import annotations

import inspect
import threading
import time
import weakref
from collections import deque

from flexarm_ros.twin import topics as T

GRAPH_POLL_S = 0.1

_BUSES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def install(context, members) -> "Bus":
    """Give ``context`` a bus whose members are ``members``: (namespace, node name)."""
    bus = Bus(context, members)
    _BUSES[context] = bus
    return bus


def bus_of(context) -> "Bus | None":
    return _BUSES.get(context)


def gid_of(info) -> bytes | None:
    """The publisher GID of a message (``MessageInfo``), or None when rmw gives none."""
    if not info:
        return None
    try:                                  # a dict (rclpy's MessageInfo, the bus's info)
        data = info["publisher_gid"]["data"]
    except (TypeError, KeyError, IndexError):
        return None
    if data is None:
        return None
    return data if type(data) is bytes else bytes(data)


def _relative(ns: str, topic_abs: str) -> str:
    prefix = "/" + ns.strip("/") + "/" if ns.strip("/") else "/"
    return topic_abs[len(prefix):] if topic_abs.startswith(prefix) else topic_abs


class Bus:
    """The in-process subscriptions and publishers of one context, and the queue of
    deliveries :meth:`deliver` runs."""

    def __init__(self, context, members):
        self.context = context
        self.members = {(("/" + ns.strip("/")) if ns.strip("/") else "/", name)
                        for ns, name in members}
        self.subs: dict = {}            # absolute topic -> [BusSubscription]
        self.pubs: dict = {}            # absolute topic -> [BusPublisher]
        # the order of deliveries: one entry per message queued, naming its subscription;
        # the message waits in that subscription's inbox (bounded by its QoS depth)
        self.queue: deque = deque()
        self.waker = None               # the executor's wake (rclpy's public Executor.wake)
        self.spinning_thread = None     # set by the executor
        self.lock = threading.RLock()    # held by deliveries and the executor's callbacks
        self.self_delivering: set = set()   # threads that run deliver_all after publishing
        self._delivering = False
        self._polled = 0.0
        self._last_ts = 0
        self.bridge = None              # the other process's bus (bridge.attach)

    def flush(self) -> None:
        """Send what is buffered for the other process (no-op without a bridge)."""
        if self.bridge is not None:
            self.bridge.flush()

    # ------------------------------------------------------------------ routing
    def routes(self, node, topic_abs: str) -> bool:
        """The topic's source node is a member in ``node``'s namespace."""
        ns = node.get_namespace()
        rel = topic_abs if topic_abs == T.CLOCK else _relative(ns, topic_abs)
        src = T.SOURCE.get(rel)
        return src is not None and (ns, src) in self.members

    def timestamp(self) -> int:
        """The host's real-time clock in ns (DDS's source-timestamp clock), strictly
        increasing: the recorder orders messages against /clock by it."""
        ts = time.time_ns()
        if ts <= self._last_ts:
            ts = self._last_ts + 1
        self._last_ts = ts
        return ts

    def post(self, topic_abs: str, data: bytes, info: dict) -> None:
        subs = self.subs.get(topic_abs)
        if not subs:
            return
        me = threading.current_thread()
        wake = not self.queue and not self._delivering and \
            me is not self.spinning_thread and me not in self.self_delivering
        for s in subs:
            if s.enqueue(data, info):
                self.queue.append(s)
        if wake:
            self.wake()

    def wake(self) -> None:
        """Wake the executor that runs the deliveries (a post from another thread)."""
        waker = self.waker
        if waker is not None:
            waker()

    def deliver(self, limit: int | None = None) -> int:
        """Run up to ``limit`` queued deliveries (all queued now: None); the number run.
        One thread at a time (a node's callbacks never run concurrently)."""
        with self.lock:
            self._delivering = True
            try:
                n = len(self.queue) if limit is None else min(limit, len(self.queue))
                q = self.queue
                for _ in range(n):
                    sub = q.popleft()
                    if sub.inbox and not sub.destroyed:
                        sub.receive(*sub.inbox.popleft())
            finally:
                self._delivering = False
        return n

    def deliver_all(self, slice_s: float = 0.05) -> None:
        """Rounds of :meth:`deliver` until nothing is queued (or ``slice_s`` of wall time
        passed). The executor's first step; and the realtime simulator's pacing thread
        runs its tick's consequences — the controller's command, the driver's effort, the
        recorder's writes — with it, in order, as ros2_control's update loop does, instead
        of handing them to the executor thread (one GIL hand-over and one wake-up less per
        message)."""
        end = time.monotonic() + slice_s
        while self.queue and time.monotonic() < end:
            self.deliver()
        if self.bridge is not None:
            self.bridge.flush()

    def poll_graph(self) -> None:
        """Open the DDS reader of a subscription whose topic got a foreign publisher."""
        now = time.monotonic()
        if now - self._polled < GRAPH_POLL_S:
            return
        self._polled = now
        for topic, subs in list(self.subs.items()):
            local = len(self.pubs.get(topic, ()))
            if self.bridge is not None:
                local += self.bridge.remote_publishers(topic)
            for s in subs:
                if s.dds is None and not s.destroyed and \
                        s.node.count_publishers(topic) > local:
                    s.open_dds()

    def remove_node(self, node) -> None:
        """Forget a node's endpoints (its queued deliveries are dropped)."""
        for table in (self.subs, self.pubs):
            for topic, items in table.items():
                for e in [e for e in items if e.node is node]:
                    e.destroyed = True
                    items.remove(e)

    def local_gids(self, topic_abs: str) -> set:
        gids = {p.gid for p in self.pubs.get(topic_abs, ()) if p.gid is not None}
        if self.bridge is not None:
            gids |= self.bridge.remote_gids.get(topic_abs, set())
        return gids

    def local_publishers(self, topic_abs: str, name: str, ns: str) -> set:
        """GIDs of this run's publishers of ``topic_abs`` in node ``ns``/``name``: the
        bus's own and those the bridge's other process announced (the source rule's
        "this run", :mod:`~flexarm_ros.nodes._wire`)."""
        gids = {p.gid for p in self.pubs.get(topic_abs, ())
                if p.gid is not None and p.node.get_name() == name
                and p.node.get_namespace() == ns}
        if self.bridge is not None:
            gids |= {g for g, who in self.bridge.remote_publisher_names(topic_abs).items()
                     if who == (name, ns)}
        return gids


class BusPublisher:
    """A DDS publisher whose messages also go to the in-process subscribers of its topic."""

    def __init__(self, bus: Bus, node, pub):
        self.bus, self.node, self.pub = bus, node, pub
        self.topic = pub.topic_name
        self.destroyed = False
        self._gid = None
        self._dds_readers, self._readers_due = 0, 0.0
        bus.pubs.setdefault(self.topic, []).append(self)
        if bus.bridge is not None:
            bus.bridge.announce_pub(self)
            bus.bridge.flush()

    @property
    def gid(self):
        """The DDS publisher's GID, from the graph (its own endpoint, known at once)."""
        if self._gid is None:
            name, ns = self.node.get_name(), self.node.get_namespace()
            for info in self.node.get_publishers_info_by_topic(self.topic):
                if info.node_name == name and info.node_namespace == ns:
                    self._gid = bytes(info.endpoint_gid)
        return self._gid

    def publish(self, data) -> None:
        # on DDS only while the graph shows a reader there (looked up every GRAPH_POLL_S):
        # a publish with none still costs rclpy's call and Fast DDS's history, ~6–8 µs a
        # message, 8 % of a one-process realtime tick (py-spy, session 17); a reader that
        # joins misses at most GRAPH_POLL_S more than any late-joining volatile reader
        now = time.monotonic()
        if now >= self._readers_due:
            self._dds_readers = self.pub.get_subscription_count()
            self._readers_due = now + GRAPH_POLL_S
        if self._dds_readers:
            self.pub.publish(data)
        bridge = self.bus.bridge
        remote = bridge is not None and bridge.wants(self.topic)
        if self.bus.subs.get(self.topic) or remote:
            if not isinstance(data, bytes):
                from rclpy.serialization import serialize_message
                data = serialize_message(data)
            ts = self.bus.timestamp()
            if remote:
                bridge.send(self, data, ts)
            info = {"source_timestamp": ts, "publisher_gid": {"data": self.gid}}
            self.bus.post(self.topic, data, info)

    def local_subscribers(self) -> list:
        """(node name, namespace) of the in-process subscribers."""
        out = [(s.node.get_name(), s.node.get_namespace())
               for s in self.bus.subs.get(self.topic, ())]
        if self.bus.bridge is not None:
            out += self.bus.bridge.remote_subs.get(self.topic, [])
        return out

    def get_subscription_count(self) -> int:
        n = self.pub.get_subscription_count() + len(self.bus.subs.get(self.topic, ()))
        if self.bus.bridge is not None:
            n += len(self.bus.bridge.remote_subs.get(self.topic, ()))
        return n

    @property
    def topic_name(self) -> str:
        return self.topic

    def __getattr__(self, name):
        return getattr(self.pub, name)


class BusSubscription:
    """An in-process subscription (raw bytes or message objects, like rclpy's), with a
    DDS reader opened when a foreign publisher appears (:meth:`Bus.poll_graph`)."""

    def __init__(self, bus: Bus, node, msg_type, topic_abs: str, callback, raw: bool, qos,
                 event_callbacks):
        self.bus, self.node, self.msg_type = bus, node, msg_type
        self.topic = topic_abs
        self.callback, self.raw = with_info(callback), raw
        self.qos, self.event_callbacks = qos, event_callbacks
        self.destroyed = False
        self.dds = None
        # KEEP_LAST as DDS keeps it: at most ``depth`` messages wait; a newer one drops
        # the oldest, counted in ``dropped`` (decision 0026 sets the twin's depth)
        self.inbox: deque = deque()
        self.depth = max(1, int(getattr(qos, "depth", 0) or 1))
        self.dropped = 0
        bus.subs.setdefault(topic_abs, []).append(self)
        if bus.bridge is not None:
            bus.bridge.announce_sub(self)
            bus.bridge.flush()

    @property
    def topic_name(self) -> str:
        return self.topic

    def get_publisher_count(self) -> int:
        """Publishers matched with this subscription, as rclpy's ``get_publisher_count``
        (not the graph's count: a foreign publisher the graph shows is matched only once
        the DDS reader is open and DDS matched it): the in-process and bridged ones, or
        the DDS reader's matched count if that is larger (it also matches the local
        publishers' DDS writers)."""
        n = len(self.bus.pubs.get(self.topic, ()))
        if self.bus.bridge is not None:
            n += self.bus.bridge.remote_publishers(self.topic)
        if self.dds is not None:
            n = max(n, self.dds.get_publisher_count())
        return n

    def enqueue(self, data: bytes, info) -> bool:
        """Queue a message; False when the inbox was full (its oldest was dropped, and
        the message takes its place in the order of deliveries)."""
        full = len(self.inbox) >= self.depth
        if full:
            self.inbox.popleft()
            self.dropped += 1
            if self.dropped == 1:
                self.node.get_logger().warning(
                    f"{self.topic}: {self.depth} messages waiting (the QoS depth): the "
                    f"oldest dropped (KEEP_LAST; counted in the subscription's `dropped`)")
        self.inbox.append((data, info))
        return not full

    def receive(self, data: bytes, info) -> None:
        if self.raw:
            m = data
        else:
            from rclpy.serialization import deserialize_message
            m = deserialize_message(data, self.msg_type)
        self.callback(m, info)

    def open_dds(self) -> None:
        """A DDS reader for foreign publishers; the in-process publishers' copies (known
        by GID) are dropped: they came by the bus."""
        def on_dds(m, info):
            if gid_of(info) not in self.bus.local_gids(self.topic):
                self.callback(m, info)
        taken: list = []
        self.dds = self.node.create_subscription(
            self.msg_type, self.topic, draining(on_dds, taken), self.qos,
            event_callbacks=self.event_callbacks, raw=self.raw)
        taken.append(self.dds)


def draining(callback, holder: list):
    """``callback`` as a (message, info) callback that, after the message rclpy's executor
    took, takes and handles every further message queued on its subscription
    (``holder[0]``) — with ``take_message``, the call rclpy's executor itself makes per
    message. One executor round per topic and wake-up instead of one per message: the
    recorder takes a batch per wake-up (docs/decisions/0007-realtime-on-two-cores.md), and
    rclpy's executor builds a wait set and a task per round."""
    from rclpy.exceptions import InvalidHandle

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


def with_info(callback):
    """``callback`` as a callable of (message, info), whichever rclpy form it has."""
    return callback if takes_info(callback) else (lambda m, info: callback(m))


def takes_info(callback) -> bool:
    """rclpy's rule: a callback with two parameters gets the MessageInfo too."""
    try:
        params = [p for p in inspect.signature(callback).parameters.values()
                  if p.default is inspect.Parameter.empty and
                  p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    except (TypeError, ValueError):
        return False
    return len(params) >= 2
