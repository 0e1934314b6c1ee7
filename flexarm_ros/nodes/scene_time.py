"""A node's scene and its time: the parameters it declares and the scene loaded from them
(the ``set`` values, then the fidelity overrides: :func:`load`), and the simulator's
time of a message's stamp (:func:`stamp_ns`, :func:`tick_of`, :class:`SimTime`)."""

from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor

from flexarm_ros.nodes.parameters import COMMON, FIDELITY, MODES, fidelity_overrides
from flexarm_ros.twin.cores import to_ns, control_period

def declare(node, params: dict) -> dict:
    """Declare ``{name: (default, description)}`` read-only; return the values."""
    out = {}
    for name, (default, text) in params.items():
        desc = ParameterDescriptor(description=text, read_only=True)
        out[name] = node.declare_parameter(name, default, desc).value
    return out


def load(node, params: dict) -> tuple:
    """Common and fidelity parameters (:mod:`~flexarm_ros.nodes.parameters`) and
    ``params`` → (values, scene with the ``set`` values and then the fidelity overrides
    applied, end tick count or None)."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.scene.overrides import decode_sets, with_overrides
    p = declare(node, {**COMMON, **FIDELITY, **params})
    if p["mode"] not in MODES:
        raise ValueError(f"parameter mode: got {p['mode']!r}, expected one of {MODES}")
    scene = with_overrides(load_scene(p["scene"]), decode_sets(p["set"]),
                           fidelity_overrides(p))
    dur = p["duration"] or scene.duration
    n = None if dur == float("inf") else int(round(dur / control_period(scene)))
    return p, scene, n


def tick_of(scene, t_ns: int) -> int:
    return int(round(t_ns * 1e-9 / control_period(scene)))


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SimTime:
    """The simulator core's time of a tick, bit for bit. The plant advances on its integer
    grid (t = k·g·1e-9, :func:`~flexarm_ros.sim.plant.plant_grid_ns`); replaying that lets
    the controller and driver use the very float the core used (``__call__``: stamp → t)
    and the recorder stamp tick n (``tick_ns``), so a lockstep run equals
    :func:`~flexarm_ros.twin.cosim.cosimulate` exactly."""

    def __init__(self, scene):
        from flexarm_ros.sim.plant import plant_grid_ns
        self.grid = plant_grid_ns(scene)
        self.period = control_period(scene)
        self.per_tick = int(round(self.period * 1e9 / self.grid)) if self.grid else 0
        self._t = self._tick_t = 0.0
        self._ticks = [0]                                  # ns of tick n (no grid)

    def __call__(self, t_ns: int) -> float:
        if self.grid:
            return t_ns * 1e-9
        while to_ns(self._t) < t_ns:
            self._t += self.period
        return self._t if to_ns(self._t) == t_ns else t_ns * 1e-9

    def tick_ns(self, n: int) -> int:
        if self.grid:
            return n * self.per_tick * self.grid
        while len(self._ticks) <= n:
            self._tick_t += self.period
            self._ticks.append(to_ns(self._tick_t))
        return self._ticks[n]
