"""The executor of the twin's nodes: rclpy's SingleThreadedExecutor, plus the intra-process bus.

Built on rclpy's public API only (issue 38: the former lean executor waited on its own
``_rclpy.WaitSet``, which tied the package to rclpy 9.1's private bindings; a test greps
the source for private rclpy names). :class:`TwinExecutor` *is* a
``SingleThreadedExecutor``: subscriptions, timers, services (every node's parameter
services: ``ros2 param list/get/set/describe`` answer as from any node), guard conditions
and waitables are waited on and called by rclpy's own code, one callback per
``spin_once``. What it adds, when the process's nodes share an intra-process bus
(:mod:`~flexarm_ros.nodes.intraprocess`, the one-process and split graphs):

* ``spin_once`` first runs the bus's queued deliveries (round after round for up to
  :attr:`TwinExecutor.BUS_SLICE_S`: a lockstep tick is three — state → command → effort —
  and a wait per round cost ~0.1 ms, cProfile on two_link_case1), then waits on the nodes'
  entities with the condition "the bus has work", so a delivery queued meanwhile returns
  it at once — or, while deliveries are still queued, looks at them without blocking, so
  timers and services run between slices of a lockstep cascade that never empties the bus;
* the bus wakes a waiting executor through rclpy's public :meth:`Executor.wake` (a post
  from the realtime pacing thread or the split layout's socket reader);
* a callback runs holding the bus's lock: the realtime pacing thread runs node callbacks
  too (its tick's deliveries), one thread at a time, so a node's callbacks never
  interleave.

Draining a subscription — taking every message queued on it in one callback, which the
recorder relies on to take a batch per wake-up — is done by the subscription's callback
itself (:func:`flexarm_ros.nodes.common.subscription`), with the same ``take_message``
call rclpy's executor makes; so it holds with the stock executor too.

``kind="single"`` in :func:`flexarm_ros.nodes.common.make_executor` is rclpy's
SingleThreadedExecutor unchanged (no bus: every message by DDS), the path CI keeps green
beside the default (``flexarm run --transport dds``).
"""

from __future__ import annotations

import threading
import time
from contextlib import nullcontext

from rclpy.executors import (ConditionReachedException, ExternalShutdownException,
                             ShutdownException, SingleThreadedExecutor, TimeoutException)

from flexarm_ros.nodes.intraprocess import bus_of


class TwinExecutor(SingleThreadedExecutor):
    """rclpy's SingleThreadedExecutor that also runs the intra-process bus's deliveries
    (module docstring). The interface is rclpy's: ``add_node``, ``remove_node``,
    ``spin_once(timeout_sec)``, ``wake``, ``shutdown``."""

    BUS_SLICE_S = 0.005
    """Wall time ``spin_once`` may spend on intra-process deliveries before it looks at
    DDS (timers, services, foreign messages) and returns."""

    def __init__(self, context=None):
        super().__init__(context=context)

    def _bus_has_work(self) -> bool:
        bus = bus_of(self.context)
        return bus is not None and bool(bus.queue)

    READY_SLICE_S = 0.05
    """Wall time :meth:`spin_ready` may spend calling what is ready before it returns (the
    caller's stop conditions are looked at between calls)."""

    def spin_ready(self, timeout_sec: float | None = None) -> int:
        """Wait up to ``timeout_sec`` for work, then call everything ready now (every
        entity one wait found ready, each subscription drained by its callback), for at
        most :attr:`READY_SLICE_S`: the number of callbacks run. A node that pauses
        between wake-ups (the recorder) takes a batch per wake-up so (rclpy's
        ``spin_once`` calls one entity)."""
        n = int(self.spin_once(timeout_sec))
        end = time.monotonic() + self.READY_SLICE_S
        while n and time.monotonic() < end and self.spin_once(0.0):
            n += 1
        return n

    def spin_once(self, timeout_sec: float | None = None) -> bool:
        """Run the bus's queued deliveries, then wait up to ``timeout_sec`` (None: forever)
        for one ready entity (or a new delivery) and call it; True if an entity's callback
        ran (rclpy's returns None)."""
        ran = False
        if not self.context.ok():
            if timeout_sec:
                time.sleep(min(timeout_sec, 0.01))
            return ran
        bus = bus_of(self.context)
        if bus is not None:
            bus.waker = self.wake
            bus.spinning_thread = threading.current_thread()
            bus.poll_graph()
            bus.deliver_all(self.BUS_SLICE_S)
        # deliveries still queued (the slice ran out: a lockstep run's cascade never
        # empties the bus): look at the entities without blocking, so timers and services
        # run between slices; else block, returning as soon as a delivery is queued. The
        # same arguments in a row keep rclpy's generator of the entities one wait found
        # ready: the next calls take them without waiting again
        busy = bus is not None and bool(bus.queue)
        args = (0.0,) if busy else (timeout_sec, None, self._bus_has_work)
        try:
            handler, _entity, _node = self.wait_for_ready_callbacks(*args)
        except (TimeoutException, ShutdownException, ConditionReachedException,
                ExternalShutdownException):
            pass
        else:
            ran = True
            with (bus.lock if bus is not None else nullcontext()):
                handler()
            exc = handler.exception()
            if exc is not None:
                raise exc
        if bus is not None:
            bus.deliver()
            bus.flush()             # what the callbacks sent the other process, if any
        return ran
