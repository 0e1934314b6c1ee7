"""The model of a scene: :class:`Chain`, the planar flexible chain
(:class:`~flexarm_ros.model.rung_chain.RungChain`, where the equations live) at the
scene's rung, with ``fidelity.rung: auto`` resolved first to the model
:mod:`~flexarm_ros.model.autofidelity` chooses over the scene's duration."""

from __future__ import annotations

import dataclasses

from flexarm_ros.model.auto_search import resolve
from flexarm_ros.model.rung_chain import RungChain, check_backend


class Chain(RungChain):
    """The planar flexible chain built from a scene at one rung of the ladder; rung auto
    is the chosen model over the scene's duration (its choice in :attr:`auto`)."""

    def __init__(self, scene, fidelity=None, backend: str = "auto"):
        check_backend(backend)
        auto = None
        if (fidelity or scene.fidelity).rung == "auto":
            if fidelity is not None:
                scene = dataclasses.replace(scene, fidelity=fidelity)
            scene, auto = resolve(scene)
            fidelity = None
        super().__init__(scene, fidelity, backend)
        self.auto = auto            # autofidelity.AutoChoice when the scene says rung auto
