"""The equations of a flexible-link arm, free of ROS and of integration.

What a library user imports (loaded on first use, so importing one submodule stays cheap)::

    from flexarm_ros.scene import load_scene
    from flexarm_ros.model import Chain, natural_modes, linearize
    chain = Chain(load_scene("link_tipmass"))
    natural_modes(chain).frequencies_hz

Modules: ``chain`` (the planar chain: M(q), h, Q_grav, K, D, right-hand side), ``beams``
(the ladder of beam discretizations), ``drives`` (DC motor + gearbox, backlash, hydraulic
servovalve), ``programs`` (input programs), ``sensors`` (instrument models), ``contact``
(wall contact laws: gap, impulse law, constrained dynamics), ``linear`` (linearization,
natural modes, highest rate), ``statespace`` (A, B, C, D), ``statics`` (initial state and
static equilibrium), ``explain`` (what was built), ``compiled`` (the numba twins of
chain, contact and sensors, and the compiled integration loops).
"""

from importlib import import_module

_PUBLIC = {
    "Chain": "chain", "Modes": "linear", "natural_modes": "linear",
    "highest_rate": "linear", "StateSpace": "statespace", "linearize": "statespace",
    "initial_state": "statics", "static_equilibrium": "statics",
    "WallContact": "contact", "build_contact": "contact",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name):
    if name in _PUBLIC:
        return getattr(import_module(f"flexarm_ros.model.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module 'flexarm_ros.model' has no attribute {name!r}")
