"""The arm as a robot description (URDF) and its transforms (TF), from the scene and the
model (no rclpy): what RViz2's RobotModel, robot_state_publisher and Foxglove's 3D panel
read.

Each beam is a chain of :data:`SEGMENTS` rigid segments of length ℓ = L/N on virtual
revolute joints about z, placed on the model's deformed centerline
(:meth:`~flexarm_ros.model.rung_chain.RungChain.centerlines`, the shape functions of the
rung that runs):

    world ─ ``<link>_joint`` ─ ``<link>_hub`` ─ ``<link>_bend0`` (at the hub radius r_h)
    ─ ``<link>_seg0`` ─ ``<link>_stretch0`` (ℓ along it) ─ ``<link>_seg0_end``
    ─ ``<link>_bend1`` ─ … ─ ``<link>_seg{N−1}_end`` ─ ``<link>_tip_slope``
    ─ ``<link>_tip`` ─ the next link's joint (at the tip body's offset) …

with ``tool`` fixed at the last tip and, in scenes with a wall, ``wall`` fixed to
``world`` (x along the wall's normal n, y along t = E·n: the frame of ``tool/wrench``).
The joint values: ``<link>_joint`` is the model's joint angle q_k; ``<link>_bend{i}`` is
the turn from one chord of the sampled centerline to the next, θ_i − θ_{i−1} (θ_{−1} = 0
in the hub frame); ``<link>_stretch{i}`` (prismatic, along the chord) is the chord's
length minus ℓ, so that each ``<link>_seg{i}`` frame sits on a sample point of the
centerline exactly (the floating-frame rungs do not keep a beam's length at large
deflection: two_link_case1's beams after 8 s of sliding on the wall were 1.8 mm off
without it); ``<link>_tip_slope`` turns the last chord onto the frame the next joint
turns from (the hub frame angle ψ_{k+1} − q_{k+1}; at the last link the tangent
extrapolated from the last two chords).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

#: rigid segments per beam
SEGMENTS = 10


@dataclass(frozen=True)
class Joint:
    """One URDF joint: ``parent`` → ``child`` at (x, y) in the parent frame, turned by
    ``yaw0`` there; ``movable``: a continuous joint about z (its value adds to yaw0)."""
    name: str
    parent: str
    child: str
    x: float
    y: float
    yaw0: float = 0.0
    movable: bool = True
    prismatic: bool = False        # a slide along the parent's x (else a turn about z)


class Description:
    """The URDF and transforms of ``chain``'s arm (module doc)."""

    def __init__(self, chain, segments: int = SEGMENTS):
        self.chain, self.n = chain, int(segments)
        scene = chain.scene
        q0 = np.asarray(_initial(chain), float)
        kin = chain.kinematics(q0, np.zeros(len(q0)), frames_only=True)
        joints, parent = [], "world"
        for k, lm in enumerate(chain.links):
            name = lm.name
            o = kin.hub_frames[0].o if k == 0 else self._offset(kin, q0, k)
            # the base's turn: the first hub frame's angle beyond the joint angle
            base = (kin.hub_frames[0].psi - (float(q0[lm.i_joint]) if lm.i_joint >= 0
                                             else 0.0)) if k == 0 else 0.0
            joints.append(Joint(f"{name}_joint", parent, f"{name}_hub", float(o[0]),
                                float(o[1]), float(base)))
            ell = lm.beam.length / self.n
            prev = f"{name}_hub"
            for i in range(self.n):
                x = lm.beam.hub_radius if i == 0 else 0.0
                joints.append(Joint(f"{name}_bend{i}", prev, f"{name}_seg{i}", x, 0.0))
                joints.append(Joint(f"{name}_stretch{i}", f"{name}_seg{i}",
                                    f"{name}_seg{i}_end", ell, 0.0, prismatic=True))
                prev = f"{name}_seg{i}_end"
            joints.append(Joint(f"{name}_tip_slope", prev, f"{name}_tip", 0.0, 0.0))
            parent = f"{name}_tip"
        joints.append(Joint("tool_joint", parent, "tool", 0.0, 0.0, movable=False))
        for w in scene.walls[:1]:
            n = np.asarray(w.normal, float) / np.linalg.norm(w.normal)
            joints.append(Joint("wall_joint", "world", "wall", float(w.point[0]),
                                float(w.point[1]), math.atan2(n[1], n[0]), movable=False))
        self.joints = joints
        self.movable = [j.name for j in joints if j.movable]
        self._check_hubs(q0)

    def _offset(self, kin, q, k) -> tuple:
        """Where link k's joint sits in the frame it turns from (the previous beam's tip
        frame, yaw ψ_k − q_k): the tip body's joint offset, constant in that frame."""
        ch = self.chain
        tip = ch.centerlines(q, 2, kin=kin)[k - 1][-1]
        lm = ch.links[k]
        yaw = kin.hub_frames[k].psi - (float(q[lm.i_joint]) if lm.i_joint >= 0 else 0.0)
        d = np.asarray(kin.hub_frames[k].o, float) - tip
        c, s = math.cos(yaw), math.sin(yaw)
        return (c * d[0] + s * d[1], -s * d[0] + c * d[1])

    def _check_hubs(self, q):
        """The joint offsets are constant in their frames (checked at a bent pose)."""
        ch = self.chain
        bent = np.asarray(q, float) + 0.05 * np.sin(np.arange(len(q)) + 1.0) * \
            np.array([_check_scale(ch, i) for i in range(len(q))])
        kin = ch.kinematics(bent, np.zeros(len(bent)), frames_only=True)
        for k in range(1, len(ch.links)):
            j = next(j for j in self.joints if j.name == f"{ch.links[k].name}_joint")
            got = self._offset(kin, bent, k)
            gap = float(np.hypot(got[0] - j.x, got[1] - j.y))
            if gap > 1e-9:
                raise ValueError(f"links[{k}]: its joint moves {gap:.3g} m in the frame of "
                                 f"the previous beam's tip, expected a fixed offset (the "
                                 f"URDF chains them)")

    def positions(self, q) -> np.ndarray:
        """The values of :attr:`movable` (rad) at the model's coordinates ``q``."""
        ch = self.chain
        q = np.asarray(q, float)
        kin = ch.kinematics(q, np.zeros(len(q)), frames_only=True)
        lines = ch.centerlines(q, self.n + 1, kin=kin)
        out = []
        for k, lm in enumerate(ch.links):
            psi = kin.hub_frames[k].psi
            qk = float(q[lm.i_joint]) if lm.i_joint >= 0 else 0.0
            c, s = math.cos(psi), math.sin(psi)
            local = (lines[k] - np.asarray(kin.hub_frames[k].o)) @ np.array([[c, -s], [s, c]])
            d = np.diff(local, axis=0)
            theta = np.arctan2(d[:, 1], d[:, 0])
            bends = np.diff(np.concatenate([[0.0], theta]))
            stretch = np.hypot(d[:, 0], d[:, 1]) - lm.beam.length / self.n
            if k + 1 < len(ch.links):
                nxt = ch.links[k + 1]
                q_next = float(q[nxt.i_joint]) if nxt.i_joint >= 0 else 0.0
                frame = kin.hub_frames[k + 1].psi - q_next - psi
            else:
                frame = theta[-1] + 0.5 * (theta[-1] - theta[-2]) if self.n > 1 else theta[-1]
            out.append(qk)
            for b, e in zip(bends, stretch):
                out += [b, e]
            out.append(_wrap(frame - theta[-1]))
        return np.asarray(out, float)

    def transforms(self, values) -> list:
        """(parent, child, x, y, yaw) of every joint: the movable ones at ``values``
        (:attr:`movable` order), the fixed ones as they are (what /tf and /tf_static
        carry)."""
        vals = dict(zip(self.movable, np.asarray(values, float)))
        return [(j.parent, j.child, j.x + vals.get(j.name, 0.0), j.y, j.yaw0)
                if j.prismatic else
                (j.parent, j.child, j.x, j.y, j.yaw0 + vals.get(j.name, 0.0))
                for j in self.joints]

    def moving(self, values) -> list:
        """The transforms of the movable joints at ``values`` (what /tf carries)."""
        return [tr for j, tr in zip(self.joints, self.transforms(values)) if j.movable]

    def fixed(self) -> list:
        """The transforms of the fixed joints, tool and wall (what /tf_static carries)."""
        return [tr for j, tr in zip(self.joints, self.transforms(np.zeros(len(self.movable))))
                if not j.movable]

    def urdf(self, name: str | None = None) -> str:
        """The URDF text: links with a box per segment and a cylinder per hub (visuals
        for RViz2), continuous joints about z, fixed tool and wall."""
        ch = self.chain
        name = name or ch.scene.name
        width = 0.01 * max(sum(lm.beam.length for lm in ch.links), 1e-3)
        lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(name)}>",
                 '  <link name="world"/>']
        for k, lm in enumerate(ch.links):
            ell = lm.beam.length / self.n
            r = max(lm.beam.hub_radius, 2 * width)
            lines.append(f'  <link name="{lm.name}_hub"><visual><geometry><cylinder '
                         f'radius="{r:.6g}" length="{width:.6g}"/></geometry></visual></link>')
            for i in range(self.n):
                lines.append(f'  <link name="{lm.name}_seg{i}"><visual><origin '
                             f'xyz="{ell / 2:.9g} 0 0"/><geometry><box size="{ell:.9g} '
                             f'{width:.6g} {width / 2:.6g}"/></geometry></visual></link>')
                lines.append(f'  <link name="{lm.name}_seg{i}_end"/>')
            lines.append(f'  <link name="{lm.name}_tip"/>')
        lines.append('  <link name="tool"/>')
        if ch.scene.walls:
            lines.append('  <link name="wall"/>')
        for j in self.joints:
            kind = ("prismatic" if j.prismatic else "continuous") if j.movable else "fixed"
            axis = ('<axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="0" '
                    'velocity="1"/>' if j.prismatic else '<axis xyz="0 0 1"/>')
            lines.append(f'  <joint name="{j.name}" type="{kind}"><parent link="{j.parent}"/>'
                         f'<child link="{j.child}"/><origin xyz="{j.x:.12g} {j.y:.12g} 0" '
                         f'rpy="0 0 {j.yaw0:.12g}"/>'
                         + (axis if j.movable else "") + "</joint>")
        lines.append("</robot>")
        return "\n".join(lines) + "\n"


def _check_scale(chain, i) -> float:
    """A coordinate's scale for the bent check pose: 1 rad for an angle, 1 % of the
    beam for an elastic coordinate (its name has no ``_joint`` / ``_motor``)."""
    name = chain.names[i]
    if name.endswith(("_joint", "_motor", "_drive")):
        return 1.0
    return 0.01


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _initial(chain):
    from flexarm_ros.model.statics import initial_state
    return initial_state(chain)[0]
