"""``/diagnostics`` from every node of the twin, received by a separate rclpy process as
rqt_robot_monitor or Foxglove would (in each kept layout), and the status rules against
counters set by hand."""

from __future__ import annotations

import math
import time

import pytest

rclpy = pytest.importorskip("rclpy")
diagnostic_msgs = pytest.importorskip("diagnostic_msgs.msg")
import flexarm_ros.nodes.common  # noqa: E402,F401  (message support, quietly)
from flexarm_ros.nodes.diagnostics import status  # noqa: E402

S = diagnostic_msgs.DiagnosticStatus


class _Rej:
    def __init__(self, n):
        self.n = n

    def total(self):
        return self.n


class _Node:
    def __init__(self, **kw):
        self.published = {"joint_states": 10}
        self.rejections = _Rej(0)
        self.values = kw

    def diagnostic_values(self):
        return dict(self.values)


def test_the_level_follows_the_periods_rejections_late_ticks_and_errors():
    node, last = _Node(ticks=1000, late_ticks=0), {"rejected": 0, "late": 0, "ticks": 0}
    values, level, msg = status(node, last)
    assert level == S.OK and values["published joint_states"] == "10"
    node.values = {"ticks": 2000, "late_ticks": 11}            # 11 of 1000: above 1 %
    _, level, msg = status(node, last)
    assert level == S.WARN and msg.startswith("11 of 1000 ticks late")
    node.values = {"ticks": 3000, "late_ticks": 12}            # 1 of 1000 in this period
    assert status(node, last)[1] == S.OK
    node.rejections.n = 3
    _, level, msg = status(node, last)
    assert level == S.WARN and msg.startswith("3 messages rejected")
    assert status(node, last)[1] == S.OK                        # none new since
    node.values = {"ticks": 4000, "error": "stalled"}
    assert status(node, last)[1:] == (S.ERROR, "stalled")


@pytest.mark.ros
@pytest.mark.subprocess
@pytest.mark.heavy
@pytest.mark.timeout(240)
@pytest.mark.parametrize("layout", ["one", "split", "processes"])
def test_every_node_publishes_diagnostics_a_second(tmp_path, layout, ros_client, twin_process):
    """A realtime `flexarm run two_link_position --record` in a child process: within
    20 s this process has a status from each of the simulator, controller, motor driver
    and recorder, at about 1 Hz, the simulator's real-time factor positive and not above
    1 (paced), its simulated time advancing."""
    ns = f"/diag_{layout}"
    proc = twin_process("two_link_position", "--mode", "realtime", "--duration", "60",
                        "--record", str(tmp_path / "d.mcap"), "--quiet", "--namespace", ns,
                        layout=layout)
    client = ros_client("diag_listener")
    seen: dict = {}
    client.node.create_subscription(
        diagnostic_msgs.DiagnosticArray, "/diagnostics",
        lambda m: [seen.setdefault(st.name, []).append(
            (time.monotonic(), {kv.key: kv.value for kv in st.values}, st.level))
            for st in m.status], 10)
    want = {f"{ns}/{n}" for n in ("simulator", "controller", "motor_driver", "recorder")}
    deadline = time.monotonic() + 60
    while not (want <= set(seen) and all(len(seen[n]) >= 3 for n in want)):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, (layout, sorted(seen))
        client.spin_once(0.1)
    sim = seen[f"{ns}/simulator"]
    gaps = [b[0] - a[0] for a, b in zip(sim, sim[1:])]
    assert 0.7 < sorted(gaps)[len(gaps) // 2] < 1.5 and max(gaps) < 5.0, gaps   # ~1 Hz
    # paced to the wall clock, a realtime twin never runs ahead of it (how far it falls
    # behind on a loaded host is the benchmarks' business, not this test's)
    rtf = float(sim[-1][1]["real_time_factor"])
    assert math.isfinite(rtf) and 0.0 < rtf < 1.05, rtf
    assert float(sim[-1][1]["sim_time_s"]) > float(sim[0][1]["sim_time_s"])
    assert "late_ticks" in sim[-1][1] and sim[-1][1]["rejected"] == "0"
    assert "published motor_driver/commands" in seen[f"{ns}/controller"][-1][1]
    assert int(seen[f"{ns}/recorder"][-1][1]["recorded"]) > 0
