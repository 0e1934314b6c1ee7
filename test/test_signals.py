"""`flexarm run --processes` and signals: the node processes die with their parent
whatever kills it (SIGKILL included), and a terminal's Ctrl-C (SIGINT to the whole
process group: the parent and every node) ends the run with exit 0 and a finalized bag.

Children are found and checked by pid through /proc (Linux, where the parent-death
signal exists); a zombie counts as gone (it has exited, its parent just did not reap
it)."""

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import NonSeekingReader, make_reader

from flexarm_ros.bag import TruncatedBagWarning, read_bag
from flexarm_ros.run import NODES, die_with_parent

pytestmark = [pytest.mark.subprocess,
              pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="the parent-death signal and /proc are Linux's")]


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out += [int(p) for p in (task / "children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError):   # a thread that just ended
            continue
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _start(out: Path):
    """`flexarm run link_motor --processes` recording to ``out``, in a process group of
    its own (what a terminal's job is); returns once the bag holds recorded chunks and
    every node process is up: (parent, node pids)."""
    exe = Path(sys.executable).with_name("flexarm")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]
    proc = subprocess.Popen(cmd + ["run", "link_motor", "--processes", "--duration", "100",
                                   "--record", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    t0 = time.monotonic()
    while not (out.exists() and out.stat().st_size > 20_000):
        if proc.poll() is not None or time.monotonic() - t0 > 240:
            _cleanup(proc)
            pytest.fail(f"the run did not start recording: {proc.communicate()}")
        time.sleep(0.1)
    kids = _children(proc.pid)
    names = {n for n in NODES for k in kids if f"flexarm_ros.nodes.{n} " in _cmdline(k)}
    assert names == set(NODES), [_cmdline(k) for k in kids]
    return proc, kids


def _signal_node(out: Path, node: str, sig):
    """:func:`_start` recording to ``out``, then ``sig`` to the process of ``node`` from
    outside the run; (the finished parent, its stdout, its stderr)."""
    proc, kids = _start(out)
    try:
        pid = next(k for k in kids if f"flexarm_ros.nodes.{node} " in _cmdline(k))
        os.kill(pid, sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        _cleanup(proc)
    return proc, stdout, stderr


def _cleanup(proc):
    try:
        os.killpg(proc.pid, signal.SIGKILL)          # the whole job, nodes included
    except ProcessLookupError:
        pass
    proc.communicate(timeout=30)                     # reaps it and closes the pipes


@pytest.mark.heavy
def test_sigkill_of_the_parent_takes_the_nodes_down(tmp_path):
    """SIGKILL cannot be caught by `flexarm run`; the kernel's parent-death signal
    (SIGTERM) still reaches every node: none is left after 2 s, and the recorder, stopped
    like on Ctrl-C, leaves a finalized bag."""
    out = tmp_path / "killed_parent.mcap"
    proc, kids = _start(out)
    try:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        t0 = time.monotonic()
        while any(_alive(k) for k in kids) and time.monotonic() - t0 < 10:
            time.sleep(0.02)
        waited = time.monotonic() - t0
        left = {k: _cmdline(k) for k in kids if _alive(k)}
        assert not left and waited <= 2.0, (waited, left)
    finally:
        _cleanup(proc)
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 100
    bag = read_bag(out)
    assert not bag.truncated and bag.message_count == summary.statistics.message_count


def test_ctrl_c_to_the_process_group_exits_130_with_a_finalized_bag(tmp_path):
    """What a terminal's Ctrl-C sends: SIGINT to the parent and to every node at once.
    Each node stops on its own, the parent's orderly SIGTERM finds them stopping (and
    must not kill one mid-exit), the recorder finalizes: exit 130 with one line (issue
    39), and mcap's indexed and stream readers read the bag with its summary."""
    out = tmp_path / "ctrl_c.mcap"
    proc, kids = _start(out)
    try:
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        _cleanup(proc)
    assert proc.returncode == 130, stderr
    assert "interrupted by SIGINT" in stdout and "nodes exited" not in stderr
    assert "Traceback" not in stderr and "ended early" not in stderr
    assert not any(_alive(k) for k in kids)
    data = out.read_bytes()
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    n = summary.statistics.message_count
    assert n > 100
    assert sum(1 for _ in NonSeekingReader(io.BytesIO(data), validate_crcs=True)
               .iter_messages()) == n
    bag = read_bag(out)
    assert not bag.truncated and bag.message_count == n
    assert bag.rosbag2_metadata()["message_count"] == n


@pytest.mark.heavy
def test_a_killed_recorder_leaves_a_repaired_bag(tmp_path):
    """The recorder node SIGKILLed mid-run: `flexarm run` says so (exit 1, the recorder's
    status named) and rewrites the bag complete with `flexarm bag repair`, keeping the
    unfinished file beside it; the repaired bag holds exactly what the unfinished one
    still has, readable by mcap's indexed reader."""
    out = tmp_path / "run.mcap"
    proc, stdout, stderr = _signal_node(out, "recorder", signal.SIGKILL)
    assert proc.returncode == 1 and "ended early: recorder killed by SIGKILL" in stderr, stderr
    killed = tmp_path / "run.killed.mcap"
    assert "the recorder was killed by SIGKILL: " in stdout and f"kept as {killed}" in stdout
    with pytest.warns(TruncatedBagWarning):
        unfinished = read_bag(killed)
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    n = summary.statistics.message_count
    assert n == unfinished.message_count > 0
    assert f"{n} messages recovered into {out}" in stdout
    repaired = read_bag(out)
    assert not repaired.truncated and repaired.message_count == n
    assert {t: [ts for ts, _ in v] for t, v in repaired.messages.items()} == \
        {t: [ts for ts, _ in v] for t, v in unfinished.messages.items()}


@pytest.mark.heavy
@pytest.mark.parametrize("node, sig", [
    ("simulator", "SIGTERM"), ("motor_driver", "SIGTERM"), ("controller", "SIGTERM"),
    ("simulator", "SIGKILL"),
    # the same path as the simulator's SIGKILL (the run reads any node's -9): in -m slow
    pytest.param("motor_driver", "SIGKILL", marks=pytest.mark.slow),
    pytest.param("controller", "SIGKILL", marks=pytest.mark.slow)])
def test_a_node_stopped_from_outside_ends_the_run_non_zero_naming_it(tmp_path, node, sig):
    """SIGTERM or SIGKILL to one node of a `--processes` run, from outside the run (issue
    39: the simulator so stopped had ended the run early with exit 0, saying nothing): the
    run ends with status 1 and one line naming the node and the signal (SIGTERM: the node
    says so itself, the simulator how far it got); the bag is finalized."""
    out = tmp_path / "run.mcap"
    proc, stdout, stderr = _signal_node(out, node, getattr(signal, sig))
    assert proc.returncode == 1, stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith("flexarm run:")]
    assert len(lines) == 1, stderr
    how = "stopped by SIGTERM from outside the run" if sig == "SIGTERM" else \
        "killed by SIGKILL"
    assert f"ended early: {node} {how}" in lines[0], lines[0]
    if node == "simulator" and sig == "SIGTERM":
        assert " at t = " in lines[0] and " of 100 s" in lines[0], lines[0]
    assert f"{out} holds what was recorded until then" in lines[0]
    assert "Traceback" not in stderr
    bag = read_bag(out)
    assert not bag.truncated and bag.message_count > 100


@pytest.mark.heavy
def test_a_recorder_stopped_from_outside_finalizes_its_bag(tmp_path):
    """SIGTERM to the recorder of a `--processes` run: the run ends with status 1 naming
    it, and the bag is finalized (readable by the indexed reader, not truncated) with
    everything recorded until then."""
    out = tmp_path / "run.mcap"
    proc, stdout, stderr = _signal_node(out, "recorder", signal.SIGTERM)
    assert proc.returncode == 1, stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith("flexarm run:")]
    assert len(lines) == 1 and "ended early: recorder stopped by SIGTERM" in lines[0], stderr
    assert "Traceback" not in stderr
    bag = read_bag(out)
    assert not bag.truncated and bag.message_count > 100
    with open(out, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == bag.message_count


_PDEATHSIG = """
import ctypes, sys
sig = ctypes.c_int(-1)
ctypes.CDLL(None).prctl(2, ctypes.byref(sig), 0, 0, 0)     # PR_GET_PDEATHSIG
print(sig.value)
"""


def test_die_with_parent_arms_sigterm_and_refuses_an_orphan(monkeypatch):
    """The child's own view (PR_GET_PDEATHSIG) is SIGTERM; and the race the pid check
    closes: a child whose parent died before the signal was armed exits at once
    (simulated by arming it for a pid that is not the child's parent)."""
    r = subprocess.run([sys.executable, "-c", _PDEATHSIG], preexec_fn=die_with_parent(),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == str(int(signal.SIGTERM))
    r = subprocess.run([sys.executable, "-c", _PDEATHSIG], capture_output=True, text=True,
                       timeout=60)
    assert r.stdout.strip() == "0"                       # not armed without it
    with monkeypatch.context() as mp:
        mp.setattr(os, "getpid", lambda: 1)              # "the parent" when arming
        orphan = die_with_parent()
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", "import time; time.sleep(30)"],
                       preexec_fn=orphan, timeout=60)
    assert r.returncode == 1 and time.monotonic() - t0 < 20


_HUNG = """
import time, types
from flexarm_ros.nodes.common import ShutdownGuard
ShutdownGuard("motor_driver", types.SimpleNamespace(diverged={diverged!r}), limit_s=0.3)
time.sleep(30)          # a teardown that hangs
"""


@pytest.mark.parametrize("diverged, code", [(None, 0), ("tip deflection", 3)])
def test_a_node_whose_teardown_hangs_ends_with_the_status_it_earned(diverged, code):
    """Once a node's work is done, a hang in what follows (DDS teardown) ends the process
    after the guard's limit — saying so, with every thread's stack — with 0, or 3 after a
    divergence; not after the parent's SIGKILL 15 s later."""
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", _HUNG.format(diverged=diverged)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == code, r.stderr
    assert time.monotonic() - t0 < 20
    assert "motor_driver: its work is done but the process has not exited 0.3 s later" \
        in r.stderr
    assert "time.sleep(30)" in r.stderr or "line 5" in r.stderr, r.stderr


@pytest.mark.heavy
def test_ctrl_c_to_a_split_run_exits_130_with_a_finalized_bag(tmp_path):
    """--layout split (the simulator in its own process, the bag written by another): a
    terminal's Ctrl-C reaches all three; the run ends with exit 0, a finalized bag, and
    no process left."""
    out = tmp_path / "split.mcap"
    exe = Path(sys.executable).with_name("flexarm")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]
    proc = subprocess.Popen(cmd + ["run", "two_link_case1", "--mode", "realtime", "--layout",
                                   "split", "--duration", "100", "--record", str(out),
                                   "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        t0 = time.monotonic()

        def sim_running():
            return any("flexarm_ros.nodes.simulator " in _cmdline(k)
                       for k in _children(proc.pid))
        while not sim_running():         # the bag's metadata is written before it starts
            assert proc.poll() is None and time.monotonic() - t0 < 240, proc.communicate()
            time.sleep(0.1)
        size = out.stat().st_size if out.exists() else 0
        while not (out.exists() and out.stat().st_size > size + 20_000):
            assert proc.poll() is None and time.monotonic() - t0 < 240, proc.communicate()
            time.sleep(0.1)
        kids = _children(proc.pid)
        assert any("flexarm_ros.nodes.simulator " in _cmdline(k) for k in kids), \
            [_cmdline(k) for k in kids]
        assert any("flexarm_ros.bag.writer_process" in _cmdline(k) for k in kids)
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        _cleanup(proc)
    assert proc.returncode == 130, stderr
    assert "interrupted by SIGINT" in stdout and "Traceback" not in stderr
    t0 = time.monotonic()
    while any(_alive(k) for k in kids) and time.monotonic() - t0 < 5:
        time.sleep(0.05)
    assert not any(_alive(k) for k in kids)
    bag = read_bag(out)
    assert not bag.truncated and bag.message_count > 100
    assert bag.rosbag2_metadata()["message_count"] == bag.message_count
