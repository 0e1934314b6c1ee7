"""When a node starts: its start condition (:class:`Barrier`: the subscribers and the
recorder it needs matched, after :data:`DISCOVERY_SETTLE_S`, and no other twin beside
it), when a wait is said at WARN level (:class:`WaitWarning`), and the steady clock its
timers run on before the twin's first /clock (:func:`wall_clock`)."""

from __future__ import annotations

import time

from flexarm_ros.nodes.endpoints import other_types, subscriber_names
from flexarm_ros.nodes.run_enclave import other_twin

def wall_clock():
    """A steady clock for the timers that must run before the twin's first /clock (the
    start barriers): with use_sim_time a node's own clock stands still until then."""
    from rclpy.clock import Clock, ClockType
    return Clock(clock_type=ClockType.STEADY_TIME)


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
