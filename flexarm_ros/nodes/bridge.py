"""The intra-process bus across two processes: the simulator alone in one, the other nodes
in the other, joined by a Unix socket.

Why (measured, docs/decisions/0009-the-bag-writer-process-and-the-split-layout.md): in one
process every node shares one core (Python's GIL) and a 1 kHz tick of seed 000 costs about
a millisecond there — the real-time factor stays near 0.9 and most ticks start late, while
the second core idles; one process per node (``--processes``) pays a DDS hop per message
(25–90 µs for the publisher alone). Here the simulator's process runs the plant, its wire
bytes and its pacing on one core, the driver, controller and recorder run on the other,
and what one side's member nodes publish reaches the other side's subscribers as bytes on
the socket — written once per tick, not once per message.

The rules are the bus's (:mod:`~flexarm_ros.nodes.intraprocess`): a topic whose source is
a member (of either process) goes by the bus; each side tells the other which
subscriptions and publishers it has (``SUB``/``PUB`` records: topic, node, namespace, the
publisher's DDS GID), so a publisher counts the remote subscribers (the simulator's start
condition), the source rule finds the remote publisher by its GID on the DDS graph (the
publishers still exist on DDS), and a DDS reader opens only for a foreign publisher. A
message keeps its source timestamp (the host's real-time clock, as DDS's) and its
publisher's GID.

Framing: ``<B kind><H index><q source ts><I length>`` then the payload; ``PUB`` and ``SUB``
payloads are JSON. A ``PUB`` record names its node and namespace with its GID, so the
source rule (:mod:`~flexarm_ros.nodes._wire`) knows the other process's publishers at
once: DDS discovery between two processes took up to several seconds here, and a rule
that waited for it (0.5 s per unknown GID and topic) stalled the receiving side for
~6 s in about half of the split realtime runs — the driver answered no state until the
run was over (found in session 11 from a stack dump during the stall). A reader thread
per process takes the records and posts the messages on its bus (waking its executor);
the socket's end (the other process ended) stops it.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import threading

from flexarm_ros.nodes.intraprocess import install

_HEAD = struct.Struct("<BHqI")
_PUB, _SUB, _MSG = range(3)
ENV = "FLEXARM_BRIDGE"
"""The child's end: ``{"fd": n, "members": [[namespace, node], ...]}`` as JSON."""


class Bridge:
    """One process's end of the socket, attached to its :class:`Bus`."""

    def __init__(self, bus, sock: socket.socket):
        self.bus, self.sock = bus, sock
        self.closed = False
        self._buf = bytearray()
        self._lock = threading.Lock()           # publishers on several threads
        self._send_lock = threading.Lock()
        self._pub_index: dict = {}              # BusPublisher -> index on the wire
        self.remote_subs: dict = {}             # topic -> [(node, namespace)]
        self.remote_pubs: dict = {}             # index -> (topic, gid)
        self.remote_gids: dict = {}             # topic -> {gid}
        self.remote_names: dict = {}            # gid -> (node name, namespace)
        for topic, subs in list(bus.subs.items()):
            for s in subs:
                self.announce_sub(s)
        for topic, pubs in list(bus.pubs.items()):
            for p in pubs:
                self.announce_pub(p)
        self.flush()
        self._thread = threading.Thread(target=self._read, name="bus-bridge", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- sending
    def _frame(self, kind, idx, ts, payload: bytes) -> None:
        with self._lock:
            self._buf += _HEAD.pack(kind, idx, ts, len(payload))
            self._buf += payload

    def announce_sub(self, sub) -> None:
        self._frame(_SUB, 0, 0, json.dumps([sub.topic, sub.node.get_name(),
                                            sub.node.get_namespace()]).encode())

    def announce_pub(self, pub) -> None:
        with self._lock:
            idx = self._pub_index.setdefault(pub, len(self._pub_index))
        gid = pub.gid
        self._frame(_PUB, idx, 0, json.dumps([pub.topic, gid.hex() if gid else "",
                                              pub.node.get_name(),
                                              pub.node.get_namespace()]).encode())

    def wants(self, topic: str) -> bool:
        return topic in self.remote_subs

    def send(self, pub, data: bytes, ts: int) -> None:
        idx = self._pub_index.get(pub)
        if idx is None:
            self.announce_pub(pub)
            idx = self._pub_index[pub]
        self._frame(_MSG, idx, ts, data)
        if len(self._buf) > 1 << 16:
            self.flush()

    def flush(self) -> None:
        """Write what is buffered (once per tick: the bus flushes after each round of
        deliveries and the simulator after each published state)."""
        # one flush at a time, taking the buffer and writing it: two threads publish (the
        # realtime pacing thread and the executor's), and a buffer taken first must be on
        # the wire first (measured without this lock: 3 of 6000 /clock messages arrived
        # out of order, which the recorder refused as time going backwards)
        with self._send_lock:
            with self._lock:
                if not self._buf or self.closed:
                    self._buf = bytearray()
                    return
                data, self._buf = bytes(self._buf), bytearray()
            try:
                self.sock.sendall(data)
            except OSError:                     # the other process is gone
                self.closed = True

    def close(self) -> None:
        """Send what is buffered and close this end (the other side's reader ends)."""
        self.flush()
        self.closed = True
        try:
            self.sock.close()
        except OSError:
            pass

    # -------------------------------------------------------------- receiving
    def _read(self) -> None:
        """Take what the socket holds, post every complete record on the bus, wake the
        executor once per chunk (not once per message: a tick's dozen messages arrive
        in one write)."""
        sock, bus = self.sock, self.bus
        buf = bytearray()
        size = _HEAD.size
        try:
            while True:
                chunk = sock.recv(1 << 16)
                if not chunk:
                    break
                buf += chunk
                pos, end, posted = 0, len(buf), False
                while end - pos >= size:
                    kind, idx, ts, n = _HEAD.unpack_from(buf, pos)
                    if end - pos - size < n:
                        break
                    payload = bytes(buf[pos + size:pos + size + n])
                    pos += size + n
                    if kind == _MSG:
                        topic, gid = self.remote_pubs[idx]
                        bus.post(topic, payload, {"source_timestamp": ts,
                                                  "publisher_gid": {"data": gid}})
                        posted = True
                    elif kind == _PUB:
                        topic, gid, name, ns = json.loads(payload)
                        gid = bytes.fromhex(gid) if gid else None
                        self.remote_pubs[idx] = (topic, gid)
                        if gid:
                            self.remote_names[gid] = (name, ns)
                            self.remote_gids.setdefault(topic, set()).add(gid)
                    elif kind == _SUB:
                        topic, name, ns = json.loads(payload)
                        self.remote_subs.setdefault(topic, []).append((name, ns))
                del buf[:pos]
                if posted:
                    # always: a post while the executor delivers does not wake it
                    bus.wake()
        except (OSError, ValueError):
            pass
        finally:
            self.closed = True
            try:
                bus.wake()
            except Exception:                   # the context is already shut down
                pass

    def remote_publishers(self, topic: str) -> int:
        return sum(1 for t, _ in list(self.remote_pubs.values()) if t == topic)

    def remote_publisher_names(self, topic: str) -> dict:
        """GID -> (node name, namespace) of the other process's publishers of ``topic``,
        as they announced themselves (known before DDS discovery shows them)."""
        return {g: self.remote_names[g] for g in list(self.remote_gids.get(topic, ()))
                if g in self.remote_names}


def socket_pair():
    """(this process's socket, the child's socket) — the child's inheritable."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    b.set_inheritable(True)
    return a, b


def child_environment(sock: socket.socket, members) -> dict:
    """The environment variable that hands the child its end and the bus's members."""
    return {ENV: json.dumps({"fd": sock.fileno(), "members": [list(m) for m in members]})}


def attach(bus, sock) -> None:
    """Join ``bus`` (:class:`~flexarm_ros.nodes.intraprocess.Bus`) to another process's
    over ``sock``."""
    bus.bridge = Bridge(bus, sock)


def attach_from_environment(context):
    """In a node process started with :data:`ENV`: install the bus with every member of
    both processes and attach its end of the socket; None when not started so."""
    spec = os.environ.get(ENV)
    if not spec:
        return None
    spec = json.loads(spec)
    bus = install(context, [tuple(m) for m in spec["members"]])
    sock = socket.socket(fileno=int(spec["fd"]))
    attach(bus, sock)
    return bus
