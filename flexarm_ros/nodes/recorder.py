"""The logger: every topic of the twin into a rosbag2-compatible MCAP file.

Subscribes (node-relative, reliable keep_last 1000): every topic of the contract
(:mod:`flexarm_ros.twin.topics`) — ``/clock``, ``joint_states``, ``encoders/counts``,
the sensor batches, ``tool/contact``, ``tool/wrench``, ``ground_truth/*``,
``motor_driver/commands``, ``effort_controller/commands``, ``motor_driver/motor_states``.
Publishes nothing. Writes ``output`` with :class:`~flexarm_ros.bag.BagWriter`: topics
under their absolute names, metadata ``flexarm_ros`` (scene YAML text, scene name,
software version, time mode, namespace, the fidelity overrides as JSON) and ``model`` (the
built model, ``flexarm explain``). With fidelity overrides (``-p rung:=rigid``, ``flexarm
run --rung rigid``) the embedded scene YAML is the scene file with its ``fidelity`` section
updated, so whoever rebuilds the model from the bag builds the one that ran.

Log time = simulation time: the header stamp where the message has one, ``/clock`` its
value. Headerless messages are paired by count: the n-th ``encoders/counts`` and
``tool/contact`` message (any mode: the simulator publishes them every tick) and, in
``lockstep``, the n-th ``motor_driver/commands`` and ``effort_controller/commands``
message belong to tick n (its stamp replayed from the scene, :class:`~._common.SimTime`;
this needs every message from the first on, which the nodes' start barrier ensures); a
sensor batch ends with sample C (cumulative rows) at C·Ts, so it belongs to tick
ceil(C·Ts/T) (any mode). In ``realtime`` / ``fast`` commands and efforts get the latest
``/clock`` received (the tick they answer, or a later one when the recorder lags).

Each message is decoded by rclpy and re-encoded with our CDR encoder (rmw leaves
alignment padding uninitialized, so raw bytes would not be reproducible). Chunks are
flushed every ``flush_period`` s of wall time, so a SIGKILL loses at most that much; on
SIGINT/SIGTERM the node keeps reading until the graph has been quiet for 0.3 s, then
finalizes the file.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import yaml

from rclpy.node import Node

from flexarm_ros import __version__
from flexarm_ros.bag import BagWriter
from flexarm_ros.scene import resolve_scene_path
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import control_period
from flexarm_ros.nodes import _common as C
from flexarm_ros.nodes._msgconv import to_dict
from flexarm_ros.nodes.parameters import fidelity_overrides

_TICK_TOPICS = (T.ENCODER_COUNTS, T.TOOL_CONTACT, T.COMMANDS, T.EFFORTS)


class RecorderNode(Node):
    """flexarm twin recorder node: all topics into an MCAP file (log time = sim time)."""

    EXECUTABLE = "recorder"
    PARAMS = {"output": ("run.mcap", "MCAP file to write"),
              "flush_period": (1.0, "s of wall time between chunk flushes (bounds the loss "
                                    "of a SIGKILL)")}

    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        self.p, scene, _ = C.load(self, self.PARAMS)
        self.lockstep = self.p["mode"] == "lockstep"
        from flexarm_ros.model.explain import explain
        ns = self.get_namespace()
        over = fidelity_overrides(self.p)
        info = {"scene": scene.name, "scene_yaml": scene_yaml(self.p["scene"], over),
                "flexarm_ros_version": __version__, "time_mode": self.p["mode"],
                "namespace": ns, "control_mode": scene.control.mode,
                "fidelity_overrides": json.dumps(over, sort_keys=True)}
        self.writer = BagWriter(self.p["output"], metadata=info, qos_depth=C.DEPTH)
        self.writer.add_metadata("model", {"explain": explain(scene)})
        self.period_ns = int(round(control_period(scene) * 1e9))
        self.every_ns = {}
        for topic, kind in T.BATCH_KINDS.items():
            rates = [s.rate_hz for s in scene.sensors if s.kind == kind]
            if rates:
                self.every_ns[topic] = int(round(1e9 / rates[0]))
        self.ticks = C.SimTime(scene)       # lockstep: the stamp of tick n
        self.latest_clock = 0
        self.index = {t: 0 for t in _TICK_TOPICS}
        self.rows = {t: 0 for t in T.BATCH_KINDS}
        self.received = {}
        self.last_rx = time.monotonic()
        self._flushed = time.monotonic()
        for topic in sorted(T.TYPES, key=lambda t: t == T.CLOCK):   # /clock last: of two
            tp = T.TYPES[topic]                   # ready messages the older is taken first
            C.subscription(self, tp, topic, lambda m, topic=topic, tp=tp: self._on(topic, tp, m))
        self.abs = {t: T.resolve(ns, t) for t in T.TYPES}

    def _write(self, topic, tp, data, t_ns):
        self.writer.write(self.abs[topic], tp, data, t_ns)
        now = time.monotonic()
        if now - self._flushed > self.p["flush_period"]:
            self.writer.flush()
            self._flushed = now

    def _on(self, topic, tp, m):
        self.last_rx = time.monotonic()
        self.received[topic] = self.received.get(topic, 0) + 1
        data = to_dict(m)
        if topic == T.CLOCK:
            t_ns = C.stamp_ns(m.clock)
            self.latest_clock = t_ns
            self._write(topic, tp, data, t_ns)
        elif "header" in data:
            self._write(topic, tp, data, C.stamp_ns(m.header.stamp))
        elif topic in T.BATCH_KINDS:
            self.rows[topic] += data["layout"]["dim"][0]["size"]
            every = self.every_ns.get(topic, self.period_ns)
            tick = -(-self.rows[topic] * every // self.period_ns)
            self._write(topic, tp, data, tick * self.period_ns)
        elif self.lockstep or topic in (T.ENCODER_COUNTS, T.TOOL_CONTACT):
            self._write(topic, tp, data, self.ticks.tick_ns(self.index[topic]))
            self.index[topic] += 1
        else:
            self._write(topic, tp, data, self.latest_clock)

    def finish(self, executor, quiet=0.3, limit=5.0):
        """Keep reading until nothing arrived for ``quiet`` s (at most ``limit`` s)."""
        t0 = time.monotonic()
        self.last_rx = max(self.last_rx, t0 - quiet / 2)
        while time.monotonic() - self.last_rx < quiet and time.monotonic() - t0 < limit:
            executor.spin_once(timeout_sec=quiet / 4)

    def close(self):
        """Finalize the file (idempotent)."""
        self.writer.close()

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


def main(args=None):
    return C.node_main(RecorderNode, args)


if __name__ == "__main__":
    sys.exit(main())
