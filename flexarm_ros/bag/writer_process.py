"""The recorder's stamping and writing in a process of its own.

Why (cProfile of the one-process realtime graph on two_link_case1, session 10): the
recorder took about a fifth of every tick on the one core a Python process runs on, while
the second core sat nearly idle; a DDS hop into another process costs the publisher
25–90 µs per message (docs/decisions/0008-an-intra-process-bus.md). Here the recorder
node stays in the graph's process — it still decides what is taken (source rule,
validation, rejections) — and hands what it takes to a child process through a pipe,
written at a ``/clock`` at most every :data:`SEND_PERIOD_S`; the child runs
:class:`~flexarm_ros.bag.stamping.SimTimeStamper` and the bag writer on the other core.
The bag is the same, record for record, as when both run in one process
(``test/test_writer_process.py``).

The child ignores SIGINT and SIGTERM (a terminal's Ctrl-C reaches the whole process group;
the bag must still be finalized): it ends when told to close, or when its input ends — its
parent died, even by SIGKILL — finalizing the file with what it received.

    python -m flexarm_ros.bag.writer_process      # the child; started by WriterProcess
"""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import sys
import time

from flexarm_ros.bag.stamping import SimTimeStamper
from flexarm_ros.child_process import python_module

_HEAD = struct.Struct("<BIqqI")     # kind, topic index, source ts, extra (ns), payload bytes
_INIT, _TOPIC, _MSG, _CLOCK, _CLOSE = range(5)
_NONE = -2**63                      # no header stamp
_BATCH = 1 << 18                    # bytes held before a write between two clocks
SEND_PERIOD_S = 0.02
"""Wall time between two writes to the child, at a /clock: one pipe write per tick cost
the tick ~30 µs (a system call that wakes the child's core; cProfile of the one-process
realtime graph, session 11). Every 5 ms (session 11 to 16) the writes still took 4 % of
the pacing thread (py-spy, session 17); every 20 ms the one-process realtime tick's CPU
fell 0.834 → 0.787 ms (four alternating 10 s runs each), 50 ms gave nothing more. What
is held is written at close, and a parent killed outright loses at most this much."""


class WriterProcessError(OSError):
    """The writer process could not start, or failed (its own message included)."""


class WriterProcess:
    """:class:`SimTimeStamper`'s interface (``emit``, ``clock``, ``close``, ``closed``)
    for a bag written by a child process: ``path``, the metadata ``info`` and
    ``qos_depth`` as :class:`~flexarm_ros.bag.BagWriter` takes them, ``extra`` metadata
    records written at once, ``names`` topic → absolute name. Raises
    :class:`WriterProcessError` when the child cannot open the bag (its message)."""

    def __init__(self, path, info: dict, qos_depth: int, extra: dict, names: dict,
                 flush_period: float = 1.0):
        import tempfile
        self.names = names
        self._err = tempfile.TemporaryFile()     # never a pipe nobody reads while it runs
        self.proc = subprocess.Popen(python_module("flexarm_ros.bag.writer_process"),
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._err)
        try:                        # room for ~1 s of ticks: the child's hiccups never block
            import fcntl
            fcntl.fcntl(self.proc.stdin.fileno(), 1031, 1 << 20)    # F_SETPIPE_SZ
        except (ImportError, OSError):
            pass
        self._buf = bytearray()
        self._topics: dict = {}
        self._sent = 0.0                         # monotonic time of the last write
        self.closed = False
        self._frame(_INIT, 0, 0, 0, json.dumps(
            {"path": str(path), "info": info, "qos_depth": qos_depth, "extra": extra,
             "flush_period": flush_period}).encode())
        self._send()
        reply = self.proc.stdout.readline().decode(errors="replace").strip()
        if reply != "ok":
            self._reap()
            err = self._stderr()
            self._close_files()
            raise WriterProcessError(reply or f"the bag writer process exited with status "
                                              f"{self.proc.returncode}: {err}")

    def _frame(self, kind, idx, ts, extra, payload: bytes) -> None:
        self._buf += _HEAD.pack(kind, idx, ts, extra, len(payload))
        self._buf += payload

    def _index(self, topic, tp) -> int:
        key = (topic, tp)
        i = self._topics.get(key)
        if i is None:
            i = self._topics[key] = len(self._topics)
            self._frame(_TOPIC, i, 0, 0, json.dumps([self.names[topic], tp]).encode())
        return i

    def _send(self) -> None:
        if not self._buf:
            return
        try:
            self.proc.stdin.write(self._buf)
            self.proc.stdin.flush()
        except (BrokenPipeError, ValueError, OSError):
            self._reap()
            err = self._stderr()
            self._close_files()
            raise WriterProcessError(f"the bag writer process stopped (status "
                                     f"{self.proc.returncode}): {err}") from None
        self._buf = bytearray()

    def emit(self, ts, topic, tp, data, header_ns=None) -> None:
        if not isinstance(data, bytes):
            from flexarm_ros.bag.writer import encode_cdr
            data = encode_cdr(tp, data)
        self._frame(_MSG, self._index(topic, tp), int(ts or 0),
                    _NONE if header_ns is None else int(header_ns), data)
        if len(self._buf) > _BATCH:
            self._send()

    def clock(self, ts, topic, tp, data, t_ns) -> None:
        self._frame(_CLOCK, self._index(topic, tp), int(ts or 0), int(t_ns), data)
        now = time.monotonic()
        if now - self._sent >= SEND_PERIOD_S:     # at most one write per SEND_PERIOD_S
            self._sent = now
            self._send()

    def close(self, metadata: dict | None = None, timeout: float = 120.0) -> None:
        """Send what is held and the metadata records; wait for the child to finalize
        the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self._frame(_CLOSE, 0, 0, 0, json.dumps(metadata or {}).encode())
        self._send()
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        err = self._stderr()
        self._close_files()
        if self.proc.returncode != 0:
            raise WriterProcessError(f"the bag writer process exited with status "
                                     f"{self.proc.returncode}: {err}")

    def _stderr(self) -> str:
        try:
            self._err.seek(0)
            return self._err.read().decode(errors="replace").strip()[-2000:]
        except (OSError, ValueError):
            return ""

    def _close_files(self) -> None:
        for f in (self._err, self.proc.stdout):
            try:
                f.close()
            except (OSError, ValueError):
                pass

    def _reap(self) -> None:
        self.closed = True
        try:
            self.proc.stdin.close()
        except (OSError, ValueError):
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class _Same(dict):
    """Topic names that are already absolute."""

    def __missing__(self, key):
        return key


def _read(stream, n: int) -> bytes | None:
    data = stream.read(n)
    return data if len(data) == n else None


def main() -> int:
    """The child: frames from stdin into a SimTimeStamper (module doc)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    inp = sys.stdin.buffer
    head = _read(inp, _HEAD.size)
    if head is None or head[0] != _INIT:
        print("error: the bag writer process got no start record", flush=True)
        return 2
    init = json.loads(_read(inp, _HEAD.unpack(head)[4]) or b"{}")
    from flexarm_ros.bag.writer import BagWriter
    try:
        writer = BagWriter(init["path"], metadata=init["info"], qos_depth=init["qos_depth"])
        for name, data in init["extra"].items():
            writer.add_metadata(name, data)
    except (OSError, ValueError) as exc:
        print(f"error: cannot write the bag {init['path']!r}: {exc}", flush=True)
        return 2
    print("ok", flush=True)
    stamper = SimTimeStamper(writer, _Same(), init["flush_period"])
    topics: list = []
    while True:
        head = _read(inp, _HEAD.size)
        if head is None:                      # the parent is gone: keep what came
            stamper.close()
            return 0
        kind, idx, ts, extra, n = _HEAD.unpack(head)
        payload = _read(inp, n) if n else b""
        if payload is None:
            stamper.close()
            return 0
        if kind == _MSG:
            topic, tp = topics[idx]
            stamper.emit(ts, topic, tp, payload, None if extra == _NONE else extra)
        elif kind == _CLOCK:
            topic, tp = topics[idx]
            stamper.clock(ts, topic, tp, payload, extra)
        elif kind == _TOPIC:
            topics.append(tuple(json.loads(payload)))
        elif kind == _CLOSE:
            stamper.close(json.loads(payload))
            return 0


if __name__ == "__main__":
    sys.exit(main())
