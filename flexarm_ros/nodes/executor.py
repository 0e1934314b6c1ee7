"""A lean executor for the twin's nodes: one rcl wait, then every queued message.

rclpy's SingleThreadedExecutor hands out one callback per ``spin_once``: for each
message it rebuilds the generator state, wraps the callback in a Task and checks every
entity's callback group, and it waits again whenever its generator runs dry. Profiled on
a lockstep run of ``two_link_case1`` with the recorder (18 receptions per control tick),
that machinery took about half of the tick
(docs/decisions/0005-a-lean-executor-and-raw-cdr.md). rclpy's
EventsExecutor would avoid it, but (rclpy 9.1) it fails with ``SystemError`` on
subscriptions whose callback takes a ``MessageInfo`` — which the source rule
(:mod:`~flexarm_ros.nodes._wire`) and the recorder's stamps need.

:class:`DrainExecutor` does only what the twin's nodes use: subscriptions (message
objects or raw bytes, with or without ``MessageInfo``), timers and services (every rclpy
node's parameter services: ``ros2 param list/get/set/describe`` answer as from any node),
all in the one default callback group, called from the spinning thread. ``spin_once`` builds one wait set of
every subscription and timer, waits, then calls each ready timer and *drains* each ready
subscription — takes and handles every message queued on it, in arrival order per
topic — before waiting again. Per topic the order is the DDS order, as with any
executor; across topics the twin's nodes never relied on more (lockstep pairs messages
by count per topic and the recorder by source timestamps).

A subscription marked ``taken_elsewhere`` is left to the thread that takes from it
(the realtime simulator's pacing thread takes its efforts itself).

When the nodes share an intra-process bus (:mod:`~flexarm_ros.nodes.intraprocess`, the
one-process graph), the bus's guard condition is in the wait set, ``spin_once`` does
not block while deliveries are queued, and runs those queued before it returns (the
ones they queue in turn wait for the next call, so a lockstep run never recurses and
the caller's stop conditions are checked every call).

Not supported (and not used by the nodes): clients, waitables, other guard conditions,
coroutine callbacks, other callback groups.
"""

from __future__ import annotations

import threading
import time
from contextlib import ExitStack, nullcontext

from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription

from flexarm_ros.nodes.intraprocess import bus_of


def _enter(stack: ExitStack, entities) -> list:
    """The entities whose handles are still valid, each held open by ``stack``."""
    live = []
    for e in entities:
        try:
            stack.enter_context(e.handle)
            live.append(e)
        except InvalidHandle:                      # destroyed since it was listed
            pass
    return live


class DrainExecutor:
    """``add_node``, ``remove_node``, ``spin_once(timeout_sec)``, ``shutdown`` — the part of
    the rclpy executor interface the twin uses (:func:`flexarm_ros.nodes.common.node_main`,
    :class:`flexarm_ros.run.InProcessGraph`)."""

    BUS_SLICE_S = 0.005
    """Wall time ``spin_once`` may spend on intra-process deliveries before it looks at
    DDS (timers, foreign messages) and returns."""

    def __init__(self, context):
        self.context = context
        self._nodes: list = []
        self._shutdown = False
        self._key = None          # the entities of the cached wait set (ids, held alive)
        self._cache = None        # (ExitStack holding their handles, subs, timers, WaitSet)

    def add_node(self, node) -> bool:
        if node not in self._nodes:
            self._nodes.append(node)
        return True

    def remove_node(self, node) -> None:
        if node in self._nodes:
            self._nodes.remove(node)
        self._release()

    def get_nodes(self) -> list:
        return list(self._nodes)

    def shutdown(self, timeout_sec=None) -> bool:
        self._shutdown = True
        self._nodes = []
        self._release()
        return True

    def _release(self) -> None:
        """Let go of the cached wait set and the handles it holds (a destroyed entity's
        handle is freed when released)."""
        if self._cache is not None:
            self._cache[0].close()
        self._key = self._cache = None

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to ``timeout_sec`` (None: forever) for work; do all of it.

        The wait set and the entered handles are kept from one call to the next while the
        nodes' subscriptions and timers stay the same (entering ~20 handles per call cost
        about 0.15 ms per lockstep tick, measured with cProfile on two_link_case1)."""
        if self._shutdown or not self.context.ok():
            self._release()
            if timeout_sec:
                time.sleep(min(timeout_sec, 0.01))
            return
        bus = bus_of(self.context)
        if bus is not None:
            bus.spinning_thread = threading.current_thread()
            bus.poll_graph()
            # in-process deliveries first, round after round (a lockstep tick is three:
            # state → command → effort), for up to BUS_SLICE_S; an rcl wait per round
            # cost ~0.1 ms (cProfile, lockstep two_link_case1)
            bus.deliver_all(self.BUS_SLICE_S)
        subs = [s for n in self._nodes for s in n.subscriptions
                if not getattr(s, "taken_elsewhere", False)]
        timers = [t for n in self._nodes for t in n.timers if not t.is_canceled()]
        services = [v for n in self._nodes for v in n.services]
        if not subs and not timers and not services and bus is None:
            self._release()
            if timeout_sec:
                time.sleep(timeout_sec)
            return
        key = (tuple(map(id, subs)), tuple(map(id, timers)), tuple(map(id, services)))
        if key != self._key:
            self._release()
            stack = ExitStack()
            live_subs, live_timers = _enter(stack, subs), _enter(stack, timers)
            live_services = _enter(stack, services)
            stack.enter_context(self.context.handle)
            ws = _rclpy.WaitSet(len(live_subs), int(bus is not None), len(live_timers),
                                0, len(live_services), 0, self.context.handle)
            self._key = key
            self._cache = (stack, live_subs, live_timers, live_services, ws)
        _, live_subs, live_timers, live_services, ws = self._cache
        timeout_ns = -1 if timeout_sec is None else int(max(timeout_sec, 0.0) * 1e9)
        if bus is not None and bus.queue:
            timeout_ns = 0
        ws.clear_entities()
        for s in live_subs:
            ws.add_subscription(s.handle)
        for t in live_timers:
            ws.add_timer(t.handle)
        for v in live_services:
            ws.add_service(v.handle)
        if bus is not None:
            ws.add_guard_condition(bus.guard)
        ws.wait(timeout_ns)
        ready_subs = set(ws.get_ready_entities("subscription"))
        ready_timers = set(ws.get_ready_entities("timer"))
        ready_services = set(ws.get_ready_entities("service"))
        # with a bus, the realtime pacing thread runs node callbacks too: one thread at a
        # time (the bus's lock), so a node's callbacks never interleave
        with (bus.lock if bus is not None else nullcontext()):
            for t in live_timers:
                if t.handle.pointer in ready_timers:
                    try:
                        with t.handle:
                            if not t.handle.is_timer_ready():
                                continue
                            t.handle.call_timer()
                    except InvalidHandle:
                        continue
                    t.callback()
            for s in live_subs:
                if s.handle.pointer in ready_subs:
                    self._drain(s)
            for v in live_services:
                if v.handle.pointer in ready_services:
                    self._serve(v)
        if bus is not None:
            bus.deliver()
            bus.flush()             # what the callbacks sent the other process, if any

    @staticmethod
    def _serve(srv) -> None:
        """Answer every request queued on ``srv`` as rclpy's executor does: take the
        request, call the service's callback with a fresh response, send it back."""
        while True:
            try:
                with srv.handle:
                    taken = srv.handle.service_take_request(srv.srv_type.Request)
            except InvalidHandle:                 # destroyed by an earlier callback
                return
            if not taken or taken[1] is None:
                return
            request, header = taken
            response = srv.callback(request, srv.srv_type.Response())
            try:
                srv.send_response(response, header)
            except InvalidHandle:
                return

    @staticmethod
    def _drain(sub) -> None:
        """Take and handle every message queued on ``sub``."""
        with_info = sub._callback_type is not Subscription.CallbackType.MessageOnly
        while True:
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:                 # destroyed by an earlier callback
                return
            if taken is None:
                return
            if with_info:
                sub.callback(*taken)
            else:
                sub.callback(taken[0])
