"""What a view of the arm draws, from the scene and the model alone: the deformed beam
centerlines of a full coordinate vector, the tool point, the wall and the contact force
in the world frame — plain numpy, no bag and no viewer.

:class:`~flexarm_ros.viz.bag_view.BagView` draws a recorded bag with it (rerun export) and
the simulator node draws the running twin with it (``arm_markers``,
:mod:`flexarm_ros.nodes.markers`), so both views show the same geometry. The model is the
public :class:`~flexarm_ros.model.Chain` (``Chain.centerlines``, ``Chain.kinematics``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ArmGeometry"]


class ArmGeometry:
    """The drawable geometry of ``scene`` with the model ``chain`` (a
    :class:`~flexarm_ros.model.Chain` of that scene; built with the numpy backend when
    not given). Coordinates ``q`` are in ``chain.names`` order."""

    def __init__(self, scene, chain=None):
        self.scene = scene
        if chain is None:
            from flexarm_ros.model import Chain
            chain = Chain(scene, backend="numpy")
        self.chain = chain

    @property
    def tool_at_tip(self) -> bool:
        """The scene's tool point is the last beam's tip."""
        return not any(self.scene.tool.position)

    def reach(self) -> float:
        """Sum of the beam lengths and hub radii (m), the scale of the drawing."""
        return float(sum(lk.beam.length + lk.beam.hub_radius for lk in self.scene.links))

    def centerlines(self, q, samples: int = 21) -> list[np.ndarray]:
        """One (samples, 2) world-frame centerline per link, beam root to tip (m)."""
        return self.chain.centerlines(np.asarray(q, float), samples)

    def frames(self, q):
        """The chain's hub and tip frames at ``q`` (``Chain.kinematics``, frames only)."""
        return self.chain.kinematics(np.asarray(q, float), np.zeros(self.chain.n),
                                     frames_only=True)

    def shape(self, q, samples: int = 21) -> tuple:
        """(centerlines, hub origins (links, 2), tool point) at ``q``, from one
        evaluation of the frames."""
        kin = self.frames(q)
        return (self.chain.centerlines(np.asarray(q, float), samples, kin=kin),
                np.array([np.asarray(h.o, float) for h in kin.hub_frames]),
                self.tool_position(q, kin))

    def tool_position(self, q, kin=None) -> np.ndarray:
        """Tool point (m): the last tip frame o + A(ψ)·tool.position (``kin``: the frames
        at ``q``, when at hand)."""
        fr = (kin or self.frames(q)).tip_frames[-1]
        c, s = np.cos(fr.psi), np.sin(fr.psi)
        p = np.asarray(self.scene.tool.position, float)
        return np.asarray(fr.o, float) + np.array([c * p[0] - s * p[1], s * p[0] + c * p[1]])

    def wall_normal_tangent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(unit inward normal n, tangent t = E·n, E the +90° rotation) of the wall
        (None without one)."""
        if not self.scene.walls:
            return None
        n = np.asarray(self.scene.walls[0].normal, float)
        n = n / np.hypot(*n)
        return n, np.array([-n[1], n[0]])

    def wall_line(self, half_length: float | None = None) -> np.ndarray | None:
        """(2, 2) end points of the wall: ``point ± half_length·t`` (default: the reach)."""
        nt = self.wall_normal_tangent()
        if nt is None:
            return None
        h = self.reach() if half_length is None else half_length
        p = np.asarray(self.scene.walls[0].point, float)
        return np.array([p - h * nt[1], p + h * nt[1]])

    def contact_force(self, normal, friction) -> np.ndarray | None:
        """Force on the tool in the world frame, F_n·n + F_t·t (N; ``normal`` and
        ``friction`` as in ``tool/wrench``: scalars, or arrays of N giving (N, 2)); None
        without a wall."""
        nt = self.wall_normal_tangent()
        if nt is None:
            return None
        fn = np.asarray(normal, float)[..., None]
        ft = np.asarray(friction, float)[..., None]
        return fn * nt[0] + ft * nt[1]
