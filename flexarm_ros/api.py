"""The Python front door (``import flexarm_ros as fx``): the commands' own entry points,
so that a script runs exactly what the CLI runs.

    fx.load_scene(name_or_path, set={...})   the scene, ``--set`` values applied
    fx.simulate(scene, duration=..., ...)    ``flexarm simulate``: the one runner, the
                                             scene's controller in the loop
    fx.linearize(scene, closed_loop=False)   ``flexarm linearize [--closed-loop]``: a
                                             python-control StateSpace where ``control``
                                             is installed, else the arrays
    fx.modes(scene, joints=None)             ``flexarm modes``
    fx.design(scene, shaper="zvd")           ``flexarm design --shaper``: the shaped scene
    fx.design(scene, lqg=True)               ``flexarm design --lqg``: the LQG scene
    fx.estimate("run.mcap")                  ``flexarm estimate``: bending from a bag
    fx.read_bag(path)                        a twin bag, decoded

Bad input raises :class:`flexarm_ros.errors.InputError` (a ``SceneError`` for a scene)
with the CLI's one-line message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["load_scene", "simulate", "linearize", "modes", "design", "estimate", "read_bag",
           "urdf", "Result", "InputError", "SceneError"]

from flexarm_ros.errors import InputError, SceneError  # noqa: E402  (re-exported)


def load_scene(name_or_path, set: dict | None = None, **fidelity):
    """The scene of a shipped name or a YAML path, with ``set`` ({key path: value}, as
    ``--set``) and fidelity overrides (``rung=``, ``refine=``, ``integrator=``, ``dt=``,
    ``tolerance=``, … as the flags) applied the way the commands apply them."""
    from flexarm_ros.scene import load_scene as _load
    from flexarm_ros.scene.overrides import parse_sets, with_overrides
    if isinstance(name_or_path, Path):
        name_or_path = str(name_or_path)
    if set is not None and not isinstance(set, dict):
        raise InputError(f"set: got {type(set).__name__}, expected a mapping of scene key "
                         f"paths to values")
    # through --set's own parser: the same values and refusals (NaN, malformed keys)
    sets = parse_sets([f"{k}={_yaml(v)}" for k, v in (set or {}).items()])
    return with_overrides(_load(name_or_path), sets, _fidelity(fidelity))


def _yaml(value) -> str:
    """``value`` as --set's YAML text; numpy scalars and arrays as the plain numbers and
    lists they hold (a script's ``q[0] - 0.05`` is a numpy float)."""
    import yaml
    return yaml.safe_dump(_plain(value), default_flow_style=True).strip() \
        .removesuffix("...").strip()


def _plain(value):
    """numpy scalars → Python numbers, arrays and tuples → lists, recursively."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (np.ndarray, tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _fidelity(kw: dict) -> dict:
    keys = ("rung", "refine", "integrator", "rtol", "atol", "dt", "max_steps", "tolerance",
            "tolerance_metric")
    bad = [k for k in kw if k not in keys + ("estimate", "foreshortening")]
    if bad:
        raise InputError(f"{bad[0]}: unknown keyword, expected one of {', '.join(keys)}, "
                         f"estimate, foreshortening")
    return {k: kw.get(k) for k in keys} | {k: kw[k] for k in ("estimate", "foreshortening")
                                           if k in kw}


def _scene(scene):
    from flexarm_ros.scene.sections import Scene
    return scene if isinstance(scene, Scene) else load_scene(scene)


class Result:
    """A run's output table, the CLI's columns under their names (SI units,
    :attr:`units`), ``result["link1_tip_deflection"]``, ``result.t``; :attr:`summary` is
    ``flexarm simulate --json``'s; :attr:`sensor_tables` {rate Hz: columns}."""

    def __init__(self, res, scene):
        from flexarm_ros.io.units import table_units
        self._res, self.scene = res, scene
        self.columns = {k: np.asarray(v) for k, v in res.columns.items()}
        self.units = table_units(res.columns, scene)
        self.sensor_tables = res.sensor_tables or {}
        self.summary = res.summary()

    @property
    def t(self) -> np.ndarray:
        return self.columns["t"]

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"{name!r}: no such column; the columns are "
                           f"{', '.join(self.columns)}") from None

    def __contains__(self, name) -> bool:
        return name in self.columns

    def to_csv(self, path) -> Path:
        """The table as ``flexarm simulate --out`` writes it (.csv or .npz), the sensor
        tables beside it."""
        from flexarm_ros.io.paths import check_output_file
        from flexarm_ros.io.tables import sensor_table_path, write_table
        from flexarm_ros.io.units import table_units
        path = check_output_file("path", path, (".csv", ".npz"))
        write_table(path, self._res.columns, table_units(self._res.columns, self.scene))
        for rate, table in self.sensor_tables.items():
            write_table(sensor_table_path(path, rate), table,
                        table_units(table, self.scene))
        return path

    def to_pandas(self):
        """A pandas DataFrame of the columns (``name [unit]`` headers); needs pandas."""
        try:
            import pandas as pd
        except ImportError:
            raise InputError("to_pandas: pandas is not installed, expected `pip install "
                             "pandas` (or use .columns)") from None
        return pd.DataFrame({(f"{k} [{self.units[k]}]" if k in self.units else k): v
                             for k, v in self.columns.items()})


def simulate(scene, duration: float | None = None, open_loop: bool = False, progress=None,
             **fidelity) -> Result:
    """``flexarm simulate``: the scene (a :class:`Scene`, a shipped name or a path) run
    by the one runner for ``duration`` s (default the scene's), its controller in the
    loop unless ``open_loop``; fidelity keywords as :func:`load_scene`'s."""
    from flexarm_ros.commands.common import check_duration
    from flexarm_ros.scene.overrides import with_overrides
    from flexarm_ros.twin.batch import run_scene
    check_duration(duration)
    sc = _scene(scene)
    if fidelity:
        sc = with_overrides(sc, {}, _fidelity(fidelity))
    return Result(run_scene(sc, duration, progress=progress, open_loop=open_loop), sc)


def linearize(scene, closed_loop: bool = False, python_control: bool = True):
    """``flexarm linearize``: ẋ = Ax + Bu, y = Cx + Du about the initial state (or, with
    ``closed_loop``, the position loop about its target pose). A python-control
    ``StateSpace`` with the state, input and output names where ``control`` is installed
    (and ``python_control``), else :class:`flexarm_ros.model.statespace.StateSpace`; the
    operating point is ``.x0`` of the latter (python-control: ``sys.x0``)."""
    from flexarm_ros.commands.linearize import closed_loop_model
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.statespace import linearize as _lin
    sc = _scene(scene)
    ss = closed_loop_model(sc) if closed_loop else _lin(Chain(sc))
    if not python_control:
        return ss
    try:
        import control
    except ImportError:
        return ss
    sys_ = control.ss(ss.A, ss.B, ss.C, ss.D, states=list(ss.states),
                      inputs=list(ss.inputs), outputs=list(ss.outputs), name=sc.name)
    sys_.x0 = ss.x0
    sys_.units = {"states": ss.state_units, "inputs": ss.input_units,
                  "outputs": ss.output_units}
    return sys_


def modes(scene, joints: str | None = None) -> dict:
    """``flexarm modes --json``: natural frequencies (Hz) and mode shapes at the initial
    configuration, joints ``locked`` or ``free`` (default: locked when the scene drives
    them)."""
    from flexarm_ros.model.modes import scene_modes
    sc = _scene(scene)
    if joints not in (None, "locked", "free"):
        raise InputError(f"joints: got {joints!r}, expected locked or free")
    _, m = scene_modes(sc, joints)
    return {"joints": m.joints, "frequencies_hz": np.asarray(m.frequencies_hz),
            "shapes": np.asarray(m.shapes), "coordinates": list(m.coordinates)}


def design(scene, shaper: str | None = "zvd", modes: int | None = None, lqg: bool = False,
           weights=None):
    """``flexarm design --shaper`` (default zvd) or, with ``lqg=True``, ``flexarm design
    --lqg [--weights]`` (``weights``: a mapping or the option's text): the scene with the
    position loop's input shaper or LQG (its ``control.shaper`` / ``control.lqg`` records
    the design)."""
    import dataclasses
    from flexarm_ros.control.design import require_position, shaper_record
    from flexarm_ros.control.lqg import lqg_for_core
    from flexarm_ros.scene.schema import from_mapping
    from flexarm_ros.scene.sections import Lqg, Shaper
    from flexarm_ros.twin.cores import ControllerCore
    from flexarm_ros.version import __version__
    sc = _scene(scene)
    require_position(sc)
    ctl = ControllerCore(sc)
    if lqg:
        record, _ = lqg_for_core(sc, ctl, weights, __version__)
        section = from_mapping(Lqg, record, "control.lqg")
        return dataclasses.replace(sc, control=dataclasses.replace(sc.control, lqg=section))
    if weights is not None:
        raise InputError("weights: got weights for a shaper, expected them with lqg=True")
    record, _ = shaper_record(sc, shaper or "zvd", ctl.q_goal, ctl.q_start, modes,
                              __version__)
    sh = from_mapping(Shaper, record, "control.shaper")
    return dataclasses.replace(sc, control=dataclasses.replace(sc.control, shaper=sh))


def estimate(bag, scene=None, sensors: str = "all", process_noise: float | None = None):
    """``flexarm estimate``: the tip deflections and position of the arm in ``bag``
    estimated from its encoders (and accelerometers, ``sensors="all"``) with ``scene``
    (default: the one it recorded). A :class:`flexarm_ros.estimation.from_bag.Estimate`:
    ``.columns`` (the CSV's), ``.score`` (against the bag's ground truth, or None)."""
    from flexarm_ros.estimation.from_bag import estimate_bag
    return estimate_bag(bag, None if scene is None else _scene(scene), sensors, process_noise)


def urdf(scene, segments: int | None = None) -> str:
    """``flexarm urdf``: the arm as a URDF text (each beam ``segments`` rigid segments on
    virtual joints, default the ROS twin's 10; :mod:`flexarm_ros.twin.robot_description`)."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.twin.robot_description import SEGMENTS, Description
    n = SEGMENTS if segments is None else segments
    if not (isinstance(n, int) and 2 <= n <= 200):
        raise InputError(f"segments: got {n!r}, expected 2 to 200 segments per beam")
    return Description(Chain(_scene(scene)), n).urdf()


def read_bag(path):
    """A twin bag (``flexarm run --record``), every message decoded
    (:class:`flexarm_ros.bag.reader.Bag`: ``bag[topic]`` → [(log time ns, message)])."""
    from flexarm_ros.bag.reader import read_bag as _read
    return _read(path)
