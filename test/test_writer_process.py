"""The recorder's bag written by a child process (flexarm_ros/bag/writer_process.py): the
same records as in one process, a finalized bag when the parent dies, errors that name
the file."""

import subprocess
import sys
import textwrap

import pytest

from flexarm_ros.bag import read_bag
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.bag.stamping import SimTimeStamper
from flexarm_ros.bag.writer_process import WriterProcess, WriterProcessError
from flexarm_ros.bag import BagWriter

pytestmark = [pytest.mark.subprocess]

NAMES = {"clock": "/clock", "joint_states": "/ns/joint_states", "r": "/ns/rejected"}
CLOCK = "rosgraph_msgs/msg/Clock"
JS = "sensor_msgs/msg/JointState"


def _feed(sink, n=300):
    """A simulator's pattern: per tick a /clock, then messages sent before and after it
    (held until the next clock), some with a header stamp of an earlier tick, and a
    rejected message as a dict."""
    for k in range(n):
        t = k * 1_000_000
        ts = 10_000 + 100 * k                    # source timestamps (host clock)
        clock = encode_cdr(CLOCK, {"clock": {"sec": 0, "nanosec": t}})
        if k % 7 == 3:                           # arrives before its clock: held
            sink.emit(ts + 1, "joint_states", JS, encode_cdr(JS, _js(t)), t)
        sink.clock(ts, "clock", CLOCK, clock, t)
        sink.emit(ts + 2, "joint_states", JS, encode_cdr(JS, _js(max(0, t - 3_000_000))),
                  max(0, t - 3_000_000))
        if k % 50 == 0:
            sink.emit(ts + 3, "r", "std_msgs/msg/String", {"data": f"rejected {k}"})


def _js(t):
    return {"header": {"stamp": {"sec": 0, "nanosec": t}, "frame_id": ""},
            "name": ["a"], "position": [t * 1e-9], "velocity": [1.0], "effort": [-0.5]}


def _records(path):
    """[(topic, log time, CDR bytes)] in file order, and the bag."""
    from mcap.reader import make_reader
    with open(path, "rb") as f:
        recs = [(ch.topic, m.log_time, m.data)
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]
    return recs, read_bag(path)


def test_the_child_writes_the_records_one_process_writes(tmp_path):
    info = {"scene": "x"}
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, b = tmp_path / "a" / "run.mcap", tmp_path / "b" / "run.mcap"   # the name is in it
    w = BagWriter(a, metadata=info, qos_depth=10)
    w.add_metadata("model", {"explain": "m"})
    local = SimTimeStamper(w, NAMES)
    _feed(local)
    local.close({"rejected_messages": {"total": "6"}})
    child = WriterProcess(b, info, 10, {"model": {"explain": "m"}}, NAMES)
    _feed(child)
    child.close({"rejected_messages": {"total": "6"}})
    ra, bag_a = _records(a)
    rb, bag_b = _records(b)
    assert len(ra) == 300 * 2 + 300 // 7 + 6 + 1 and ra == rb
    assert bag_a.metadata == bag_b.metadata
    assert bag_b.metadata["rejected_messages"]["total"] == "6"


def test_the_bag_is_finalized_when_the_parent_dies(tmp_path):
    """The parent hands over 200 ticks and dies without closing (os._exit: what SIGKILL
    leaves): the child finalizes the file with all of them."""
    out = tmp_path / "orphan.mcap"
    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(tmp_path)!r})
        from test_writer_process_feed import _feed, NAMES
        from flexarm_ros.bag.writer_process import WriterProcess
        w = WriterProcess({str(out)!r}, {{"scene": "x"}}, 10, {{}}, NAMES)
        _feed(w, 200)
        w._send()
        os._exit(9)
    """)
    from pathlib import Path
    (tmp_path / "test_writer_process_feed.py").write_text(Path(__file__).read_text())
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 9, r.stderr
    import time
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30:
        try:
            recs, bag = _records(out)
            if bag.rosbag2_metadata():
                break
        except Exception:
            pass
        time.sleep(0.2)
    assert not bag.truncated
    assert len([r for r in recs if r[0] == "/clock"]) == 200


def test_a_bag_that_cannot_be_opened_is_an_error_naming_it(tmp_path):
    bad = tmp_path / "no" / "such" / "dir" / "x.mcap"
    with pytest.raises(WriterProcessError, match="no/such/dir/x.mcap"):
        WriterProcess(bad, {"scene": "x"}, 10, {}, NAMES)
