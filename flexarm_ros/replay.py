"""Play a recorded MCAP bag back on ROS 2 (rclpy) with ``/clock`` from its log times, so
tools that use simulation time (``use_sim_time``) can be driven from a bag without
rosbag2. ``flexarm replay`` is :func:`replay` after :func:`load_plan`.

Messages are decoded with :mod:`flexarm_ros.bag.reader` and republished as rclpy
messages of the recorded type (:func:`flexarm_ros.nodes._msgconv.to_msg`) with the twin's
QoS (reliable, volatile, depth 10000). They go out in log-time order (file order among
equal times). Before the first message of each new log time, ``/clock`` carries that
time; the bag's own ``/clock`` messages are not replayed (the log times are the clock).
``rate`` scales the pace: 1 real time, 2 twice as fast, 0 as fast as possible (a
subscriber that falls more than its queue depth behind then loses the oldest messages,
as with ``ros2 bag play``). At the end the publishers wait up to 5 s for their reliable
subscribers to acknowledge everything (Fast DDS acknowledges on its heartbeat, about
3 s), so the last messages are not lost when the node goes away.

Topics are republished under their recorded names; ``namespace`` moves those under the
recording namespace (metadata ``flexarm_ros.namespace``) to another one, or, for a bag
without it, prefixes every topic but ``/clock``.

The bag is read into memory first. rclpy is imported only by :func:`replay`.
"""

from __future__ import annotations

import heapq
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from flexarm_ros.bag.reader import Bag, BagError, read_bag, to_dict
from flexarm_ros.twin.recording import recorded_namespace
from flexarm_ros.twin import topics as T

__all__ = ["ReplayPlan", "ReplayResult", "load_plan", "remap", "replay"]

ACK_TIMEOUT_S = 5.0      # wall s to wait, at the end, for subscribers to acknowledge


@dataclass
class ReplayPlan:
    """The messages to publish: ``items`` = [(log time ns, topic out, type, message)],
    time-ordered; ``types[topic out]``; ``source[topic out]`` = recorded name."""
    path: str
    items: list
    types: dict
    source: dict
    bag: Bag | None = None

    @property
    def duration_ns(self) -> int:
        return self.items[-1][0] - self.items[0][0] if self.items else 0


@dataclass
class ReplayResult:
    published: dict = field(default_factory=dict)   # topic out -> messages
    clock: int = 0                                   # /clock messages
    loops: int = 0                                   # complete passes
    wall_s: float = 0.0                              # publishing, first to last message
    interrupted: bool = False
    skipped: dict = field(default_factory=dict)      # topic -> reason (no type support)

    @property
    def total(self) -> int:
        return sum(self.published.values())

    def summary(self) -> str:
        s = (f"replayed {self.total} messages on {len(self.published)} topics and "
             f"{self.clock} /clock messages in {self.wall_s:.3g} s")
        if self.loops > 1:
            s += f" ({self.loops} passes)"
        return s + (", interrupted" if self.interrupted else "")


def remap(topic: str, recorded_ns: str, namespace: str | None) -> str:
    """Output name of a recorded topic (see the module docstring)."""
    if not namespace or topic == T.CLOCK:
        return topic
    new = "/" + namespace.strip("/") if namespace.strip("/") else ""
    old = "/" + recorded_ns.strip("/") if recorded_ns.strip("/") else ""
    if old:
        if topic == old or topic.startswith(old + "/"):
            return new + topic[len(old):]
        return topic
    return new + (topic if topic.startswith("/") else "/" + topic)


def load_plan(path, topics=None, namespace: str | None = None) -> ReplayPlan:
    """Read ``path`` and order its messages for :func:`replay`. ``topics``: recorded
    names to keep, absolute or relative to the recording namespace (unknown → BagError
    listing the bag's topics). Raises FileNotFoundError, IsADirectoryError, BagError."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file, expected an MCAP bag")
    bag = read_bag(path)
    rec_ns = recorded_namespace(bag) or ""
    names = [t for t in bag.topics if t != T.CLOCK]
    if topics:
        keep = []
        for want in topics:
            hit = [t for t in names if t == want or t == T.resolve(rec_ns or "/", want)]
            if not hit:
                raise BagError(f"{path}: --topics {want!r} is not in the bag; its topics are "
                               f"{', '.join(names) or 'none'}")
            keep += [t for t in hit if t not in keep]
        names = keep
    order = {t: i for i, t in enumerate(bag.topics)}
    streams = [[(t_ns, order[topic], k, topic) for k, (t_ns, _) in enumerate(bag[topic])]
               for topic in names]
    items = []
    for t_ns, _, k, topic in heapq.merge(*(sorted(s) for s in streams)):
        items.append((t_ns, remap(topic, rec_ns, namespace), bag.types[topic],
                      bag[topic][k][1]))
    types = {remap(t, rec_ns, namespace): bag.types[t] for t in names}
    source = {remap(t, rec_ns, namespace): t for t in names}
    return ReplayPlan(str(path), items, types, source, bag)


def _clock(t_ns: int) -> dict:
    return {"clock": {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}}


def replay(plan: ReplayPlan, rate: float = 1.0, loop: bool = False,
           wait_subscribers: int = 0, wait_timeout: float = 30.0, delay: float = 0.5,
           node_name: str = "flexarm_replay", progress=None) -> ReplayResult:
    """Publish ``plan`` on ROS 2 (domain from ``ROS_DOMAIN_ID``, discovery on loopback
    unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is set) until done, or forever
    with ``loop``, or until SIGINT/SIGTERM. ``wait_subscribers``: before the first
    message, wait (up to ``wait_timeout`` s of wall time, else TimeoutError) until every
    publisher has that many matched subscriptions; then ``delay`` s for discovery to
    settle. ``progress(text)`` is called with one status line per second."""
    if not rate >= 0:
        raise ValueError(f"rate: got {rate}, expected >= 0 (0: as fast as possible)")
    import rclpy
    from rclpy.context import Context
    from rclpy.duration import Duration
    from rclpy.signals import SignalHandlerOptions

    from flexarm_ros.nodes.common import StopFlag, publisher
    from flexarm_ros.nodes._msgconv import msg_class, to_msg

    from flexarm_ros.nodes import environment
    environment.use_loopback()
    res = ReplayResult()
    stop = StopFlag()
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    t_start = time.monotonic()
    try:
        node = rclpy.create_node(node_name, context=ctx)
        pubs = {}
        for topic, tp in plan.types.items():
            try:
                msg_class(tp)
            except (ImportError, AttributeError) as err:
                res.skipped[topic] = f"type {tp} is not available to rclpy ({err})"
                warnings.warn(f"{plan.path}: not replaying {topic}: {res.skipped[topic]}",
                              stacklevel=2)
                continue
            pubs[topic] = publisher(node, tp, topic)
        clock = publisher(node, "rosgraph_msgs/msg/Clock", T.CLOCK)
        every = list(pubs.values()) + [clock]

        def sleep_until(deadline):
            while not stop.set:
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                time.sleep(min(left, 0.05))

        if wait_subscribers > 0:
            t0 = time.monotonic()
            while not stop.set and any(p.get_subscription_count() < wait_subscribers
                                       for p in every):
                if time.monotonic() - t0 > wait_timeout:
                    short = [p.topic_name for p in every
                             if p.get_subscription_count() < wait_subscribers]
                    raise TimeoutError(f"fewer than {wait_subscribers} subscribers after "
                                       f"{wait_timeout:g} s on {', '.join(short)}")
                time.sleep(0.02)
        sleep_until(time.monotonic() + delay)
        res.published = dict.fromkeys(pubs, 0)
        said = time.monotonic()
        t_start = time.monotonic()
        while not stop.set:
            wall0, last_t, first_t = time.monotonic(), None, None
            for t_ns, topic, tp, msg in plan.items:
                if stop.set:
                    break
                pub = pubs.get(topic)
                if pub is None:
                    continue
                if t_ns != last_t:
                    if first_t is None:
                        first_t = t_ns
                    if rate > 0:
                        sleep_until(wall0 + (t_ns - first_t) * 1e-9 / rate)
                        if stop.set:
                            break
                    clock.publish(to_msg("rosgraph_msgs/msg/Clock", _clock(t_ns)))
                    res.clock += 1
                    last_t = t_ns
                pub.publish(to_msg(tp, to_dict(msg)))
                res.published[topic] = res.published.get(topic, 0) + 1
                if progress is not None and time.monotonic() - said > 1.0:
                    said = time.monotonic()
                    progress(f"t = {t_ns * 1e-9:.3f} s, {res.total} messages")
            else:
                res.loops += 1
            if not loop or not plan.items:
                break
        res.interrupted = stop.set
        res.wall_s = time.monotonic() - t_start
        deadline = time.monotonic() + ACK_TIMEOUT_S
        for p in every:                # let reliable subscribers get the tail
            left = deadline - time.monotonic()
            if left <= 0:
                break
            p.wait_for_all_acked(Duration(seconds=left))
        return res
    finally:
        stop.restore()
        if node is not None:
            node.destroy_node()
        if ctx.ok():
            rclpy.shutdown(context=ctx)


def command(args) -> int:
    """``flexarm replay`` (arguments from :mod:`flexarm_ros.commands.replay`): exit 0
    done or interrupted, 1 no subscriber in time, 2 bad bag/arguments or rerun missing."""
    import json
    import math
    import sys

    def fail(text, code=2):
        print(f"flexarm replay: error: {text}", file=sys.stderr)
        return code

    if not (args.rate >= 0 and math.isfinite(args.rate)):
        return fail(f"--rate: got {args.rate}, expected a finite number >= 0 (1 real time, "
                    "0 as fast as possible)")
    if not (args.delay >= 0 and math.isfinite(args.delay)):
        return fail(f"--delay: got {args.delay}, expected a finite number >= 0 s")
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.nodes.names import check_namespace
    try:
        args.namespace = check_namespace("--namespace", args.namespace)
        if args.rerun is not None:
            check_output_file("--rerun", args.rerun, (".rrd",))
    except InputError as exc:
        return fail(exc)
    options = None
    if args.rerun is not None:
        from flexarm_ros.viz.rerun_view import RerunUnavailable, ViewOptions, require_rerun
        try:
            require_rerun()
            options = ViewOptions(args.shape_rate, args.samples, args.force_scale)
        except (RerunUnavailable, ValueError) as exc:
            return fail(exc)
    import warnings
    with warnings.catch_warnings(record=True) as caught:   # a damaged bag: one line each
        warnings.simplefilter("always")
        try:
            plan = load_plan(args.bag, args.topics, args.namespace)
        except (OSError, BagError) as exc:
            plan = exc
    for w in caught:
        print(f"flexarm replay: warning: {w.message}", file=sys.stderr)
    if isinstance(plan, Exception):
        return fail(plan)
    out = {"bag": plan.path}
    if args.rerun is not None:
        from flexarm_ros.viz.rerun_view import bag_to_rerun
        final = Path(args.rerun)
        part = final.with_name(f".{final.name}.partial.rrd")   # the file is kept till done
        try:
            summ = bag_to_rerun(plan.bag, part, options=options)
        except (OSError, BagError) as exc:
            part.unlink(missing_ok=True)
            return fail(exc)
        if summ.rows or summ.shape_frames:
            part.replace(final)
            summ.rrd = final
        else:
            part.unlink(missing_ok=True)
            topics = ", ".join(sorted(plan.bag.messages)[:5]) or "none"
            return fail(f"BAG.mcap: got {args.bag} with nothing the rerun view draws (its "
                        f"topics: {topics}), expected a bag of flexarm run --record or "
                        f"flexarm simulate --record")
        out["rerun"] = {"file": str(summ.rrd), "bytes": summ.size_bytes,
                        "entities": summ.rows, "shape_frames": summ.shape_frames}
        if not args.json:
            print(summ.text())
        if not args.publish:
            if args.json:
                print(json.dumps(out, indent=2))
            return 0
    from flexarm_ros.io.progress import ProgressLine
    line = ProgressLine(48)
    progress = None if (args.quiet or args.json) else (lambda text: line.show(f"  {text}"))
    try:
        res = replay(plan, rate=args.rate, loop=args.loop,
                     wait_subscribers=args.wait_subscribers, delay=args.delay,
                     progress=progress)
    except TimeoutError as exc:
        return fail(exc, 1)
    line.clear()
    out.update(published=res.published, clock=res.clock, loops=res.loops,
               wall_s=res.wall_s, interrupted=res.interrupted, skipped=res.skipped)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{plan.path}: {res.summary()}")
        for topic, n in res.published.items():
            print(f"  {topic}: {n}")
        for topic, why in res.skipped.items():
            print(f"  {topic}: skipped, {why}")
    return 0
