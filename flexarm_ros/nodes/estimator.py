"""The twin follows the rig, live: :class:`~flexarm_ros.estimation.from_bag.Follower` on
ROS 2 (``ros2 run flexarm_ros estimator``, ``flexarm-estimator``).

Subscribes (node-relative) to the bench topics of docs/topic_contract.md, so it runs
unchanged beside a real rig publishing them: ``joint_states`` (the encoder angles, read
back as counts), ``accelerometers/batch`` and ``motor_driver/commands``. Publishes, one
per tick: ``estimator/joint_states`` (estimated joint angles and rates),
``estimator/tip_deflections`` (each link's hub-frame tip deflection, m),
``estimator/tip`` (the tip, frame ``world``), ``estimator/nis`` ([ν per dof, CPU µs of the
tick]), and ``estimator/events`` (std_msgs/String) when the departure test turns on.

A tick is estimated once its encoder angles, its accelerometer batch (where the scene has
accelerometers) and the command answering it have arrived, or when the next tick's state
comes; its events are fed in the bag estimate's order, so the node's estimate of a run is
``flexarm estimate``'s of its bag. Parameter ``sensors``: all or encoders.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rclpy.node import Node

import flexarm_ros.nodes.common as C            # first: it loads rclpy's message support
from flexarm_ros.nodes.diagnostics import attach as attach_diagnostics
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.recording import expand_batch
from builtin_interfaces.msg import Time  # noqa: E402,I100
from geometry_msgs.msg import PointStamped  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402


class EstimatorNode(Node):
    """flexarm twin estimator node: bench topics in, estimated bending out."""

    EXECUTABLE = "estimator"

    def __init__(self, **kwargs):
        super().__init__("estimator", **kwargs)
        from flexarm_ros.estimation.from_bag import Follower
        from flexarm_ros.estimation.kalman import Measurement
        from flexarm_ros.model.sensors import build_sensors
        from flexarm_ros.model.statics import initial_state
        self.p, scene, _ = C.load(self, {"sensors": ("all", "the measurements the filter "
                                                            "reads: all or encoders")})
        self.scene, self.M = scene, Measurement
        self.fol = Follower(scene, self.p["sensors"])
        chain = self.fol.filter.chain
        q0 = np.asarray(initial_state(chain)[0], float)
        enc = sorted((s for s in build_sensors(chain) if s.spec.kind == "encoder"),
                     key=lambda s: s.spec.joint)
        self.enc = [(s.link, q0[s.coord], s.gain, s.name) for s in enc]
        acc = [s for s in scene.sensors if s.kind == "accelerometer"]
        self.acc_names = tuple(s.name for s in acc)
        self.acc_rate = acc[0].rate_hz if acc else None
        self.pending = []                         # [t_ns, enc, acc rows, command]
        self.pubs = {t: C.publisher(self, ty, t) for t, ty in T.ESTIMATOR_TYPES.items()}
        self.in_departure = False
        self.first_ns = None
        self.ticks_published = 0
        self.nis = float('nan')                   # the latest tick's NIS
        attach_diagnostics(self)                  # /diagnostics at 1 Hz
        for topic, cb in ((T.JOINT_STATES, self._on_state), (T.ACCEL_BATCH, self._on_batch),
                          (T.COMMANDS, self._on_command)):
            C.subscription(self, T.TYPES[topic], topic, cb, plain=True)

    def _on_state(self, m, *_):
        self._flush()
        t = C.stamp_ns(m.header.stamp)
        counts = np.array([round((m.position[link] - q0) * gain)
                           for link, q0, gain, _ in self.enc], float)
        enc = self.M(t, "encoder", tuple(n for *_, n in self.enc), counts)
        self.pending = [t, enc, None if self.acc_names else [], None]

    def _on_batch(self, m, *_):
        if not self.pending or self.pending[2] is not None or not self.acc_names:
            return
        t_ns, rows = expand_batch(m, self.pending[0], self.acc_rate, len(self.acc_names))
        self.pending[2] = [self.M(int(t), "accelerometer", self.acc_names, r)
                           for t, r in zip(t_ns, rows)]
        self._maybe()

    def _on_command(self, m, *_):
        if self.pending and self.pending[3] is None:
            self.pending[3] = np.asarray(m.data, float)
            self._maybe()

    def _maybe(self):
        if self.pending and self.pending[2] is not None and self.pending[3] is not None:
            self._flush()

    def _flush(self):
        if not self.pending:
            return
        t, enc, acc, cmd = self.pending
        self.pending = []
        if self.first_ns is None:
            self.first_ns = t                     # the first tick it estimated
        c0 = time.process_time()
        events = ([(t, 0, "command", cmd)] if cmd is not None else []) + \
            [(a.t_ns, 1, "accelerometer", a) for a in (acc or [])] + [(t, 2, "encoder", enc)]
        row = None
        for tt, _, kind, payload in sorted(events, key=lambda e: (e[0], e[1])):
            row = self.fol.feed(tt, kind, payload) or row
        if row is not None:
            self._publish(t, row, (time.process_time() - c0) * 1e6)

    def _publish(self, t_ns, row, cpu_us):
        _, q, nis, event = row
        ch = self.fol.filter.chain
        stamp = Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
        f = self.fol.filter
        qd = np.zeros(ch.n)
        qd[list(ch.free)] = f.ss.x0[f.nf:2 * f.nf] + f.x[f.nf:2 * f.nf]
        js = JointState(name=[f"{lm.name}_joint" for lm in ch.links],
                        position=[float(q[lm.i_joint]) for lm in ch.links],
                        velocity=[float(qd[lm.i_joint]) for lm in ch.links])
        js.header.stamp = stamp
        self.pubs[T.EST_JOINT_STATES].publish(js)
        self.pubs[T.EST_DEFLECTIONS].publish(
            Float64MultiArray(data=[float(v) for v in ch.tip_deflections(q)]))
        tip = ch.tip_position(q)
        pt = PointStamped()
        pt.header.stamp, pt.header.frame_id = stamp, "world"
        pt.point.x, pt.point.y = float(tip[0]), float(tip[1])
        self.pubs[T.EST_TIP].publish(pt)
        self.pubs[T.EST_NIS].publish(Float64MultiArray(data=[float(nis), float(cpu_us)]))
        self.nis = float(nis)
        if (event == "departure") != self.in_departure:
            self.in_departure = event == "departure"
            self.pubs[T.EST_EVENTS].publish(String(
                data=f"{t_ns * 1e-9:.6f} s: departure {'on' if self.in_departure else 'off'}"))
        self.ticks_published += 1

    def diagnostic_values(self) -> dict:
        """/diagnostics: ticks estimated, the latest NIS, whether a departure is on."""
        return {"ticks": self.ticks_published, "nis": self.nis,
                "departure": self.in_departure}

    def finish(self, executor=None):
        """The final log line: ticks estimated, CPU per tick."""
        self._flush()
        self.get_logger().info(f"{self.ticks_published} ticks estimated, "
                               f"{self.fol.cpu_per_tick_us:.0f} µs of CPU per tick")


def main(args=None):
    return C.node_main(EstimatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
