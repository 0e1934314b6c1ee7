"""``/diagnostics`` from every node of the twin: one ``diagnostic_msgs/DiagnosticArray``
a second, as ROS drivers publish it (rqt_robot_monitor, diagnostic_aggregator and
Foxglove's Diagnostics panel read it), with one ``DiagnosticStatus`` named after the node
(``/flexarm/simulator``, hardware id ``flexarm_ros twin``).

Its values are the node's counters: messages published per topic, messages rejected (the
:class:`~flexarm_ros.nodes._wire.Rejections` count), and what the node adds through a
``diagnostic_values()`` method — the simulator its simulated time, ticks, real-time
factor and late ticks, the estimator its ticks and the latest NIS. Level: ERROR when the
node says so (a diverged or stalled plant), WARN when messages were rejected in the last
period or (realtime) more than 1 % of the period's ticks were late, else OK.

The timer runs on the steady wall clock (a node with ``use_sim_time`` waits for /clock
otherwise). Where ``diagnostic_msgs`` does not import (a ROS distribution without it; the
``[ros]`` extra installs it), the node says so once at INFO and publishes nothing.
"""

from __future__ import annotations

import math

from flexarm_ros.nodes.startup import wall_clock

PERIOD_S = 1.0
TOPIC = "/diagnostics"
HARDWARE_ID = "flexarm_ros twin"
#: share of late ticks in a period above which the simulator's status is WARN
LATE_WARN_SHARE = 0.01


def attach(node):
    """Publish ``node``'s status on :data:`TOPIC` every :data:`PERIOD_S` (module doc);
    the publisher, or None where diagnostic_msgs is missing."""
    try:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    except ImportError:
        node.get_logger().info(f"{TOPIC}: not published (diagnostic_msgs does not import; "
                               f"pip install ros-diagnostic-msgs)")
        return None
    pub = node.create_publisher(DiagnosticArray, TOPIC, 10)
    name = f"{node.get_namespace().rstrip('/')}/{node.get_name()}"
    last = {"rejected": 0, "late": 0, "ticks": 0}

    def tick():
        values, level, message = status(node, last)
        st = DiagnosticStatus(level=level, name=name, message=message,
                              hardware_id=HARDWARE_ID,
                              values=[KeyValue(key=k, value=v) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = node.get_clock().now().to_msg()
        pub.publish(arr)

    node._diagnostics_timer = node.create_timer(PERIOD_S, tick, clock=wall_clock())
    return pub


def status(node, last: dict) -> tuple:
    """({key: text}, level byte, message) of ``node`` now; ``last`` keeps the previous
    period's totals (rejected messages, late ticks, ticks)."""
    from diagnostic_msgs.msg import DiagnosticStatus as S
    values = {}
    for topic, n in sorted((getattr(node, "published", None) or {}).items()):
        values[f"published {topic}"] = str(n)
    rej = getattr(node, "rejections", None)
    rejected = rej.total() if rej is not None else 0
    values["rejected"] = str(rejected)
    extra = node.diagnostic_values() if hasattr(node, "diagnostic_values") else {}
    error = extra.pop("error", None)
    for k, v in extra.items():
        values[k] = _text(v)
    late, ticks = int(extra.get("late_ticks", 0) or 0), int(extra.get("ticks", 0) or 0)
    new_rej, new_late = rejected - last["rejected"], late - last["late"]
    new_ticks = ticks - last["ticks"]
    last.update(rejected=rejected, late=late, ticks=ticks)
    if error:
        return values, S.ERROR, str(error)
    if new_rej > 0:
        return values, S.WARN, f"{new_rej} messages rejected in the last {PERIOD_S:g} s"
    if new_ticks > 0 and new_late > LATE_WARN_SHARE * new_ticks:
        return values, S.WARN, (f"{new_late} of {new_ticks} ticks late in the last "
                                f"{PERIOD_S:g} s")
    return values, S.OK, "ok"


def _text(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else str(v)
    return str(v)
