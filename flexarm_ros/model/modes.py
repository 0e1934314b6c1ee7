"""A scene's natural modes at its initial state, as ``flexarm modes`` and ``fx.modes``
give them (:func:`flexarm_ros.model.linear.natural_modes` of the scene's chain)."""

from __future__ import annotations


def scene_modes(scene, joints: str | None = None):
    """(chain, Modes) of ``scene`` at its initial state (``flexarm modes``): joints
    ``locked`` or ``free``, by default locked when the scene has inputs (it drives them)."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.linear import natural_modes
    from flexarm_ros.model.statics import initial_state
    chain = Chain(scene)
    joints = joints or ("locked" if scene.inputs else "free")
    return chain, natural_modes(chain, initial_state(chain)[0], joints)
