"""The logger: every topic of the twin into a rosbag2-compatible MCAP file.

Subscribes (node-relative, reliable keep_last 1000): every topic of the contract
(:mod:`flexarm_ros.twin.topics`) — ``/clock``, ``joint_states``, ``encoders/counts``,
the sensor batches, ``tool/contact``, ``tool/wrench``, ``ground_truth/*``,
``motor_driver/commands``, ``effort_controller/commands``, ``motor_driver/motor_states``,
``arm_markers`` (the viewers' MarkerArray, recorded with its ros2msg schema so Foxglove
draws the arm from the bag).
Publishes nothing. Writes ``output`` with :class:`~flexarm_ros.bag.BagWriter` — in this
process, or with ``writer_process`` (set by ``flexarm run`` in one process) in a child
process on the other core (:mod:`flexarm_ros.bag.writer_process`; the stamping below runs
there, :mod:`flexarm_ros.bag.stamping`): topics
under their absolute names, metadata ``flexarm_ros`` (scene YAML text, scene name,
software version, time mode, namespace, the fidelity overrides as JSON, ``set``: the scene
values set by ``flexarm run --set`` as a JSON object, ``{}`` for none) and ``model`` (the
built model, ``flexarm explain``). With fidelity overrides (``-p rung:=rigid``, ``flexarm
run --rung rigid``) the embedded scene YAML is the scene file with its ``fidelity`` section
updated; with ``set`` values it is the whole scene that ran, written out (every key, the
sets and the overrides in it); either way whoever rebuilds the model from the bag builds
the one that ran.

Log time = the simulation time at which the message was sent, never a count of messages:
the value of the latest ``/clock`` the simulator had published when the message was
published (both moments are the DDS source timestamps of one host's clock; a message is
held until a later ``/clock`` arrives, so delivery order does not matter). A message with a
header keeps its stamp when that lies between 0 and that time (an answer to an earlier
state: the driver's ``motor_states``; a MarkerArray, by its first marker's stamp, which
the simulator's marker thread builds after the tick it shows), else it gets that time. So in ``lockstep`` every
message of tick k — commands and efforts included — is logged at t_k exactly as
``cosimulate`` gives it, and no burst of foreign messages can log anything past the last
``/clock``, the run's end.

What the twin's nodes refused never reaches a topic of the bag as if it had been taken: a
message from a second publisher of a topic (:mod:`~flexarm_ros.nodes._wire`, the same rule
the nodes apply), a command or effort the nodes' validator rejects
(:mod:`~flexarm_ros.twin.validation`, the same check), or any message holding a
non-finite number goes to ``diagnostics/rejected`` instead (std_msgs/String, one JSON
object: ``topic``, ``reason``, ``publisher``, ``data`` as text), and the counts by topic and
reason go into the metadata record ``rejected_messages`` when the file is closed.

Subscriptions are raw: a message from the twin's own node expected on its topic (the
source rule, :mod:`~flexarm_ros.nodes._wire`) is written into the MCAP as the bytes
received — the twin's nodes publish :func:`~flexarm_ros.bag.writer.encode_cdr` output,
padding zeroed, so a lockstep bag stays reproducible byte for byte — and only the command
topics are decoded (to validate them) and the stamps read from the bytes. A message from
any other publisher is decoded, checked, and re-encoded with our encoder (rmw leaves
alignment padding uninitialized). Chunks are
flushed every ``flush_period`` s of wall time, so a SIGKILL loses at most that much; on
SIGINT/SIGTERM the node keeps reading until the graph has been quiet for 0.3 s, then
finalizes the file.
"""

from __future__ import annotations

import json
import math
import struct
import sys
import time
from pathlib import Path

import yaml

from rclpy.node import Node

from flexarm_ros import __version__
from flexarm_ros.bag import BagWriter
from flexarm_ros.bag import messages as M
from flexarm_ros.bag.stamping import SimTimeStamper
from flexarm_ros.bag.writer_process import WriterProcess
from flexarm_ros.bag.cdr_read import CdrError, decode as decode_values
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.scene import resolve_scene_path
from flexarm_ros.scene.overrides import decode_sets
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.recording import missing_messages
from flexarm_ros.twin.validation import NON_FINITE, NOT_CDR, Validator
import flexarm_ros.nodes.common as C
from flexarm_ros.nodes._msgconv import msg_class, to_dict
from flexarm_ros.nodes.parameters import fidelity_overrides
from flexarm_ros.nodes.diagnostics import attach as attach_diagnostics
from flexarm_ros.nodes._wire import Rejections, Source, show
from flexarm_ros.nodes.intraprocess import gid_of


def finite(obj) -> bool:
    """Every number in a message dict is finite."""
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(finite(v) for v in obj.values())
    if isinstance(obj, list):
        if obj and isinstance(obj[0], float):
            return all(map(math.isfinite, obj))
        return all(finite(v) for v in obj)
    return True


_STAMPED = {tp for tp in T.TYPES.values() if tp in (
    "sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped",
    "geometry_msgs/msg/PointStamped")}
"""Types whose first field is a std_msgs/Header (its stamp right after the CDR header)."""


def _stamp_ns(raw: bytes) -> int:
    """The time at the start of a message: rosgraph_msgs/Clock's ``clock`` or a stamped
    message's ``header.stamp`` (int32 sec, uint32 nanosec at byte 4, little-endian)."""
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nsec


_MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


def _header_ns(tp: str, raw: bytes) -> int | None:
    """The header stamp of a stamped message (None for the others): the first
    ``header.stamp`` of a stamped type, the first marker's of a MarkerArray (after the
    sequence count; the simulator stamps every marker of an array alike, and builds it
    in realtime after the tick it shows)."""
    if tp in _STAMPED:
        return _stamp_ns(raw)
    if tp == _MARKER_ARRAY and len(raw) >= 16 and struct.unpack_from("<I", raw, 4)[0]:
        sec, nsec = struct.unpack_from("<iI", raw, 8)
        return sec * 1_000_000_000 + nsec
    return None


def _decode(tp: str, raw: bytes):
    """The rclpy message of ``raw``, or None when the bytes are not one of ``tp`` (checked
    first with :mod:`flexarm_ros.bag.cdr_read` where it reads ``tp``: rmw prints a line to
    stderr for every message it fails to deserialize)."""
    from rclpy.serialization import deserialize_message
    from flexarm_ros.bag.cdr_read import READERS
    if tp in READERS:
        try:
            decode_values(tp, raw)
        except CdrError:
            return None
    try:
        return deserialize_message(raw, msg_class(tp))
    except Exception:                        # rmw's deserialization error
        return None


def _text(m, raw: bytes = b"") -> str:
    """A message's content as a short text for ``diagnostics/rejected``."""
    if m is None:
        return f"{len(raw)} bytes that are not a message of the topic's type"
    data = getattr(m, "data", None)
    if data is not None and not isinstance(data, (str, bool)):
        return show(data)
    return str(m)[:200]


class RecorderNode(Node):
    """flexarm twin recorder node: all topics into an MCAP file (log time = sim time)."""

    EXECUTABLE = "recorder"
    PARAMS = {"output": ("run.mcap", "MCAP file to write"),
              "flush_period": (1.0, "s of wall time between chunk flushes (bounds the loss "
                                    "of a SIGKILL)"),
              "writer_process": (False, "stamp and write the bag in a child process (on "
                                        "another core; flexarm run sets it in one process)"),
              "batch_s": (0.005, "s of wall time the recorder's own process pauses between "
                                 "draining its queues (one wake-up per batch; below "
                                 f"{C.DEPTH} messages per topic nothing is lost; 0: none)"),
              "await_command_source": (False, "subscribe to joint_states only once every "
                                       "publisher of motor_driver/commands on the graph "
                                       "is matched, so the bag holds a user's controller's "
                                       "first command (flexarm run sets it where it "
                                       "starts the motor driver and not the controller)"),
              "published_file": ("", "the simulator's summary file (flexarm run sets it): "
                                     "at the end the recorder compares what it took with "
                                     "what the simulator published, per topic, and writes "
                                     "any shortfall into the bag's missing_messages "
                                     "metadata (empty: no comparison)")}

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        self.p, scene, _ = C.load(self, self.PARAMS)
        self.lockstep = self.p["mode"] == "lockstep"
        b = self.p["batch_s"]
        if not (isinstance(b, (int, float)) and 0.0 <= b <= 0.5):
            raise ValueError(f"parameter batch_s: got {b!r}, expected 0 to 0.5 s")
        self.spin_pause_s = float(b)             # read by node_main (own process only)
        from flexarm_ros.model.explain import explain
        ns = self.get_namespace()
        over = fidelity_overrides(self.p)
        sets = decode_sets(self.p["set"])
        embed = dict(over)
        ran = scene
        if scene.fidelity.rung == "auto":       # the model that runs, for whoever rebuilds it
            from flexarm_ros.model.autofidelity import choose
            c = choose(scene)
            chosen = dict(rung=c.rung, refine=c.refine, dt=c.dt_request, tolerance=0.0)
            embed.update(chosen)
            ran = scene.with_fidelity(**chosen)
        info = {"scene": scene.name,
                "scene_yaml": (ran_scene_yaml(self.p["scene"], ran, sets, over) if sets else
                               scene_yaml(self.p["scene"], embed)),
                "flexarm_ros_version": __version__, "time_mode": self.p["mode"],
                "namespace": ns, "control_mode": scene.twin_control.mode,
                "fidelity_overrides": json.dumps(over, sort_keys=True),
                "set": json.dumps(sets)}
        self.abs = {t: T.resolve(ns, t) for t in list(T.TYPES) + [T.REJECTED]
                    + list(T.BAG_ONLY_TYPES)}
        extra = {"model": {"explain": explain(scene)}}
        if self.p["writer_process"]:
            self.sink = WriterProcess(self.p["output"], info, C.DEPTH, extra, self.abs,
                                      self.p["flush_period"])
        else:
            writer = BagWriter(self.p["output"], metadata=info, qos_depth=C.DEPTH)
            for name, data in extra.items():
                writer.add_metadata(name, data)
            self.sink = SimTimeStamper(writer, self.abs, self.p["flush_period"])
        self.robot = _robot_description(self, ran)   # the URDF, for the bag
        self._robot_due = self.robot is not None     # written with the run's first message
        self.validators = {T.COMMANDS: Validator(scene, "command"),
                           T.EFFORTS: Validator(scene, "effort")}
        self.rejections = Rejections(self, period_s=float("inf"))   # the nodes log them
        self.last_clock_ns = None         # the simulator's latest /clock taken
        self.received = {}
        attach_diagnostics(self)               # /diagnostics at 1 Hz
        self.last_rx = time.monotonic()
        self.sources, self.subs = {}, {}
        gated = bool(self.p["await_command_source"])
        for topic in sorted(T.TYPES, key=lambda t: t == T.CLOCK):
            if gated and topic == T.JOINT_STATES:
                continue                        # see _subscribe_states_when_matched
            self._subscribe(topic)
        self._gate = (self.create_timer(0.02, self._subscribe_states_when_matched,
                                        clock=C.wall_clock()) if gated else None)

    def _subscribe(self, topic):
        tp = T.TYPES[topic]
        sub = C.subscription(self, tp, topic, lambda m, info, topic=topic, tp=tp:
                             self._on(topic, tp, m, info), raw=True)
        self.subs[topic] = sub
        self.sources[topic] = Source(self, sub.topic_name, T.SOURCE[topic])

    def _subscribe_states_when_matched(self):
        """With a controller of the user's (``await_command_source``): subscribe to
        joint_states only once this node's command subscription has matched every
        publisher of commands the graph shows (one at least). The simulator starts only
        with the recorder on joint_states, and the controller answers the first state, so
        its first command is in the bag: before, the recorder of a ``--processes`` run
        matched the controller up to 0.36 s of sim time after the start, 168 commands
        missing, 1 run in 4 (session 27)."""
        sub = self.subs[T.COMMANDS]
        want = sum(1 for i in self.get_publishers_info_by_topic(sub.topic_name)
                   if i.topic_type == T.TYPES[T.COMMANDS])
        if want >= 1 and sub.get_publisher_count() >= want:
            self._gate.cancel()
            self._subscribe(T.JOINT_STATES)

    def _write_robot_description(self):
        """The URDF (``robot_description``) and the fixed transforms (``/tf_static``) at
        t = 0, once the run has started (a run that never starts records nothing but its
        refusals, and keeps the bag already there)."""
        self._robot_due = False
        self.sink.emit(0, T.ROBOT_DESCRIPTION, T.BAG_ONLY_TYPES[T.ROBOT_DESCRIPTION],
                       {"data": self.robot.urdf()}, 0)
        self.sink.emit(0, T.TF_STATIC, T.BAG_ONLY_TYPES[T.TF_STATIC],
                       M.tf_message(0, self.robot.fixed()), 0)

    def _on_clock(self, ts, data, t_ns):
        if self._robot_due:
            self._write_robot_description()
        if self.last_clock_ns is not None and t_ns < self.last_clock_ns:
            self._reject(T.CLOCK, "time went backwards", str(t_ns), ts, "the source")
            return
        self.last_clock_ns = t_ns
        self.sink.clock(ts, T.CLOCK, T.TYPES[T.CLOCK], data, t_ns)

    # ------------------------------------------------------------------- receiving
    def _reject(self, topic, reason, text, ts, who):
        self.rejections.add(self.abs[topic], reason, "")
        entry = {"topic": self.abs[topic], "reason": reason, "publisher": who, "data": text}
        self.sink.emit(ts, T.REJECTED, "std_msgs/msg/String", {"data": json.dumps(entry)})

    def _on(self, topic, tp, raw: bytes, info=None):
        self.last_rx = time.monotonic()
        ts = int(info.get("source_timestamp") or 0) if info else 0
        src = self.sources[topic]
        if topic not in self.validators and src.owner_expected and gid_of(info) in src.owner:
            # the twin's own node on a topic without a validator: what the general path
            # below does in this case (verdict None, trusted), with less Python
            self.received[topic] = self.received.get(topic, 0) + 1
            if topic == T.CLOCK:
                self._on_clock(ts, raw, _stamp_ns(raw))
            else:
                self._emit(ts, topic, tp, raw)
            return
        v = self.validators.get(topic)
        m = None
        if v is not None:                      # the values only (bag/cdr_read.py)
            try:
                m = decode_values(tp, raw)
            except CdrError:
                m = None
            why = v.reason(m.data) if m is not None else NOT_CDR
        else:
            why = None
        who = src.verdict(info, valid=why is None)
        if who is not None:
            self._reject(topic, src.reason, _text(m if m is not None else _decode(tp, raw), raw),
                         ts, who)
            return
        if why is not None:
            self._reject(topic, why, _text(m, raw), ts, self._name(info))
            return
        if not src.trusted(info):             # not the twin's own node: decode and check
            m = _decode(tp, raw)
            data = to_dict(m) if m is not None else None
            if data is None or not finite(data):
                self._reject(topic, NON_FINITE if data is not None else
                             NOT_CDR, _text(m, raw), ts,
                             self._name(info))
                return
            raw = encode_cdr(tp, data)        # padding zeroed: reproducible bytes
        self.received[topic] = self.received.get(topic, 0) + 1      # taken messages only
        if topic == T.CLOCK:
            self._on_clock(ts, raw, _stamp_ns(raw))
        else:
            self._emit(ts, topic, tp, raw)

    def _emit(self, ts, topic, tp, raw):
        """Into the bag at the message's stamp; a robot_state adds its /tf."""
        if self._robot_due:
            self._write_robot_description()
        hdr = _header_ns(tp, raw)
        self.sink.emit(ts, topic, tp, raw, hdr)
        if topic == T.ROBOT_JOINT_STATES and self.robot is not None:
            try:
                m = decode_values(tp, raw)
            except CdrError:
                return
            vals = dict(zip(m.name, m.position))
            moved = self.robot.moving([vals.get(n, 0.0) for n in self.robot.movable])
            t_ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            self.sink.emit(ts, T.TF, T.BAG_ONLY_TYPES[T.TF], M.tf_message(t_ns, moved), hdr)

    def _name(self, info) -> str:
        gid = gid_of(info)
        return "the source" if gid is None else gid.hex()

    def diagnostic_values(self) -> dict:
        """/diagnostics: messages recorded."""
        return {"recorded": sum(self.received.values())}

    def finish(self, executor, quiet=0.3, limit=5.0):
        """Keep reading until nothing arrived for ``quiet`` s (at most ``limit`` s)."""
        t0 = time.monotonic()
        self.last_rx = max(self.last_rx, t0 - quiet / 2)
        while time.monotonic() - self.last_rx < quiet and time.monotonic() - t0 < limit:
            executor.spin_once(timeout_sec=quiet / 4)

    #: the simulator's published counts per topic (relative names), when the recorder is
    #: in its process (a callable; else ``published_file`` is read)
    published_counts = None

    def missing(self) -> dict:
        """topic -> {"published": n, "recorded": m} for every topic of the simulator's of
        which the bag holds fewer messages than it published (a paused or overloaded
        recorder whose queue overflowed): nothing may be lost without a word."""
        published = None
        if self.published_counts is not None:
            published = self.published_counts()
        elif self.p["published_file"]:
            try:
                with open(self.p["published_file"]) as f:
                    published = json.load(f).get("published")
            except (OSError, ValueError):
                published = None
        return missing_messages(
            {self.abs[t]: n for t, n in (published or {}).items() if t in self.abs},
            {self.abs[t]: n for t, n in self.received.items()}) or {}

    def close(self):
        """Write what is held, the rejection counts, any shortfall against what the
        simulator published, and finalize the file (idempotent)."""
        if not self.sink.closed:
            counts = self.rejections.counts
            meta = {"rejected_messages": {"total": str(self.rejections.total()),
                                          "by_topic": json.dumps(counts, sort_keys=True)}}
            missing = self.missing()
            if missing:
                self.get_logger().error(
                    "the bag misses messages the simulator published: " + ", ".join(
                        f"{t} {v['recorded']} of {v['published']}"
                        for t, v in missing.items()))
                meta["missing_messages"] = {t: json.dumps(v) for t, v in missing.items()}
            self.sink.close(meta)

    @property
    def path(self) -> Path:
        return Path(self.p["output"])


def scene_yaml(scene, overrides: dict) -> str:
    """The text of the scene file ``scene`` (path or shipped name); with ``overrides``
    (``Scene.with_fidelity`` keywords) the file re-dumped with them in its ``fidelity``
    section."""
    text = resolve_scene_path(scene).read_text()
    if not overrides:
        return text
    data = yaml.safe_load(text)
    data["fidelity"] = {**(data.get("fidelity") or {}), **overrides}
    return (f"# {Path(str(scene)).name} with the fidelity overrides "
            f"{json.dumps(overrides, sort_keys=True)}\n"
            + yaml.safe_dump(data, sort_keys=False, allow_unicode=True))


def ran_scene_yaml(scene, ran, sets: dict, overrides: dict) -> str:
    """The scene that ran (``ran``: the file ``scene`` with the ``--set`` values ``sets``,
    the fidelity ``overrides`` and rung auto's choice applied), written out whole: the
    sets may change any section, and the loader gives exactly ``ran`` back."""
    from flexarm_ros.scene.keys import scene_mapping
    from flexarm_ros.scene.overrides import format_sets
    return (f"# {Path(str(scene)).name} with --set {format_sets(sets)}"
            + (f" and the fidelity overrides {json.dumps(overrides, sort_keys=True)}"
               if overrides else "") + "\n"
            + yaml.safe_dump(scene_mapping(ran), sort_keys=False, allow_unicode=True))


def _robot_description(node, scene):
    """The arm's :class:`~flexarm_ros.twin.robot_description.Description`, or None, said
    once, where the scene's arm cannot be described (the bag is recorded without)."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.twin.robot_description import Description
    try:
        return Description(Chain(scene))
    except (ValueError, ArithmeticError) as exc:
        node.get_logger().warning(f"{T.ROBOT_DESCRIPTION}: not recorded ({exc})")
        return None


def main(args=None):
    return C.node_main(RecorderNode, args)


if __name__ == "__main__":
    sys.exit(main())

