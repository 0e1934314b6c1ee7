"""The twin's topics' endpoints: :data:`QOS` (every topic's profile), :func:`publisher`
and :func:`subscription` without QoS-event handlers and on the process's intra-process
bus where there is one (a subscription's callback drains its queue, or is fed plain
messages read from the raw bytes), and what the graph shows of a topic's other endpoints
(:func:`subscriber_names`, :func:`other_types`). Importing it loads rclpy's message
support quietly first."""

from __future__ import annotations

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

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

DEPTH = 10000
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
"""Every topic of the twin: reliable, volatile, keep_last DEPTH (deep enough that nothing
is dropped while a subscriber lags by less than DEPTH messages per topic: a recorder
paused for 5 s, docs/decisions/0026-a-history-deep-enough-for-a-paused-reader.md)."""


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
    from flexarm_ros.nodes.intraprocess import BusSubscription, bus_of, draining
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
    sub = node.create_subscription(msg_class(msgtype), topic, draining(callback, taken),
                                   QOS, event_callbacks=events, raw=raw)
    taken.append(sub)
    return sub


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
