"""Log time = simulation time: the recorder's stamping of what it received, and the writing.

A message is logged at the value of the latest ``/clock`` the simulator had published when
the message was published (both moments are DDS source timestamps of one host's clock).
A message is held until a later ``/clock`` arrives, so delivery order does not matter. A
message with a header keeps its stamp when that lies between 0 and that time (an answer
to an earlier state: the driver's ``motor_states``), else it gets that time
(:class:`~flexarm_ros.nodes.recorder.RecorderNode` says why).

No rclpy here: the recorder node decides what is taken (source rule, validation) and hands
it to a :class:`SimTimeStamper` — in its own process, or in a writer process of its own
(:mod:`flexarm_ros.bag.writer_process`) that runs this same class on another core.
"""

from __future__ import annotations

import bisect
import time

HISTORY = 20_000           # /clock values kept for stamping late messages (20 s at 1 kHz)


class SimTimeStamper:
    """Stamps messages by the simulator's clock and writes them into ``writer`` (a
    :class:`~flexarm_ros.bag.BagWriter`) under ``names[topic]`` (absolute names);
    chunks are flushed every ``flush_period`` s of wall time."""

    def __init__(self, writer, names: dict, flush_period: float = 1.0):
        self.writer = writer
        self.names = names
        self.flush_period = float(flush_period)
        self.clock_ts: list = []          # source timestamps of the simulator's /clock
        self.clock_ns: list = []          # their values
        self.pending: list = []           # (source ts, topic, type, data, header ns)
        self._flushed = time.monotonic()

    def _write(self, topic, tp, data, t_ns):
        """``data``: CDR bytes (the fast path) or a message dict."""
        if isinstance(data, bytes):
            self.writer.write_raw(self.names[topic], tp, data, t_ns)
        else:
            self.writer.write(self.names[topic], tp, data, t_ns)
        now = time.monotonic()
        if now - self._flushed > self.flush_period:
            self.writer.flush()
            self._flushed = now

    def sim_ns(self, ts: int) -> int:
        """The simulator's latest /clock value published at or before source time ts."""
        i = bisect.bisect_right(self.clock_ts, ts)
        return self.clock_ns[i - 1] if i else (self.clock_ns[0] if self.clock_ns else 0)

    def emit(self, ts, topic, tp, data, header_ns=None):
        """Write now when the simulator's time at ``ts`` is known (a later /clock has
        arrived), else hold the message until it is."""
        if not ts or (self.clock_ts and ts < self.clock_ts[-1]):
            self._stamp_write(ts, topic, tp, data, header_ns)
        else:
            self.pending.append((ts, topic, tp, data, header_ns))

    def _stamp_write(self, ts, topic, tp, data, header_ns):
        t_ns = self.sim_ns(ts) if ts else (self.clock_ns[-1] if self.clock_ns else 0)
        if header_ns is not None and 0 <= header_ns <= t_ns:
            t_ns = header_ns
        self._write(topic, tp, data, t_ns)

    def release(self, upto=None):
        """Write the held messages sent before source time ``upto`` (all: None)."""
        keep = []
        for item in self.pending:
            if upto is None or (item[0] and item[0] < upto):
                self._stamp_write(*item)
            else:
                keep.append(item)
        self.pending = keep

    def clock(self, ts, topic, tp, data, t_ns):
        """A /clock message (``t_ns`` its value, never below the previous one: the
        recorder refuses a clock that goes backwards before it gets here): logged at its
        own time, and what was held until it is written."""
        if not ts and self.clock_ts:
            ts = self.clock_ts[-1] + 1
        self.clock_ts.append(ts)
        self.clock_ns.append(t_ns)
        if len(self.clock_ts) > 2 * HISTORY:
            del self.clock_ts[:HISTORY], self.clock_ns[:HISTORY]
        self._write(topic, tp, data, t_ns)
        self.release(ts)

    def close(self, metadata: dict | None = None):
        """Write what is held, the metadata records ``{name: {key: text}}``, and finalize
        the file (idempotent)."""
        if not self.writer.closed:
            self.release()
            for name, data in (metadata or {}).items():
                self.writer.add_metadata(name, data)
        self.writer.close()

    @property
    def closed(self) -> bool:
        return self.writer.closed
