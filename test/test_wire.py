"""The wire (issue 12): a rejected command never moves the arm, nothing hangs, every bad path
ends in one clear line.

Truths used: the batch co-simulation (``cosimulate``, no ROS, no hostile input) is the clean
run, message for message; the wire limits are recomputed here by hand from the scene's
numbers; a diverging scene is one ``flexarm simulate`` itself stops with status 3."""

import dataclasses
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from flexarm_ros.bag import read_bag, to_dict
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.errors import SceneError, SimulationDiverged
from flexarm_ros.model.limits import DEFAULT_SUPPLY_VOLTAGE, DEFAULT_TORQUE_LIMIT, joint_limits
from flexarm_ros.scene import load_scene
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import ControllerCore, DriverCore, SimulatorCore
from flexarm_ros.twin.cosim import Lockstep, cosimulate
from flexarm_ros.twin.validation import BEYOND, FOREIGN, LENGTH, NON_FINITE, Validator

NS = "/flexarm"
NAN, INF = math.nan, math.inf
#: what a source sends before each of its real messages in the hostile runs
BAD = [[NAN, NAN], [INF, -INF], [1e300, -1e300], [1.0], []]
BAD_COUNTS = {NON_FINITE: 2, BEYOND: 1, LENGTH: 2}            # per real message


# ================================================================ limits (no ROS)
def test_limits_follow_the_drive_or_the_stated_defaults():
    """By hand from the scene files: n·K_t·2·V/R for a DC motor without current limit,
    the supply or 48 V for its voltage, η·D·P_s and the rated current for the valve,
    1000 N·m or the key for a joint without a drive."""
    case1 = joint_limits(load_scene("two_link_case1"))
    assert [lim.command_limit for lim in case1] == [48.0, 48.0] == [DEFAULT_SUPPLY_VOLTAGE] * 2
    assert case1[0].torque_limit == pytest.approx(156.0 * 0.0302 * 2 * 48.0 / 0.9879832, rel=1e-12)
    assert case1[1].torque_limit == pytest.approx(236.0 * 0.0258 * 2 * 48.0 / 4.042532, rel=1e-12)
    assert "default" in case1[0].command_from
    pos = joint_limits(load_scene("two_link_position"))
    assert [lim.command_limit for lim in pos] == [24.0, 24.0]
    hyd = joint_limits(load_scene("hydraulic_2kg"))[0]
    d = load_scene("hydraulic_2kg").links[0].joint.drive
    assert hyd.command_limit == 0.010 and hyd.command_unit == "A"
    assert hyd.torque_limit == pytest.approx((d.torque_efficiency or 1.0) * d.displacement
                                             * 1.37889e7, rel=1e-12)
    link = load_scene("link")
    assert joint_limits(link)[0].torque_limit == DEFAULT_TORQUE_LIMIT == 1000.0
    lk = dataclasses.replace(link.links[0], joint=dataclasses.replace(link.links[0].joint,
                                                                      torque_limit=2.5))
    own = joint_limits(dataclasses.replace(link, links=(lk,)))[0]
    assert own.command_limit == own.torque_limit == 2.5 and "torque_limit" in own.torque_from


def test_torque_limit_belongs_to_joints_without_a_drive(tmp_path):
    text = (Path(__file__).resolve().parents[1] / "config" / "two_link_case1.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("      drive_damping: 5.1764", "      drive_damping: 5.1764\n"
                                "      torque_limit: 10.0", 1))
    with pytest.raises(SceneError, match=r"links\[0\]\.joint\.torque_limit"):
        load_scene(bad)


def test_explain_states_every_limit():
    from flexarm_ros.model.explain import explain
    text = explain(load_scene("two_link_case1"))
    assert "wire limits" in text
    assert "link1: voltage command within ±48 V (default" in text
    assert "effort within ±457.776 N·m" in text          # 156·0.0302·2·48 V / 0.9879832 Ω


def test_validator_rejects_by_reason_and_counts():
    v = Validator(load_scene("two_link_case1"), "command")
    assert v.check([1.5, -1.5]) is None and v.check([48.0, -48.0]) is None
    cases = {NON_FINITE: [[NAN, 0.0], [0.0, INF], [-INF, 1.0]], BEYOND: [[48.01, 0.0],
                                                                       [1e300, -1e300]],
             LENGTH: [[1.0], [], [1.0, 2.0, 3.0]], "not numbers": [["a", "b"], None, 3.0]}
    for why, items in cases.items():
        for data in items:
            assert v.check(data) == why, data
    assert v.rejected == 11 and v.counts[BEYOND] == 2
    e = Validator(load_scene("two_link_case1"), "effort")
    lim = joint_limits(load_scene("two_link_case1"))[0].torque_limit
    assert e.check([lim, 0.0]) is None and e.check([lim * (1 + 1e-9), 0.0]) == BEYOND


# ============================================================== cores (no ROS)
def test_a_rejected_command_changes_nothing_in_the_cores():
    """Lockstep with every bad command offered to the driver and every bad effort to the
    simulator's validator before each real one equals the clean co-simulation exactly."""
    scene = load_scene("two_link_case1")
    ref = cosimulate(scene, 0.05).messages
    ls = Lockstep(scene)
    got = []
    for _ in range(50):
        state = ls.state_messages()
        for data in BAD:
            assert not ls.drv.accept(ls.sim.t, data)
            assert ls.sim.validator.check(data) is not None
        ctrl = ls.control_messages(state)
        ls.sim.step(ctrl[1].data["data"])
        got.extend(state + ctrl)
    got.extend(ls.state_messages())
    assert [(m.topic, m.t_ns, m.data) for m in got] == [(m.topic, m.t_ns, m.data) for m in ref]
    assert dict(ls.drv.validator.counts) == {k: 50 * n for k, n in BAD_COUNTS.items()}


def test_driver_never_publishes_beyond_the_torque_limit():
    """A DC drive without current limit turned by the load far beyond its no-load speed
    would draw more than the plugging current 2·48 V/R: its torque is held at the limit
    (two_link_case1: quasi-static current i = (V − K_b·n·w)/R)."""
    scene = load_scene("two_link_case1")
    drv = DriverCore(scene)
    lim = joint_limits(scene)[0].torque_limit
    d = scene.links[0].joint.drive
    assert drv.accept(0.0, [-3.0, 0.0])
    tau = drv.update(0.0, 1e-3, [0.0, 0.0])                       # stall: -n·K_t·3/R
    assert tau[0] == pytest.approx(-d.gear_ratio * d.torque_constant * 3.0 / d.resistance,
                                   rel=1e-12) and drv.held == 0
    w = 200.0 / (d.back_emf_constant * d.gear_ratio)             # back-EMF 200 V
    tau = drv.update(0.0, 1e-3, [w, 0.0])
    assert tau[0] == -lim and drv.held == 1


def test_a_diverging_plant_raises_before_any_message_is_built():
    """[4e300, -1e300] N·m held on two_link_case1 (the issue's 1e300 V through the
    driver): SimulationDiverged naming the held torques, never a NaN encoder count
    (`ValueError: cannot convert float NaN to integer`)."""
    sim = SimulatorCore(load_scene("two_link_case1"))
    for _ in range(5):
        sim.outputs()
        sim.step([1.0, 1.0])
    with pytest.raises(SimulationDiverged, match=r"held \[4e\+300 N·m, -1e\+300 N·m\]") as exc:
        sim.step([4e300, -1e300])
    assert exc.value.time <= sim.t + sim.period


def test_a_diverging_plant_without_sensors_raises_too():
    """link has no sensors: nothing but the plant's own state test stands between a
    huge torque and a NaN joint_states message."""
    sim = SimulatorCore(load_scene("link"))
    sim.step([0.55])
    with pytest.raises(SimulationDiverged) as exc:
        for _ in range(3):
            sim.step([1e300])
    assert exc.value.quantity.startswith(("coordinate", "rate"))
    assert np.all(np.isfinite(sim.plant.x))                 # the last finite state stays


def test_open_loop_programs_beyond_the_default_limit_are_refused(tmp_path):
    text = (Path(__file__).resolve().parents[1] / "config" / "link_motor.yaml").read_text()
    p = tmp_path / "hot.yaml"
    p.write_text(text.replace("values: [3.0, -3.0]", "values: [60.0, -3.0]"))
    with pytest.raises(SceneError, match=r"inputs\[0\]\.voltage: got a program reaching 60 V"
                                         r".*supply_voltage"):
        ControllerCore(load_scene(p))


# ============================================================ hostile ROS runs
def _graph(**kw):
    from flexarm_ros.run import InProcessGraph
    return InProcessGraph(namespace=NS, **kw)


class Hostile:
    """Everything the issue's hostile user did, at ~1 kHz of wall time: bad and valid
    commands and efforts from a second publisher, a foreign /clock and joint_states
    stamped 1e6 s, encoder counts; messages of the wrong type (std_msgs/String,
    Int32MultiArray) on both command topics from two other DDS participants (rclpy
    refuses a second type on a topic within one participant); and, with ``sources``,
    the graph's own controller and driver sending BAD before each real message."""

    def __init__(self, g, sources=True):
        import rclpy
        from rclpy.context import Context
        from rclpy.node import Node
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray, Int32MultiArray, String

        from flexarm_ros.nodes.common import QOS
        self.g, self.k, self.sent = g, 0, 0
        self.F, self.I, self.S = Float64MultiArray, Int32MultiArray, String
        node = Node("hostile", namespace=NS, context=g.context)
        g.executor.add_node(node)
        g.nodes["hostile"] = node                      # closed with the graph
        self.pubs = {t: node.create_publisher(Float64MultiArray, t, QOS)
                     for t in (T.COMMANDS, T.EFFORTS)}
        self.counts = node.create_publisher(Int32MultiArray, T.ENCODER_COUNTS, QOS)
        self.clock = node.create_publisher(Clock, T.CLOCK, QOS)
        self.js = node.create_publisher(JointState, T.JOINT_STATES, QOS)
        self.Clock, self.JointState, self.Time = Clock, JointState, Time
        self.others = []
        for cls in (String, Int32MultiArray):            # wrong types, other participants
            ctx = Context()
            rclpy.init(context=ctx, domain_id=g.context.get_domain_id())
            n = Node(f"hostile_{cls.__name__.lower()}", namespace=NS, context=ctx)
            self.others.append((ctx, n, cls, [n.create_publisher(cls, t, QOS)
                                              for t in (T.COMMANDS, T.EFFORTS)]))
        self.timer = node.create_timer(0.001, self.fire)
        if sources:
            self._wrap(g["controller"].pub)
            self._wrap(g["motor_driver"].pub_eff)

    def _wrap(self, pub):
        real = pub.publish

        def publish(msg):
            for data in BAD:
                m = self.F()
                m.data = data
                real(m)
            real(msg)
        pub.publish = publish

    def fire(self):
        self.k += 1
        data = (BAD + [[0.5, -0.5]])[self.k % 6]          # valid ones too: refused as well
        for pub in self.pubs.values():
            m = self.F()
            m.data = data
            pub.publish(m)
        if self.k % 3 == 0:
            c = self.Clock()
            c.clock = self.Time(sec=1_000_000)
            self.clock.publish(c)
            js = self.JointState()
            js.header.stamp = self.Time(sec=1_000_000)
            js.name, js.position = ["link1_joint", "link2_joint"], [NAN, 1e300]
            self.js.publish(js)
            ic = self.I()
            ic.data = [7, 7]
            self.counts.publish(ic)
        for _, _, cls, pubs in self.others:
            for p in pubs:
                p.publish(cls(data="[nan, nan]") if cls is self.S else cls(data=[1, 2]))
        self.sent += 1

    def burst(self, n=400):
        """A burst of foreign messages at once (within the topics' keep_last 1000)."""
        for _ in range(n):
            self.fire()

    def close(self):
        import rclpy
        self.timer.cancel()
        for ctx, n, _, _ in self.others:
            n.destroy_node()
            rclpy.shutdown(context=ctx)


def _run(scene, mode, duration, path, sources=True, burst_at=None):
    """One in-process run under :class:`Hostile`; (graph counters, hostile sent)."""
    g = _graph(scene=scene, mode=mode, duration=duration, record=path)
    try:
        h = Hostile(g, sources)
        sim = g["simulator"]
        if burst_at is not None:
            assert g.spin_until(lambda: sim.core.t >= burst_at, 120)
            h.burst()
        assert g.spin_until(lambda: sim.finished, 300)
        sim.halt()
        assert g.spin_until(g.recorded_all, 60)
        h.close()
        out = {"sim": dict(sim.core.validator.counts),
               "drv": dict(g["motor_driver"].core.validator.counts),
               "ctl": g["controller"].rejections.summary(), "t": sim.core.t,
               "rejected": dict(sim.rejections.counts, **g["motor_driver"].rejections.counts),
               "torque_limit": np.array([lim.torque_limit for lim in
                                         joint_limits(load_scene(scene))])}
    finally:
        g.close()
    return out, h.sent


def _raw(path):
    out = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def _all_finite(bag):
    def fin(x):
        if isinstance(x, float):
            return math.isfinite(x)
        if isinstance(x, dict):
            return all(fin(v) for v in x.values())
        if isinstance(x, (list, tuple)):
            return all(fin(v) for v in x)
        return True
    return all(fin(to_dict(m)) for t in bag.topics for _, m in bag[t])


def _tip(messages):
    p = messages[-1]
    return np.array([p["point"]["x"], p["point"]["y"]])


@pytest.mark.ros
@pytest.mark.subprocess
def test_lockstep_under_attack_equals_the_clean_run_message_for_message(tmp_path):
    """two_link_case1, lockstep, 0.1 s: the graph's own controller and driver send NaN,
    ±inf, ±1e300 and wrong lengths before each real command/effort; a second publisher
    sends those and valid ones at ~1 kHz on both command topics, plus a foreign /clock and
    joint_states stamped 1e6 s and encoder counts, and a burst of 400 of them at 0.05 s;
    String and Int32MultiArray go out on both command topics. The bag equals the
    co-simulation on every topic of the contract, byte for byte and log time for log time
    (tip difference exactly 0); what was refused is in diagnostics/rejected, counted by
    reason; nothing is logged past the run's end; nothing non-finite."""
    path = tmp_path / "attack.mcap"
    counts, sent = _run("two_link_case1", "lockstep", 0.1, path, burst_at=0.05)
    assert sent > 400
    ref = cosimulate(load_scene("two_link_case1"), 0.1)
    raw = _raw(path)
    for topic in {m.topic for m in ref.messages}:
        want = [(m.t_ns, encode_cdr(m.msgtype, m.data)) for m in ref.topic(topic)]
        assert raw[T.resolve(NS, topic)] == want, topic
    bag = read_bag(path)
    tip = _tip([to_dict(m) for _, m in bag[f"{NS}/{T.GT_TIP}"]])
    assert np.array_equal(tip, _tip([m.data for m in ref.topic(T.GT_TIP)]))
    # the sources' bad messages, exactly (100 commands and 100 efforts were answered)
    for who in ("sim", "drv"):
        assert {k: counts[who][k] for k in BAD_COUNTS} == {k: 100 * n for k, n in
                                                           BAD_COUNTS.items()}, who
        assert counts[who][FOREIGN] > 0, who
    assert "second publisher" in counts["ctl"]
    end = 100_000_000
    assert max(t for msgs in raw.values() for t, _ in msgs) == end
    diag = [json.loads(m.data) for _, m in bag[f"{NS}/{T.REJECTED}"]]
    reasons = {(d["topic"], d["reason"]) for d in diag}
    for topic in (T.COMMANDS, T.EFFORTS):
        for why in (NON_FINITE, BEYOND, LENGTH, FOREIGN):
            assert (f"{NS}/{topic}", why) in reasons, (topic, why)
    for topic in ("/clock", f"{NS}/{T.JOINT_STATES}", f"{NS}/{T.ENCODER_COUNTS}"):
        assert (topic, FOREIGN) in reasons, topic
    meta = json.loads(bag.metadata["rejected_messages"]["by_topic"])
    assert meta[f"{NS}/{T.EFFORTS}"][NON_FINITE] == counts["sim"][NON_FINITE] == 200
    assert not bag.truncated and _all_finite(bag)


@pytest.mark.ros
@pytest.mark.subprocess
def test_realtime_under_attack_stays_finite_and_within_the_drive_limits(tmp_path):
    """The same attack in realtime (0.15 s): every step holds an accepted effort, so the
    plant stays finite, every effort on the wire and applied stays within the joints'
    torque limits, every command within ±48 V; the counts reach the run summary."""
    path = tmp_path / "rt.mcap"
    counts, _ = _run("two_link_case1", "realtime", 0.15, path)
    bag = read_bag(path)
    assert not bag.truncated and _all_finite(bag)
    lim = counts["torque_limit"]
    gt = [to_dict(m) for _, m in bag[f"{NS}/{T.GT_JOINT_STATES}"]]
    assert len(gt) >= 150
    assert all(np.all(np.abs(m["effort"][:2]) <= lim) for m in gt)
    assert all(np.all(np.abs(list(m.data)) <= lim) for _, m in bag[f"{NS}/{T.EFFORTS}"])
    assert all(np.all(np.abs(list(m.data)) <= 48.0) for _, m in bag[f"{NS}/{T.COMMANDS}"])
    assert counts["sim"][NON_FINITE] > 0 and counts["drv"][FOREIGN] > 0
    assert max(t for t, _ in bag.messages["/clock"]) == round(counts["t"] * 1e9)
    assert max(t for topic in bag.topics for t, _ in bag[topic]) <= round(counts["t"] * 1e9)


@pytest.mark.ros
@pytest.mark.subprocess
def test_recorder_stamps_with_the_simulators_clock_when_sent(tmp_path):
    """The recorder alone; a test node owns /clock (no simulator on the graph) and sends,
    per tick, /clock then joint_states and encoder counts. Every message is logged at the
    clock value published before it; a stamp beyond that (1e6 s) gets that time instead;
    nothing is logged past the last /clock."""
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Int32MultiArray

    from flexarm_ros.nodes.common import QOS
    path = tmp_path / "rec.mcap"
    g = _graph(scene="two_link_case1", mode="fast", nodes=(), record=path)
    try:
        rec = g["recorder"]
        node = Node("my_simulator", namespace=NS, context=g.context)
        g.executor.add_node(node)
        g.nodes["my_simulator"] = node
        pubs = [node.create_publisher(Clock, T.CLOCK, QOS),
                node.create_publisher(JointState, T.JOINT_STATES, QOS),
                node.create_publisher(Int32MultiArray, T.ENCODER_COUNTS, QOS)]
        assert g.spin_until(lambda: all(p.get_subscription_count() for p in pubs), 30)
        for k in range(4):
            pubs[0].publish(Clock(clock=Time(nanosec=k * 1_000_000)))
            js = JointState()
            js.header.stamp = Time(sec=1_000_000) if k == 2 else Time(nanosec=k * 1_000_000)
            pubs[1].publish(js)
            pubs[2].publish(Int32MultiArray(data=[k, k]))
        assert g.spin_until(lambda: all(rec.received.get(t, 0) == 4 for t in
                                        (T.CLOCK, T.JOINT_STATES, T.ENCODER_COUNTS)), 30)
    finally:
        g.close()
    bag = read_bag(path)
    want = [k * 1_000_000 for k in range(4)]
    for topic in ("/clock", f"{NS}/{T.JOINT_STATES}", f"{NS}/{T.ENCODER_COUNTS}"):
        assert [t for t, _ in bag[topic]] == want, topic


@pytest.mark.ros
def test_one_source_per_topic_the_latest_wins_and_a_successor_takes_over():
    """Without the graph's controller the first publisher whose command is taken owns
    motor_driver/commands: its latest command wins, a second publisher's valid commands
    are refused (counted, nothing changed) until the owner leaves the graph."""
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    from flexarm_ros.nodes.common import QOS
    g = _graph(scene="two_link_position", mode="realtime", duration=0.0,
               nodes=("motor_driver",))
    try:
        drv = g["motor_driver"]
        nodes, pubs = {}, {}
        for name in ("user_controller", "intruder"):
            nodes[name] = Node(name, namespace=NS, context=g.context)
            g.executor.add_node(nodes[name])
            g.nodes[name] = nodes[name]
            pubs[name] = nodes[name].create_publisher(Float64MultiArray, T.COMMANDS, QOS)

        def send(name, data, until):
            m = Float64MultiArray()
            m.data = data
            pubs[name].publish(m)
            return g.spin_until(until, 30)

        assert g.spin_until(lambda: pubs["user_controller"].get_subscription_count() >= 1, 30)
        assert send("user_controller", [1.0, 2.0], lambda: list(drv.core.command) == [1, 2])
        v = drv.core.validator
        assert send("intruder", [3.0, 3.0], lambda: v.counts[FOREIGN] == 1)
        assert list(drv.core.command) == [1.0, 2.0]
        assert send("user_controller", [NAN, 1.0], lambda: v.counts[NON_FINITE] == 1)
        assert send("user_controller", [1.5, -1.5], lambda: list(drv.core.command) == [1.5, -1.5])
        assert send("intruder", [3.0, 3.0], lambda: v.counts[FOREIGN] == 2)
        assert list(drv.core.command) == [1.5, -1.5]
        g.remove("user_controller")                       # the owner leaves the graph
        assert send("intruder", [3.0, 3.0], lambda: list(drv.core.command) == [3.0, 3.0])
        assert v.counts[FOREIGN] == 2
    finally:
        g.close()


@pytest.mark.parametrize("in_process", [True, False])
def test_the_expected_node_of_another_run_is_refused_as_another_run(in_process):
    """Two twin runs on one domain and namespace show two nodes named ``controller`` on
    the graph (issue 39). The driver's source rule takes only its own run's: in one
    process the bus's own publisher (known without discovery), one node per process the
    one it saw first (after its start condition, with no other twin on the graph).
    Another run's is refused with the reason ``another run``; a user's node of another
    name stays a second publisher."""
    from types import SimpleNamespace
    from flexarm_ros.nodes import _wire, intraprocess
    from flexarm_ros.twin.validation import ANOTHER_RUN
    topic = f"{NS}/{T.COMMANDS}"
    mine, theirs, user = bytes([1] * 16), bytes([2] * 16), bytes([3] * 16)
    shown = {mine: "controller"}

    class Context:
        pass

    context = Context()
    context.get_domain_id = lambda: 0
    import os
    from flexarm_ros.nodes.run_enclave import RUN_ENCLAVE_PREFIX
    my_run = f"{RUN_ENCLAVE_PREFIX}1000_{os.getpid()}_aaaaaa"
    their_run = f"{RUN_ENCLAVE_PREFIX}2000_{os.getpid()}_bbbbbb"
    enclaves = [("controller", NS, my_run)]          # the graph's nodes with enclaves

    def fake_node():
        return SimpleNamespace(
            context=context, get_namespace=lambda: NS, p={"run_enclave": my_run},
            count_publishers=lambda t: len(shown),
            get_publishers_info_by_topic=lambda t: [
                SimpleNamespace(endpoint_gid=g, node_name=n, node_namespace=NS)
                for g, n in shown.items()],
            get_node_names_and_namespaces_with_enclaves=lambda: list(enclaves))
    node = fake_node()
    if in_process:
        intraprocess._BUSES[context] = SimpleNamespace(
            bridge=None, members={(NS, "controller")}, local_publishers=lambda t, name, ns:
            {mine} if (t, name, ns) == (topic, "controller", NS) else set())
    try:
        src = _wire.Source(node, topic, expected="controller")
        if not in_process:
            assert src.verdict({"publisher_gid": {"data": mine}}) is None   # pinned
        shown[theirs] = "controller"           # the newer run's controller appears
        enclaves.append(("controller", NS, their_run))
        if not in_process:        # a rule that saw neither yet: it cannot tell, takes none
            late = _wire.Source(fake_node(), topic, expected="controller")
            for gid in (theirs, mine):
                assert late.verdict({"publisher_gid": {"data": gid}}) == \
                    "controller of another run"
            assert late.mine is None
        if in_process:                          # the bus knows its own at once
            assert src.verdict({"publisher_gid": {"data": theirs}}) == \
                "controller of another run"
            assert src.reason == ANOTHER_RUN
        assert src.verdict({"publisher_gid": {"data": mine}}) is None
        assert src.trusted({"publisher_gid": {"data": mine}})
        assert src.verdict({"publisher_gid": {"data": theirs}}) == "controller of another run"
        assert src.reason == ANOTHER_RUN
        shown[user] = "my_controller"
        assert src.verdict({"publisher_gid": {"data": user}}) == "my_controller"
        assert src.reason == FOREIGN
        assert src.verdict({"publisher_gid": {"data": mine}}) is None
    finally:
        intraprocess._BUSES.pop(context, None)


# ================================================================= divergence
def _diverging_scene(tmp_path):
    """link with fidelity.max_deflection_ratio 1e-4: the 0.55 N·m pulse bends the beam
    past it at t = 4.75 ms (flexarm simulate stops there with status 3)."""
    text = (Path(__file__).resolve().parents[1] / "config" / "link.yaml").read_text()
    p = tmp_path / "link_diverges.yaml"
    text = re.sub(r"  rung: modal.*\n  refine: 3.*\n", "  rung: fd\n  refine: 10\n", text)
    assert "rung: fd" in text                  # the seed's own model, whose step these pin
    # the pins below are RK4's (the scene steps lawson4 since session 21)
    text, n = re.subn(r"  integrator: \w+.*\n", "  integrator: rk4\n"
                      "  max_deflection_ratio: 1.0e-4\n", text, count=1)
    assert n == 1
    p.write_text(text)
    return p


def _check_diverged_bag(path):
    bag = read_bag(path)
    assert not bag.truncated and bag.rosbag2_metadata() is not None
    clocks = [t for t, _ in bag["/clock"]]
    assert clocks == [k * 1_000_000 for k in range(5)]        # up to the divergence
    assert len(bag[f"{NS}/{T.GT_TIP}"]) == 5
    assert _all_finite(bag)


@pytest.mark.ros
@pytest.mark.subprocess
def test_divergence_in_a_run_exits_3_with_one_message(tmp_path, capsys):
    from flexarm_ros.cli import main
    out = tmp_path / "div.mcap"
    assert main(["run", str(_diverging_scene(tmp_path)), "--duration", "0.5", "--record",
                 str(out), "--quiet"]) == 3
    cap = capsys.readouterr()
    assert cap.err.count("simulation diverged") == 1 and "Traceback" not in cap.err
    assert "tip deflection of link1 at t = 0.00475 s" in cap.err and "To fix:" in cap.err
    assert "diverged" in cap.out
    _check_diverged_bag(out)


@pytest.mark.subprocess
def test_divergence_in_a_run_with_processes_exits_3_with_one_message(tmp_path):
    out = tmp_path / "divp.mcap"
    exe = Path(sys.executable).with_name("flexarm")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]
    r = subprocess.run(cmd + ["run", str(_diverging_scene(tmp_path)), "--duration", "0.5",
                              "--record", str(out), "--quiet", "--processes"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 3, r.stderr
    assert r.stderr.count("simulation diverged") == 1 and "Traceback" not in r.stderr
    assert "tip deflection of link1 at t = 0.00475 s" in r.stderr
    _check_diverged_bag(out)
