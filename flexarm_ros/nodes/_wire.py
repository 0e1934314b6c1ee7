"""Who may talk to a node: one publisher per input topic (the *source*), identified by the
publisher GID that comes with every message (rclpy ``MessageInfo``).

Rule, the same in every time mode and for every input of the twin's nodes:

* When the graph shows a publisher of the topic belonging to the node the twin expects
  there (``motor_driver`` for ``effort_controller/commands``, ``controller`` for
  ``motor_driver/commands``, ``simulator`` for the state topics and ``/clock``) in the
  subscriber's namespace, only that node's messages are taken.
* Otherwise the first publisher whose message is taken owns the topic until it leaves the
  graph; then the next one may take over (a user's own controller in place of ours).
* A message from any other publisher is refused: it is counted and logged (throttled) and
  changes nothing — in ``lockstep`` it does not step the plant.
* The expected node is this run's (issue 39): a second publisher of that name in the
  namespace — the same node of another twin run on the domain — is refused with the reason
  ``another run``. Which GIDs are this run's: in one process (and the split layout) those
  of the bus's own publishers (:mod:`~flexarm_ros.nodes.intraprocess`, the bridge's
  announced ones), known without discovery; one node per process (``--processes``, or
  nodes started by hand) pins the expected node's GIDs when it first sees them, which is
  after its start condition let it start with no other twin on the graph
  (:mod:`~flexarm_ros.nodes.run_enclave`). Without this, the window before a newer twin
  sees the older one and stops (docs/decisions/0027) let the older twin's driver take the
  newer one's commands — seen diverging a clean CI run.

This guards against a second publisher by mistake (a stray ``ros2 topic pub``, a replay
into a live twin); it is not a security boundary (a node may take any name). A publisher
whose GID the graph does not show yet (discovery still under way) is looked up again for
up to :data:`RESOLVE_S` of wall time before the rule is applied without it.

DDS itself keeps messages of another type away: rclpy refuses to create a publisher of a
second type on a topic in the same process, and across processes the endpoints of
different types never match, so nothing arrives.
"""

from __future__ import annotations

import time

from flexarm_ros.nodes.intraprocess import bus_of, gid_of
from flexarm_ros.nodes.run_enclave import other_twin
from flexarm_ros.twin.validation import ANOTHER_RUN, FOREIGN, NOT_CDR

RESOLVE_S = 0.5
UNKNOWN = "_NODE_NAME_UNKNOWN_"


class Source:
    """The source rule for one topic of one node."""

    def __init__(self, node, topic: str, expected: str | None):
        self.node = node
        self.topic = topic                     # absolute name
        self.expected = expected
        self.ns = node.get_namespace()
        self.owner: set = set()                # GIDs taken
        self.owner_expected = False            # the owners are the expected twin node
        self._snap: dict = {}                  # GID -> (node name, namespace)
        self._count = -1                       # publishers when _snap was taken
        self._waited: set = set()              # GIDs already waited for
        self.mine: set | None = None           # the expected node's GIDs, pinned (no bus)
        self.reason = FOREIGN                  # why the last refused message was refused

    def _graph(self) -> dict:
        """GID -> (node name, namespace) of the topic's publishers now: the DDS graph's,
        and those another process of the twin announced over its bridge
        (:mod:`~flexarm_ros.nodes.bridge`; DDS may not show them for seconds)."""
        out = {}
        for info in self.node.get_publishers_info_by_topic(self.topic):
            out[bytes(info.endpoint_gid)] = (info.node_name, info.node_namespace)
        bus = bus_of(self.node.context)
        if bus is not None and bus.bridge is not None:
            out.update(bus.bridge.remote_publisher_names(self.topic))
        return out

    def _snapshot(self, gid) -> dict:
        """The topic's publishers, queried again only when their number changed or
        ``gid`` is not resolved in the last answer (waited for once per GID)."""
        count = self.node.count_publishers(self.topic)
        if count == self._count and gid in self._snap and self._snap[gid][0] != UNKNOWN:
            return self._snap
        self._snap, self._count = self._graph(), count
        if (gid not in self._snap or self._snap[gid][0] == UNKNOWN) and \
                gid not in self._waited:
            self._waited.add(gid)
            t0 = time.monotonic()
            while (gid not in self._snap or self._snap[gid][0] == UNKNOWN) and \
                    time.monotonic() - t0 < RESOLVE_S:
                time.sleep(0.002)              # rmw's discovery thread fills the graph
                self._snap = self._graph()
            self._count = self.node.count_publishers(self.topic)
        return self._snap

    def verdict(self, info, valid: bool = True) -> str | None:
        """None: the message may be taken (it still has to pass validation); else the
        name of the refused publisher. Only a ``valid`` message makes its publisher the
        owner of a topic nobody owns."""
        gid = gid_of(info)
        if gid is None or gid in self.owner:
            return None
        graph = self._snapshot(gid)
        named = {g for g, (name, ns) in graph.items()
                 if self.expected and name == self.expected and ns == self.ns}
        expected = self._this_run(named, graph)
        if gid in named and gid not in expected:
            self.reason = ANOTHER_RUN
            return f"{self.expected} of another run"
        self.reason = FOREIGN
        if expected:
            self.owner = expected
        else:
            self.owner = {g for g in self.owner if g in graph}   # owners still there
        self.owner_expected = bool(expected)
        if gid in self.owner:
            return None
        if not self.owner:
            if valid:
                self.owner.add(gid)
            return None
        return graph.get(gid, ("an unknown node",))[0]

    def _this_run(self, named: set, graph: dict) -> set:
        """Of the GIDs of publishers named like the expected node, those of this run."""
        if not named:
            return set()
        bus = bus_of(self.node.context)
        if bus is not None:
            local = bus.local_publishers(self.topic, self.expected, self.ns)
            if local or (self.ns, self.expected) in bus.members:
                # a member of this run (this process's or, split, the other's): only its
                # own GIDs, none until it announced them — never pinned at first sight
                # (a split run refused at start had pinned the other run's simulator,
                # whose messages came before its own process did, and recorded them)
                return named & local
        if self.mine is None or not (self.mine & set(graph)):
            # first seen, or ours left the graph: pinned again — but not while another
            # run's twin shows in this namespace: their nodes' names are ours, so nothing
            # tells which is this run's (a refused run's recorder, one node per process,
            # had pinned the running twin's simulator and recorded its messages)
            if other_twin(self.node) is not None:
                return set()
            self.mine = set(named)
        return named & self.mine

    def trusted(self, info) -> bool:
        """The message (already given a ``None`` verdict) comes from the twin's own node
        expected on this topic: its content is the twin's (finite, well formed)."""
        return self.owner_expected and gid_of(info) in self.owner


class Rejections:
    """Counts and throttled log lines of what a node refused or rejected, per topic."""

    def __init__(self, node, period_s: float = 1.0):
        self.node = node
        self.period = period_s
        self.counts: dict = {}                   # topic -> {reason: n}
        self._said: dict = {}

    def add(self, topic: str, reason: str, text: str) -> None:
        by = self.counts.setdefault(topic, {})
        by[reason] = by.get(reason, 0) + 1
        now = time.monotonic()
        if now - self._said.get(topic, -1e9) >= self.period:
            self._said[topic] = now
            total = sum(by.values())
            self.node.get_logger().warning(f"{topic}: rejected {text}; {total} rejected on "
                                           f"this topic so far, nothing changed")

    def refused(self, source: "Source", what: str, data, who: str) -> None:
        """A message that ``source`` (its topic's rule) refused from ``who``, for the
        reason it gives: :data:`FOREIGN`, or :data:`ANOTHER_RUN` for the expected node of
        another twin run."""
        what = what if data is None else f"{what} {show(data)}"
        why = ("another twin run's node of that name; the source is this run's"
               if source.reason == ANOTHER_RUN else "a second publisher; the source is "
               f"{source.expected or 'the first publisher'}")
        self.add(source.topic, source.reason, f"{what} from {who} ({why})")

    def invalid(self, topic: str, what: str, data, why: str, expected: str) -> None:
        """A message that failed validation."""
        self.add(topic, why, f"{what} {show(data)} ({why}; expected {expected})")

    def total(self, topic: str | None = None) -> int:
        if topic is not None:
            return sum(self.counts.get(topic, {}).values())
        return sum(sum(by.values()) for by in self.counts.values())

    def summary(self) -> str:
        """``topic: N rejected (a reason, …)`` per topic, or ``no message rejected``."""
        if not self.counts:
            return "no message rejected"
        return "; ".join(f"{t}: {sum(by.values())} rejected ("
                         + ", ".join(f"{n} {r}" for r, n in sorted(by.items())) + ")"
                         for t, by in sorted(self.counts.items()))


def show(data, limit: int = 6) -> str:
    """A short text of a message's values for a log line (``[nan, 1.0, …]``)."""
    try:
        vals = list(data)
    except TypeError:
        return repr(data)[:80]
    text = ", ".join(f"{v:.6g}" if isinstance(v, float) else repr(v) for v in vals[:limit])
    return f"[{text}{', …' if len(vals) > limit else ''}] ({len(vals)} values)"


def reject_undecodable(node, validator, source: Source, what: str, data: bytes, exc,
                       info) -> None:
    """Bytes on a validated input topic that are not a message of its type: from a second
    publisher refused (``second publisher``), else rejected (``not a CDR message of its
    type``); counted by the validator and logged (throttled) like any rejection."""
    who = source.verdict(info, valid=False)
    if who is not None:
        validator.refuse(source.reason)
        node.rejections.refused(source, what, None, who)
    else:
        validator.refuse(NOT_CDR)
        node.rejections.add(source.topic, NOT_CDR, f"{len(data)} bytes that are not a "
                            f"{what} ({exc}; expected {validator.expectation()})")
