"""The bench computer: :class:`~flexarm_ros.twin.cores.ControllerCore` on ROS 2.

Subscribes (node-relative): ``joint_states`` (quantized encoder angles), and in scenes
with a wall ``tool/contact`` and ``tool/wrench``. Publishes: ``motor_driver/commands``
(std_msgs/Float64MultiArray, V per joint; A for a valve; N·m for a joint without drive),
one per joint state it answers, and with position or sanding control
``controller/joint_targets`` after each command (for the log: the targets it tracks). The control law comes from the scene's ``control:``
section (open_loop programs, position PD with inverse kinematics, sanding).

With position control it also follows ``controller/joint_trajectory``
(trajectory_msgs/JointTrajectory, joint_trajectory_controller's convention; from any node):
validated on entry (:meth:`ControllerCore.accept_trajectory`), a rejected one is logged
and counted and changes nothing; header.stamp zero starts it at the latest state's time.

Live tuning: the PD's ``kp``, ``kd`` and ``voltage_limit`` (position and sanding),
``joint_target`` and the shaper's ``shaper_impulses`` ([t0, A0, t1, A1, …]; position)
are parameters a user sets while the twin runs (``ros2 param set``); a set is
validated by the scene's rules for ``control.changes`` (refused with the reason, nothing
changes), applied at the next tick and published on ``controller/parameter_changes`` as
the ``control.changes`` entry that reruns it (:meth:`ControllerCore.retune`).

Its state inputs are taken from the ``simulator`` only (a second publisher of any of them is
refused, counted and logged: :mod:`flexarm_ros.nodes._wire`).

Time: the state's stamp (simulation time) is the controller's time; no timer, no clock.
In ``lockstep`` the k-th joint state is paired with the k-th contact and wrench messages
(count-based FIFO, the same tick); in ``realtime`` / ``fast`` the latest contact and
wrench go with each joint state. States at or past ``duration`` are not answered, and
nothing is published before the driver (and ``recorders``) have matched.
"""

from __future__ import annotations

import sys
from collections import deque

from rclpy.node import Node
from rclpy.parameter import Parameter
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult

from flexarm_ros.bag.cdr_fixed import CdrBuilder
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import ControllerCore
import flexarm_ros.nodes.common as C
from flexarm_ros.nodes.diagnostics import attach as attach_diagnostics
from flexarm_ros.nodes._wire import Rejections, Source


class ControllerNode(Node):
    """flexarm twin controller node: joint states in, motor commands out."""

    EXECUTABLE = "controller"

    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        self.p, scene, self.n_end = C.load(self, {})
        self.lockstep = self.p["mode"] == "lockstep"
        self.scene = scene
        self.core = ControllerCore(scene)
        self.period = 1.0 / scene.twin_control.rate_hz
        self.sim_time = C.SimTime(scene)
        self.pub = C.publisher(self, T.TYPES[T.COMMANDS], T.COMMANDS)
        self._cdr = CdrBuilder()                # wire bytes from a template
        needs = [(self.pub, 1 + self.p["recorders"], "the motor driver")]
        self.pub_targets = None                 # the targets: for the log (position, sanding)
        if self.core.has_targets:
            self.pub_targets = C.publisher(self, T.TYPES[T.JOINT_TARGETS], T.JOINT_TARGETS)
            needs.append((self.pub_targets, self.p["recorders"], "the recorder"))
        self.live, self.pending = _live_parameters(self), {}
        self.pub_changes = None
        if self.live:
            self.pub_changes = C.publisher(self, T.TYPES[T.PARAMETER_CHANGES],
                                           T.PARAMETER_CHANGES)
            needs.append((self.pub_changes, self.p["recorders"], "the recorder"))
            self.add_on_set_parameters_callback(self._on_set)
        self.ready = C.Barrier(self, needs, self.p["recorders"])
        self.queues = {T.JOINT_STATES: deque()}
        if scene.walls:
            self.queues[T.TOOL_CONTACT] = deque()
            self.queues[T.TOOL_WRENCH] = deque()
        self.latest = {T.TOOL_CONTACT: False, T.TOOL_WRENCH: 0.0}
        self.sources = {}
        self.rejections = Rejections(self)
        attach_diagnostics(self)               # /diagnostics at 1 Hz
        for topic in self.queues:
            sub = C.subscription(self, T.TYPES[topic], topic,
                                 lambda m, info, topic=topic: self._on(topic, m, info),
                                 plain=True)
            self.sources[topic] = Source(self, sub.topic_name, T.SOURCE[topic])
        self.t_now = 0.0                        # the latest state's scene time
        self.trajectories = 0
        if self.core.mode == "position" and _has_trajectory_msgs():
            C.subscription(self, T.INPUT_TYPES[T.JOINT_TRAJECTORY], T.JOINT_TRAJECTORY,
                           self._on_trajectory)
        self.published = {T.COMMANDS: 0}
        if self.pub_targets is not None:
            self.published[T.JOINT_TARGETS] = 0
        self._started = False                   # the start barrier passed
        # the start barrier, on the wall clock: with use_sim_time (fast mode) a timer on
        # the node's clock would wait for the /clock that only the start brings
        self.timer = self.create_timer(0.01, self._drain, clock=C.wall_clock())

    def _on(self, topic, m, info=None):
        who = self.sources[topic].verdict(info)
        if who is not None:
            self.rejections.refused(self.sources[topic], "a message", None, who)
            return
        if topic == T.TOOL_CONTACT:
            m = bool(m.data)
        elif topic == T.TOOL_WRENCH:
            m = m.wrench.force.x
        if self.lockstep or topic == T.JOINT_STATES:
            self.queues[topic].append(m)
        else:
            self.latest[topic] = m
        self._drain()

    def _on_trajectory(self, m, *_):
        """A trajectory: the reference from its start, or rejected with the reason."""
        try:
            st = m.header.stamp
            start = self.sim_time(C.stamp_ns(st)) if (st.sec or st.nanosec) else None
            times = [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                     for p in m.points]
            why = self.core.accept_trajectory(
                self.t_now, start, list(m.joint_names), times,
                [list(p.positions) for p in m.points], [list(p.velocities) for p in m.points])
        except Exception as exc:  # noqa: BLE001 — no message may stop the controller
            why = f"unreadable ({type(exc).__name__}: {exc})"
        if why is not None:
            self.rejections.invalid(T.JOINT_TRAJECTORY, "a trajectory of",
                                    [len(m.points), "points"], why,
                                    "the scene's joints, finite targets at increasing times")
            return
        self.trajectories += 1
        self.get_logger().info(f"{T.JOINT_TRAJECTORY}: following a trajectory of "
                               f"{len(m.points)} points to {self.core.q_goal.tolist()} rad")

    def _drain(self):
        if not self._started:
            if not self.ready():
                return
            self.timer.cancel()
            self._started = True
        qs = self.queues
        while qs[T.JOINT_STATES] and (not self.lockstep or all(qs.values())):
            js = qs[T.JOINT_STATES].popleft()
            if self.lockstep and len(qs) > 1:
                contact, fn = qs[T.TOOL_CONTACT].popleft(), qs[T.TOOL_WRENCH].popleft()
            else:
                contact, fn = self.latest[T.TOOL_CONTACT], self.latest[T.TOOL_WRENCH]
            t_ns = C.stamp_ns(js.header.stamp)
            if self.n_end is not None and C.tick_of(self.scene, t_ns) >= self.n_end:
                continue
            self.t_now = self.sim_time(t_ns)
            if self.pending:
                self._apply(self.t_now)
            cmd = self.core.update(self.t_now, self.period, list(js.position), contact, fn)
            self.pub.publish(self._cdr.float64_multiarray(cmd, ("joint",)))
            self.published[T.COMMANDS] += 1
            if self.pub_targets is not None:
                self.pub_targets.publish(self.core.targets(t_ns, self._cdr))
                self.published[T.JOINT_TARGETS] += 1

    def _on_set(self, params):
        """A live set of kp / kd / joint_target: checked as a ``control.changes`` entry of
        the scene (with the sets accepted before it), kept for the next tick."""
        from flexarm_ros.errors import InputError, SceneError
        from flexarm_ros.scene.keys import set_keys
        change = dict(self.pending)
        for prm in params:
            if prm.name not in self.live:
                continue
            if prm.type_ not in (Parameter.Type.DOUBLE_ARRAY, Parameter.Type.INTEGER_ARRAY):
                return SetParametersResult(successful=False, reason=(
                    f"{prm.name}: got {prm.value!r} ({prm.type_.name.lower()}), expected a "
                    f"list of {len(self.scene.links)} numbers (one per joint)"))
            values = [float(v) for v in prm.value]
            if prm.name == "shaper_impulses":   # [t0, A0, t1, A1, …]: one shaper, one set
                if not values or len(values) % 2:
                    return SetParametersResult(successful=False, reason=(
                        f"shaper_impulses: got {values}, expected pairs of time and "
                        f"amplitude [t0, A0, t1, A1, ...]"))
                change["shaper"] = {"times": values[0::2], "amplitudes": values[1::2]}
                continue
            change[prm.name] = values
        if change == self.pending:
            return SetParametersResult(successful=True)
        try:
            set_keys(self.scene, {"control.changes": [{"time": 0.0, **change}]})
        except (SceneError, InputError, ValueError) as exc:
            why = " ".join(str(exc).split()).replace("control.changes[0].", "")
            return SetParametersResult(successful=False, reason=why)
        why = self.core.voltage_limit_error(change.get("voltage_limit", ()))
        if why:
            return SetParametersResult(successful=False, reason=f"voltage_limit: {why}")
        self.pending = change
        return SetParametersResult(successful=True)

    def _apply(self, t: float):
        """The pending sets, from this tick on, recorded as a ``control.changes`` entry."""
        import json
        from std_msgs.msg import String
        rec = self.core.retune(t, **self.pending)
        self.pending = {}
        self.pub_changes.publish(String(data=json.dumps(rec)))
        self.get_logger().info(f"{T.PARAMETER_CHANGES}: {json.dumps(rec)}")

    def finish(self, executor=None):
        """The final log line: commands published, inputs refused."""
        self.get_logger().info(f"{self.published[T.COMMANDS]} commands published; "
                               f"{self.trajectories} trajectories followed; "
                               f"{self.rejections.summary()}")


#: what a user tunes live: parameter -> (modes, description)
LIVE = {"kp": (("position", "sanding"), "PD stiffness per joint, N·m/rad (live: applied at "
                                        "the next tick)"),
        "kd": (("position", "sanding"), "PD damping per joint, N·m·s/rad (live: applied at "
                                        "the next tick)"),
        "joint_target": (("position",), "the step target, rad per joint (live: a new step "
                                        "from the current command at the next tick)"),
        "voltage_limit": (("position", "sanding"), "the output limit, V per joint, at most "
                                                   "the drive's (live: from the next tick)"),
        "shaper_impulses": (("position",), "the shaper as [t0, A0, t1, A1, ...] (s, 1): the "
                                           "first time 0, the amplitudes summing to 1; "
                                           "[0.0, 1.0] no shaping (live: for the target "
                                           "steps set from then on)")}


def _live_parameters(node) -> tuple:
    """Declare the live-tunable parameters the scene's law has (none in open loop or
    with an LQG), at the values the controller starts with; their names."""
    core = node.core
    if core.mode == "open_loop" or core.lqg is not None:
        return ()
    sh = core.shaper
    values = {"kp": core.pd.kp, "kd": core.pd.kd, "joint_target": core.q_goal,
              "voltage_limit": core.limit,
              "shaper_impulses": ([v for pair in zip(sh.times, sh.amplitudes) for v in pair]
                                  if sh is not None else [0.0, 1.0])}
    names = []
    for name, (modes, text) in LIVE.items():
        if core.mode in modes:
            node.declare_parameter(name, [float(v) for v in values[name]],
                                   ParameterDescriptor(description=text,
                                                       dynamic_typing=True))
            names.append(name)
    return tuple(names)


def _has_trajectory_msgs() -> bool:
    """trajectory_msgs imports (the [ros] extra installs it; a ROS distribution has it)."""
    try:
        import trajectory_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True


def main(args=None):
    return C.node_main(ControllerNode, args)


if __name__ == "__main__":
    sys.exit(main())
