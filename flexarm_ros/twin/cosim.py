"""Batch co-simulation: the simulator, driver and controller cores wired in one loop in
the lockstep order of the ROS graph (:mod:`cores`), exchanging the same message
dictionaries. A lockstep ROS run must reproduce these messages exactly; an MCAP of the
co-simulation is what ``flexarm run --mode lockstep`` would record."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.bag import messages as msg
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import ControllerCore, DriverCore, SimulatorCore, to_ns


@dataclass
class Message:
    topic: str          # node-relative (or /clock)
    msgtype: str
    t_ns: int           # simulation time of publication (the log time)
    data: dict


@dataclass
class CosimResult:
    messages: list = field(default_factory=list)
    rejected_commands: int = 0
    controller_status: str = "ok"

    def topic(self, name: str) -> list:
        return [m for m in self.messages if m.topic == name]


class Lockstep:
    """One tick at a time: ``tick()`` publishes the simulator's state, runs the
    controller and driver on it, and steps the plant; the messages of every piece in
    publication order."""

    def __init__(self, scene):
        self.scene = scene
        self.sim = SimulatorCore(scene)
        self.ctl = ControllerCore(scene)
        self.drv = DriverCore(scene)
        self.period = self.sim.period

    def state_messages(self) -> list:
        t_ns = to_ns(self.sim.t)
        return [Message(topic, tp, t_ns, data) for topic, tp, data in self.sim.outputs()]

    def control_messages(self, state: list) -> list:
        """Controller and driver answering the state messages (by topic content only)."""
        by = {m.topic: m.data for m in state}
        t = self.sim.t
        t_ns = to_ns(t)
        js = by[T.JOINT_STATES]
        contact = by.get(T.TOOL_CONTACT, {"data": False})["data"]
        fn = by[T.TOOL_WRENCH]["wrench"]["force"]["x"] if T.TOOL_WRENCH in by else 0.0
        cmd = self.ctl.update(t, self.period, js["position"], contact, fn)
        out = [Message(T.COMMANDS, T.TYPES[T.COMMANDS], t_ns,
                       msg.float64_multiarray(cmd, ("joint",)))]
        self.drv.accept(t, out[0].data["data"])
        targets = ([Message(T.JOINT_TARGETS, T.TYPES[T.JOINT_TARGETS], t_ns,
                            self.ctl.targets(t_ns))] if self.ctl.has_targets else [])
        gt = by[T.GT_JOINT_STATES]
        n = len(self.scene.links)
        drive_angles = np.array(gt["position"][n:2 * n])
        drive_rates = np.array(gt["velocity"][n:2 * n])
        tau = self.drv.update(t, self.period, drive_rates, gt["effort"][n:2 * n])
        out.append(Message(T.EFFORTS, T.TYPES[T.EFFORTS], t_ns,
                           msg.float64_multiarray(tau, ("joint",))))
        out.append(Message(T.MOTOR_STATES, T.TYPES[T.MOTOR_STATES], t_ns,
                           self.drv.motor_states(t_ns, drive_angles, drive_rates)))
        return out + targets

    def tick(self) -> list:
        state = self.state_messages()
        ctrl = self.control_messages(state)
        self.sim.step(ctrl[1].data["data"])
        return state + ctrl


def cosimulate(scene, duration: float, progress=None) -> CosimResult:
    """Run the three cores in lockstep for ``duration`` s (whole control periods)."""
    ls = Lockstep(scene)
    n = int(round(duration / ls.period))
    res = CosimResult()
    for k in range(n):
        res.messages.extend(ls.tick())
        if progress is not None and k % 200 == 0:
            progress(k / n)
    res.messages.extend(ls.state_messages())
    res.rejected_commands = ls.drv.rejected
    res.controller_status = ls.ctl.status
    return res
