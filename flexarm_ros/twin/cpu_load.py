"""What a run's processes cost per tick: CPU time of every process of the graph over the
ticking alone, and the share of the machine's CPUs it takes.

Why: a realtime tick starts late when the CPUs it needs are busy, and a graph that needs
most of them per tick turns every stall of the host into a run of late ticks (after a
stall of S seconds the backlog drains at (1 − c/T) per tick, c the CPU per tick of the
busiest CPU and T the period, so ~S/(T − c) ticks start late). Measured on the 2-core
host (docs/decisions/0010-the-hosts-floor-and-the-cpu-per-tick.md): ``--processes`` needed ~1.9
ms of CPU per
1 ms tick (simulator 0.88, motor_driver 0.40, controller 0.33, recorder 0.33), all but
the whole machine. The run summary reports it so that a user sees it on their machine.

How: :class:`CpuSampler` reads ``utime + stime`` of ``/proc/<pid>/stat`` (Linux; clock
ticks, usually 10 ms) of the process that runs the graph and of its descendants at a
fixed period in a thread of its own, and :meth:`CpuSampler.between` interpolates each
process's CPU time linearly at the ticking's start and end (the simulator's monotonic
times; ``time.monotonic`` is the system-wide ``CLOCK_MONOTONIC``). Before the first tick
the other nodes only wait for it, so the interpolation's error there is the sampling
period's share of an idle process; the simulator's own process is taken exactly from
``time.process_time`` at both ends where it reports it. No rclpy here."""

from __future__ import annotations

import os
import threading
import time
from bisect import bisect_left
from pathlib import Path

#: the sampling period (s): 20 readings of the process tree per second, ~0.1 % of a CPU
SAMPLE_S = 0.05


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU time (s) of process ``pid`` (all its threads) from
    ``/proc/<pid>/stat``; None where it has ended or there is no ``/proc``."""
    st = _stat(pid)
    return None if st is None else (int(st[11]) + int(st[12])) / os.sysconf("SC_CLK_TCK")


def process_start_s(pid: int) -> float | None:
    """When process ``pid`` started, on the clock of ``time.monotonic`` (both count from
    the boot on Linux: ``/proc/<pid>/stat``'s start time in clock ticks); None if gone."""
    st = _stat(pid)
    return None if st is None else int(st[19]) / os.sysconf("SC_CLK_TCK")


def _stat(pid: int) -> list | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (which may hold spaces):
    state is [0], utime [11], stime [12], starttime [19]."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def children(pid: int) -> list[int]:
    """The child processes of ``pid`` (of every one of its threads)."""
    out = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tasks:
        try:
            out += [int(c) for c in Path(f"/proc/{pid}/task/{tid}/children").read_text()
                    .split()]
        except OSError:
            pass
    return out


def descendants(pid: int) -> list[int]:
    """``pid``'s children, theirs, and so on."""
    out, todo = [], children(pid)
    while todo:
        c = todo.pop()
        out.append(c)
        todo += children(c)
    return out


def role(pid: int) -> str | None:
    """What a graph's process runs, from its command line: the node of
    ``python -m flexarm_ros.nodes.<node>``, ``bag_writer`` for the bag's writer process,
    else the program's name; None when the command line cannot be read or is empty (an
    exited process not yet reaped)."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    args = [a.decode(errors="replace") for a in argv if a]
    if not args:
        return None
    for a in args:
        if a.startswith("flexarm_ros.nodes."):
            return a.rsplit(".", 1)[1]
        if a == "flexarm_ros.bag.writer_process":
            return "bag_writer"
    return Path(args[0]).name


class CpuSampler:
    """CPU time of ``root`` (default: this process) and its descendants, sampled every
    ``period`` s from :meth:`start` to :meth:`stop`; ``root_role`` names the root's
    process (e.g. the nodes it runs in-process)."""

    def __init__(self, root: int | None = None, root_role: str = "run",
                 period: float = SAMPLE_S):
        self.root = os.getpid() if root is None else root
        self.roles = {self.root: root_role}
        self.period = period
        self.samples: dict[int, list[tuple[float, float]]] = {}
        self._pids = [self.root]
        self._stop = threading.Event()
        self._thread = None

    def start(self) -> "CpuSampler":
        if Path(f"/proc/{self.root}/stat").exists():
            self._thread = threading.Thread(target=self._loop, name="cpu-sampler",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            self.sample()                       # the last one, after the ticking's end

    def _loop(self):
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.period)

    def sample(self) -> None:
        """One reading of the process tree, each process stamped with ``time.monotonic()``.
        A process seen for the first time gets a reading of 0 s at its start (so a child
        born between two readings is counted from its birth, not from the next reading);
        its role is read again while it runs (a child is its parent's copy until exec)."""
        self._pids = [self.root] + descendants(self.root)
        for pid in self._pids:
            t, cpu = time.monotonic(), process_cpu_s(pid)
            if cpu is None:
                continue
            s = self.samples.get(pid)
            if s is None:
                born = process_start_s(pid)
                s = self.samples[pid] = ([(born, 0.0)] if born is not None and born < t
                                         and pid != self.root else [])
            if pid != self.root:
                name = role(pid)                # None for a zombie: keep what it ran
                if name is not None:
                    self.roles[pid] = name
            s.append((t, cpu))

    def between(self, t0: float, t1: float) -> dict[str, float]:
        """CPU seconds of each process from monotonic time ``t0`` to ``t1`` (linear
        between samples; a process without samples on both sides of an end is taken
        from its nearest sample), by role; roles of several processes add."""
        out: dict[str, float] = {}
        for pid, s in self.samples.items():
            if len(s) < 1:
                continue
            used = _at(s, t1) - _at(s, t0)
            name = self.roles.get(pid, str(pid))
            out[name] = out.get(name, 0.0) + max(used, 0.0)
        return out


def _at(s: list[tuple[float, float]], t: float) -> float:
    """A process's CPU time at monotonic ``t`` from its samples (time, cpu) in time
    order: linear between the two around t, the nearest one outside them."""
    times = [a for a, _ in s]
    i = bisect_left(times, t)
    if i == 0:
        return s[0][1]
    if i == len(s):
        return s[-1][1]
    (ta, ca), (tb, cb) = s[i - 1], s[i]
    return ca + (cb - ca) * (t - ta) / (tb - ta) if tb > ta else cb


def cpu_budget(cpu_s: dict[str, float], ticks: int, wall_s: float,
               cpus: int | None = None) -> dict:
    """The per-tick figures of a run: ``cpu_ms_per_tick`` by process (CPU ms over
    ``ticks``), their ``total``, and ``cpu_share``: the share of ``cpus`` CPUs'
    time (default: those this process may run on) the graph took over ``wall_s`` of
    ticking."""
    cpus = cpus or len(os.sched_getaffinity(0))
    per = {k: 1e3 * v / ticks for k, v in cpu_s.items()} if ticks else {}
    total = sum(cpu_s.values())
    return {"cpu_ms_per_tick": per,
            "cpu_ms_per_tick_total": 1e3 * total / ticks if ticks else None,
            "cpu_share": total / (wall_s * cpus) if wall_s > 0 else None,
            "cpus_available": cpus}
