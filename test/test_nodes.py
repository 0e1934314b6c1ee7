"""The twin's ROS 2 nodes one by one: message conversion, --help, the core packages
without rclpy, malformed commands at the driver, the driver's watchdog."""

import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from flexarm_ros.bag import read_bag, to_dict
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.scene import load_scene
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import DriverCore
from flexarm_ros.twin.cosim import cosimulate

ROOT = Path(__file__).resolve().parents[1]
NS = "/flexarm"


# ----------------------------------------------------------------------- conversion
@pytest.mark.parametrize("scene", ["two_link_case1", "two_link_sanding", "hydraulic_2kg"])
def test_message_dicts_survive_rclpy_objects_bit_for_bit(scene):
    from flexarm_ros.nodes._msgconv import to_dict as msg_to_dict
    from flexarm_ros.nodes._msgconv import to_msg
    sc = load_scene(scene)
    if scene == "hydraulic_2kg":       # its 6 ms sensor grid needs a matching control rate
        import dataclasses
        sc = dataclasses.replace(sc, control=dataclasses.replace(sc.twin_control, rate_hz=500 / 3))
    res = cosimulate(sc, 0.02)
    assert {m.topic for m in res.messages} >= {T.CLOCK, T.JOINT_STATES, T.EFFORTS}
    for m in res.messages:
        back = msg_to_dict(to_msg(m.msgtype, m.data))
        assert back == m.data, m.topic
        assert encode_cdr(m.msgtype, back) == encode_cdr(m.msgtype, m.data)


# -------------------------------------------------------------------------- packaging
@pytest.mark.subprocess
@pytest.mark.parametrize("node", ["simulator", "motor_driver", "controller", "recorder"])
def test_node_help_prints_usage_and_parameters(node):
    r = subprocess.run([sys.executable, "-m", f"flexarm_ros.nodes.{node}", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"usage: {node}")
    for p in ("scene", "mode", "duration", "recorders", "rung", "refine", "integrator",
              "rtol", "atol", "dt", "no_foreshortening"):
        assert f"  {p} (default" in r.stdout


@pytest.mark.subprocess
def test_node_reports_a_bad_scene_and_exits_2():
    r = subprocess.run([sys.executable, "-m", "flexarm_ros.nodes.controller", "--ros-args",
                        "-p", "scene:=no_such_scene"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert "no_such_scene" in r.stderr


@pytest.mark.subprocess
def test_core_packages_import_and_cosimulate_without_rclpy():
    code = textwrap.dedent("""
        import sys
        BLOCKED = ("rclpy", "rosidl", "rcl_interfaces", "std_msgs", "sensor_msgs",
                   "geometry_msgs", "rosgraph_msgs", "builtin_interfaces")

        class Block:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0].startswith(BLOCKED):
                    raise ImportError(f"blocked: {name}")
                return None

        sys.meta_path.insert(0, Block())
        import flexarm_ros.model, flexarm_ros.twin, flexarm_ros.control, flexarm_ros.bag
        import flexarm_ros.nodes.environment, flexarm_ros.nodes.parameters, flexarm_ros.run
        from flexarm_ros.scene import load_scene
        from flexarm_ros.twin.cosim import cosimulate
        res = cosimulate(load_scene("link_motor"), 0.005)
        assert len(res.messages) > 10
        try:
            import flexarm_ros.nodes.simulator
        except ImportError:
            pass
        else:
            raise SystemExit("the hook did not block rclpy")
        bad = [m for m in sys.modules if m.split(".")[0].startswith(BLOCKED)]
        assert not bad, bad
        print("ok")
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.strip().endswith("ok")


# ------------------------------------------------------------------------------ faults
def _graph(**kw):
    from flexarm_ros.run import InProcessGraph
    return InProcessGraph(namespace=NS, **kw)


@pytest.mark.ros
def test_malformed_commands_never_crash_the_driver_nor_reach_the_plant(capfd):
    from std_msgs.msg import Float64MultiArray
    g = _graph(scene="two_link_position", mode="fast", duration=0.3)
    try:
        sim, drv = g["simulator"], g["motor_driver"]
        from rclpy.node import Node
        node = Node("fault_injector", namespace=NS, context=g.context)   # the test's node
        g.executor.add_node(node)
        from flexarm_ros.nodes.common import QOS
        pub = node.create_publisher(Float64MultiArray, T.COMMANDS, QOS)
        efforts = []
        node.create_subscription(Float64MultiArray, T.EFFORTS,
                                 lambda m: efforts.append(list(m.data)), QOS)
        assert g.spin_until(lambda: sim.started and pub.get_subscription_count() >= 1, 30)
        assert g.spin_until(lambda: sim.core.t > 0.05, 60)
        bad = [[math.nan, 0.0], [0.0, math.inf], [1.0, 2.0, 3.0], [], [-math.inf, 1.0]] * 4
        for data in bad:
            m = Float64MultiArray()
            m.data = data
            pub.publish(m)
        assert g.spin_until(lambda: drv.rejected >= len(bad), 30)
        assert g.spin_until(lambda: sim.finished, 120)
        assert drv.rejected == len(bad)
        assert efforts and all(len(e) == 2 and all(map(math.isfinite, e)) for e in efforts)
        assert np.all(np.isfinite(sim.torque))
        assert np.all(np.isfinite(sim.core.plant.x))
        node.destroy_node()
    finally:
        g.close()
    err = capfd.readouterr().err
    warnings_logged = err.count("rejected command")
    assert 1 <= warnings_logged < len(bad)          # logged, and throttled


def _zero_volt_torques(scene, rates):
    """Joint torques of the motors at 0 V with the drives turning at ``rates``."""
    return DriverCore(scene).update(0.0, 1e-3, rates)


def _check_watchdog(path, scene, duration, slack_ticks=5):
    """After the last command the driver holds it for control.watchdog_s, then every
    effort is the 0 V torque (back-EMF only) while the simulation runs on to the end.

    Efforts carry no stamp: the n-th effort goes with the n-th motor_states message (the
    driver publishes both for one ground-truth state, whose stamp motor_states carries).
    A command's log time is the recorder's latest /clock, exact only in lockstep: the trip
    time is checked to ``slack_ticks`` control periods."""
    bag = read_bag(path)
    n = len(scene.links)
    period = 1.0 / scene.twin_control.rate_hz
    cmds = bag.messages[f"{NS}/{T.COMMANDS}"]
    efforts = bag.messages[f"{NS}/{T.EFFORTS}"]
    states = bag.messages[f"{NS}/{T.MOTOR_STATES}"]
    gt = {t: to_dict(m) for t, m in bag.messages[f"{NS}/{T.GT_JOINT_STATES}"]}
    clock = bag.messages[T.CLOCK]
    assert clock[-1][0] == pytest.approx(duration * 1e9, abs=2e6)   # the arm coasts on
    assert len(efforts) == len(states) and len(efforts) >= duration / period - 2
    t_last = cmds[-1][0]
    assert t_last < duration * 1e9 - 0.1e9, "the controller was not stopped early enough"
    zero = []
    for (_, tau), (t, ms) in zip(efforts, states):
        tau = list(tau.data)
        assert len(tau) == n and np.all(np.isfinite(tau))
        rates = gt[t]["velocity"][n:2 * n]
        zero.append((t, np.allclose(tau, _zero_volt_torques(scene, rates), rtol=0, atol=1e-12)))
    last_live = max(i for i, (_, z) in enumerate(zero) if not z)
    assert last_live < len(zero) - 20                   # 0 V from then on, to the end
    t_trip = zero[last_live + 1][0]
    held = (t_trip - t_last) * 1e-9
    assert held == pytest.approx(scene.twin_control.watchdog_s + period, abs=slack_ticks * period)
    assert sum(not z for _, z in zero) > 50             # it was driving before


@pytest.mark.ros
@pytest.mark.subprocess
def test_driver_watchdog_zero_volts_when_the_controller_dies(tmp_path):
    scene = load_scene("two_link_position")
    out = tmp_path / "watchdog.mcap"
    g = _graph(scene="two_link_position", mode="fast", duration=0.4, record=out)
    try:
        sim, drv = g["simulator"], g["motor_driver"]
        assert g.spin_until(lambda: sim.core.t >= 0.1, 60)
        g.remove("controller")
        assert not drv.core.tripped
        assert g.spin_until(lambda: sim.finished, 120)
        assert g.spin_until(g.recorded_all, 30)
        assert drv.core.tripped
    finally:
        g.close()
    _check_watchdog(out, scene, 0.4, slack_ticks=2)


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.subprocess
def test_killed_controller_process_trips_the_watchdog(tmp_path):
    """--processes: SIGKILL the controller process; the driver (another process) goes to
    0 V within control.watchdog_s and the simulator runs to the end."""
    import signal

    from rosgraph_msgs.msg import Clock

    from flexarm_ros.run import InProcessGraph, ProcessGraph
    scene = load_scene("two_link_position")
    out = tmp_path / "killed.mcap"
    # the watcher (the test's node) subscribes before the graph starts, so it sees /clock
    # from the first tick (the simulator does not wait for it: a late match made it miss
    # the whole run on a loaded machine), and the run is long enough to kill at 0.3 s
    watcher = InProcessGraph(nodes=())                 # an empty graph: the test's node
    from rclpy.node import Node
    node = Node("watcher", context=watcher.context)
    watcher.executor.add_node(node)
    watcher.nodes["watcher"] = node                    # closed with the graph
    now = [0.0]
    from flexarm_ros.nodes.common import QOS
    node.create_subscription(Clock, T.CLOCK, lambda m: now.__setitem__(
        0, m.clock.sec + 1e-9 * m.clock.nanosec), QOS)
    pg = ProcessGraph("two_link_position", "fast", 2.0, out, NS)
    try:
        assert watcher.spin_until(lambda: node.count_publishers(T.CLOCK) > 0, 120)
        assert watcher.spin_until(lambda: now[0] >= 0.3, 120)
        watcher.close()         # before the kill, as in test_run's SIGKILL test (0034)
        pg.signal("controller", signal.SIGKILL)
        pg.procs["simulator"].wait(timeout=300)        # runs to its end without the controller
    finally:
        codes = pg.stop()
        watcher.close()
    assert codes["simulator"] == 0 and codes["recorder"] == 0
    assert codes["controller"] == -signal.SIGKILL
    _check_watchdog(out, scene, 2.0)


def test_environment_stays_on_loopback():
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert 0 < int(os.environ["ROS_DOMAIN_ID"]) <= 101


def test_environment_sets_defaults_and_keeps_what_the_user_set():
    from flexarm_ros.nodes import environment
    env = {}
    environment.use_loopback(env)
    assert env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}     # no private domain
    env = {}
    got = environment.private_graph(env, pid=4242)
    assert got == env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                          "ROS_DOMAIN_ID": str(1 + 4242 % 101)}
    for pid in (0, 100, 101, 2**22):
        assert 1 <= int(environment.private_graph({}, pid=pid)["ROS_DOMAIN_ID"]) <= 101
    user = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DOMAIN_ID": "7"}
    assert environment.private_graph(dict(user)) == user
    assert environment.domain_id(user) == 7 and environment.domain_id({}) == 0
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID: got 'seven'"):
        environment.domain_id({"ROS_DOMAIN_ID": "seven"})


@pytest.mark.heavy
def test_nothing_imports_the_cli():
    """The command line is the top: no module of the package, tool or benchmark imports
    it (the console script ``flexarm`` runs it, tests may import it)."""
    import ast
    offenders = []
    for folder in ("flexarm_ros", "tools", "bench"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    mod = node.module or ""
                    names = [mod] + [f"{mod}.{a.name}" for a in node.names]
                    if node.level:                      # relative: resolve against path
                        names = [".".join(path.relative_to(ROOT).with_suffix("").parts[
                            :-node.level]) + "." + n for n in names]
                if any(n == "flexarm_ros.cli" or n.startswith("flexarm_ros.cli.")
                       for n in names):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, offenders


@pytest.mark.parametrize("over", [
    {"rung": "rigid"},
    {"rung": "fem", "refine": 3, "integrator": "dop853", "rtol": 1e-6, "atol": 1e-9,
     "dt": 0.0, "foreshortening": False},
    {"refine": 0, "dt": 2e-4, "foreshortening": True},
])
def test_fidelity_overrides_survive_the_node_parameters(over):
    from flexarm_ros.nodes.parameters import FIDELITY, fidelity_overrides, fidelity_parameters
    params = fidelity_parameters(over)
    assert all(type(v) is type(FIDELITY[k][0]) for k, v in params.items())
    values = {k: d for k, (d, _) in FIDELITY.items()}
    values.update(params)
    want = {k: v for k, v in over.items() if not (k == "foreshortening" and v)}
    assert fidelity_overrides(values) == want
    assert fidelity_overrides({k: d for k, (d, _) in FIDELITY.items()}) == {}
