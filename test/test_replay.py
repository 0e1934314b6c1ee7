"""`flexarm replay`: a bag republished on ROS 2 (a subprocess with its own domain) is
received by an rclpy subscriber in this test with the bag's counts and payloads, and
/clock carrying the bag's log times; pacing by --rate, --namespace/--topics, Ctrl-C,
and bad input (exit 2 naming the file)."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from flexarm_ros.bag import BagWriter, read_bag, to_dict
from flexarm_ros.scene import load_scene, resolve_scene_path
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cosim import cosimulate

NS = "/flexarm"
SCENE = "two_link_case1"
DURATION = 0.05


def _domain(k):
    """A ROS domain of its own per test (150..229; conftest and `flexarm run` use less)."""
    return 150 + (os.getpid() + 7 * k) % 80


def _env(domain):
    return dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                ROS_DOMAIN_ID=str(domain))


@pytest.fixture(scope="module")
def bag_path(tmp_path_factory):
    """What `flexarm run two_link_case1 --duration 0.05` records (its messages are the
    co-simulation's, test_run.py), written without ROS."""
    path = tmp_path_factory.mktemp("replay") / "case1.mcap"
    info = {"scene": SCENE, "scene_yaml": resolve_scene_path(SCENE).read_text(),
            "namespace": NS, "time_mode": "lockstep"}
    with BagWriter(path, metadata=info) as w:
        for m in cosimulate(load_scene(SCENE), DURATION).messages:
            w.write(T.resolve(NS, m.topic), m.msgtype, m.data, m.t_ns)
    return path


class Listener:
    """Subscribes (reliable, depth 1000) to ``topics`` {name: type} in ``domain``;
    ``got[topic]`` = [(plain dict, monotonic receive time)]."""

    def __init__(self, domain, topics):
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        from flexarm_ros.nodes.common import make_executor, subscription
        from flexarm_ros.nodes._msgconv import to_dict as ros_dict
        self.rclpy, self.ctx = rclpy, Context()
        rclpy.init(context=self.ctx, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("replay_listener", context=self.ctx)
        self.exe = make_executor(self.ctx)
        self.exe.add_node(self.node)
        self.got = {t: [] for t in topics}
        for topic, tp in topics.items():
            subscription(self.node, tp, topic, lambda m, topic=topic: self.got[topic].append(
                (ros_dict(m), time.monotonic())))

    def spin_while(self, cond, timeout):
        t0 = time.monotonic()
        while cond() and time.monotonic() - t0 < timeout:
            self.exe.spin_once(timeout_sec=0.02)

    def close(self):
        self.exe.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)


def _replay(bag, domain, *args):
    return subprocess.Popen([sys.executable, "-m", "flexarm_ros.cli", "replay", str(bag),
                             "--json", "--quiet", *args], env=_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finish(listener, proc, expected, timeout=60.0):
    """Spin until the replay exits and ``expected()`` holds (or the time is up)."""
    listener.spin_while(lambda: proc.poll() is None, timeout)
    listener.spin_while(lambda: not expected(), 5.0)
    out, err = proc.communicate(timeout=10)
    return out, err


@pytest.mark.ros
@pytest.mark.subprocess
def test_replay_publishes_the_bag_with_its_clock(bag_path):
    bag = read_bag(bag_path)
    data = {t: [to_dict(m) for _, m in bag[t]] for t in bag.topics if t != T.CLOCK}
    topics = {t: bag.types[t] for t in data} | {T.CLOCK: "rosgraph_msgs/msg/Clock"}
    log_times = sorted({t for topic in data for t, _ in bag[topic]})
    assert len(data) >= 11 and len(log_times) == round(DURATION * 1000) + 1
    domain = _domain(1)
    listener = Listener(domain, topics)
    try:
        proc = _replay(bag_path, domain, "--rate", "0", "--wait-subscribers", "1",
                       "--delay", "0.2")
        out, err = _finish(listener, proc, lambda: all(
            len(listener.got[t]) >= len(v) for t, v in data.items()) and
            len(listener.got[T.CLOCK]) >= len(log_times))
    finally:
        listener.close()
    assert proc.returncode == 0, err
    report = json.loads(out)
    assert report["published"] == {t: len(v) for t, v in data.items()}
    assert report["clock"] == len(log_times) and not report["interrupted"]
    for topic, want in data.items():
        got = [json.dumps(d) for d, _ in listener.got[topic]]          # NaN == NaN here
        assert got == [json.dumps(d) for d in want], topic              # counts, payloads
    clock = [d["clock"]["sec"] * 10**9 + d["clock"]["nanosec"] for d, _ in listener.got[T.CLOCK]]
    assert clock == log_times
    assert clock == [t for t, _ in bag[T.CLOCK]]            # = the recorded /clock too


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_rate_namespace_and_topic_selection(bag_path):
    """--rate 0.25 stretches the 50 ms bag to 200 ms of wall time; --namespace moves the
    selected topics (and only those) under /other; /clock stays global."""
    domain = _domain(2)
    topics = {"/other/joint_states": "sensor_msgs/msg/JointState",
              "/other/tool/contact": "std_msgs/msg/Bool",
              "/flexarm/joint_states": "sensor_msgs/msg/JointState",
              "/other/ground_truth/tip": "geometry_msgs/msg/PointStamped",
              T.CLOCK: "rosgraph_msgs/msg/Clock"}
    listener = Listener(domain, topics)
    n = round(DURATION * 1000) + 1
    try:
        proc = _replay(bag_path, domain, "--rate", "0.25", "--namespace", "/other",
                       "--topics", "joint_states", "/flexarm/tool/contact",
                       "--wait-subscribers", "1", "--delay", "0.2")
        out, err = _finish(listener, proc, lambda: len(listener.got[T.CLOCK]) >= n)
    finally:
        listener.close()
    assert proc.returncode == 0, err
    report = json.loads(out)
    assert report["published"] == {"/other/joint_states": n, "/other/tool/contact": n}
    got = {t: len(v) for t, v in listener.got.items()}
    assert got == {"/other/joint_states": n, "/other/tool/contact": n,
                   "/flexarm/joint_states": 0, "/other/ground_truth/tip": 0, T.CLOCK: n}
    stamps = [s for _, s in listener.got[T.CLOCK]]
    assert stamps[-1] - stamps[0] > 0.9 * DURATION / 0.25           # paced, not flooded
    assert 0.9 * DURATION / 0.25 < report["wall_s"] < 2.0


@pytest.mark.ros
@pytest.mark.subprocess
def test_ctrl_c_stops_a_loop_cleanly(bag_path):
    domain = _domain(3)
    listener = Listener(domain, {T.CLOCK: "rosgraph_msgs/msg/Clock"})
    try:
        proc = _replay(bag_path, domain, "--rate", "1", "--loop", "--delay", "0")
        listener.spin_while(lambda: len(listener.got[T.CLOCK]) < 120 and proc.poll() is None,
                            60.0)                                  # past the first pass
        assert proc.poll() is None, proc.communicate()[1]
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        listener.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    report = json.loads(out)
    assert report["interrupted"] and report["loops"] >= 1
    assert report["clock"] >= len(listener.got[T.CLOCK]) >= 120


@pytest.mark.parametrize("content", [None, b"", b"hello, not a bag\n"])
def test_bad_input_exits_2_naming_the_file(tmp_path, capsys, content):
    from flexarm_ros.cli import main
    path = tmp_path / "input.mcap"
    if content is not None:
        path.write_bytes(content)
    assert main(["replay", str(path), "--rate", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flexarm replay: error:") and str(path) in err


def test_unknown_topic_and_bad_rate_exit_2(bag_path, capsys):
    from flexarm_ros.cli import main
    assert main(["replay", str(bag_path), "--topics", "no/such/topic"]) == 2
    err = capsys.readouterr().err
    assert "'no/such/topic' is not in the bag" in err and "/flexarm/joint_states" in err
    assert main(["replay", str(bag_path), "--rate", "-1"]) == 2
    assert "--rate" in capsys.readouterr().err
