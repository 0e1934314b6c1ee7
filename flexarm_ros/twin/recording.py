"""The twin's conventions in a recorded bag, read in one place (for analysis and views).

A bag written by ``flexarm run --record`` (:mod:`flexarm_ros.nodes.recorder`) holds:

* metadata :data:`~flexarm_ros.bag.writer.INFO_METADATA_NAME` (``flexarm_ros``): ``scene``
  (the scene name), ``scene_yaml`` (the scene file's text), ``namespace`` (where the twin's
  topics are; :data:`DEFAULT_NAMESPACE` when absent), ``flexarm_ros_version``,
  ``time_mode``, ``control_mode``;
* the topics of :mod:`flexarm_ros.twin.topics` under that namespace, each message logged
  at the simulation time;
* sensor batches (:data:`~flexarm_ros.twin.topics.BATCH_KINDS`: ``accelerometers/batch``,
  ``strain/batch``, ``potentiometer/batch``), ``std_msgs/Float64MultiArray`` laid out
  [sample, channel] by the std_msgs rule ``value[i, j] = data[data_offset +
  dim[1].stride * i + j]`` with ``n = dim[0].size`` samples and ``c = dim[1].size``
  channels (a ``dim[1].stride`` of 0 counts as ``c``). Sample ``i`` of a batch logged at
  ``t_m`` was taken at ``t_m - (n - 1 - i) / rate_hz`` (rounded to the nanosecond):
  uniform, the last at the message time. The channels are the scene's sensors of that
  kind in scene order and ``rate_hz`` their common rate.

Nothing here imports rclpy or the model; the embedded scene is loaded with
:func:`flexarm_ros.scene.load_scene_dict`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

import yaml

from flexarm_ros.bag.reader import BagError
from flexarm_ros.bag.writer import INFO_METADATA_NAME
from flexarm_ros.twin import topics as T
from flexarm_ros.scene.yaml_input import load_yaml

__all__ = ["DEFAULT_NAMESPACE", "BatchLayout", "SensorBatches", "batch_layout",
           "batch_times_ns", "embedded_scene", "expand_batch", "expand_batches",
           "namespace", "recorded_namespace", "scene_yaml", "sensor_batches", "twin_info",
           "twin_messages"]

#: Namespace of the twin's topics in a bag whose metadata does not name one.
DEFAULT_NAMESPACE = "/flexarm"


# ----------------------------------------------------------------------------- metadata

def twin_info(bag) -> dict | None:
    """The ``flexarm_ros`` metadata of a twin bag; None for a bag the twin did not record.

    When that record was lost to damage, the copy :class:`~flexarm_ros.bag.BagWriter`
    keeps as the ``rosbag2`` record's ``custom_data`` (written on close) stands in."""
    info = bag.metadata.get(INFO_METADATA_NAME)
    if info is None:
        custom = (bag.rosbag2_metadata() or {}).get("custom_data")
        if isinstance(custom, dict) and "scene_yaml" in custom:
            return {str(k): str(v) for k, v in custom.items()}
    return info


def recorded_namespace(bag) -> str | None:
    """The namespace the twin recorded under (metadata ``flexarm_ros.namespace``), or None
    when the bag does not say."""
    return (twin_info(bag) or {}).get("namespace") or None


def namespace(bag, override: str | None = None) -> str:
    """Where the twin's topics are: ``override``, else the recorded namespace, else
    :data:`DEFAULT_NAMESPACE`."""
    return override or recorded_namespace(bag) or DEFAULT_NAMESPACE


def scene_yaml(bag) -> str | None:
    """The scene text embedded in a twin bag (metadata ``flexarm_ros.scene_yaml``), or
    None."""
    return (twin_info(bag) or {}).get("scene_yaml") or None


def embedded_scene(bag):
    """The :class:`~flexarm_ros.scene.Scene` embedded in a twin bag, or None when the bag
    has no ``flexarm_ros.scene_yaml``.

    Raises:
        BagError: the text is not YAML or not a valid scene (e.g. written by another
            software version), naming the bag, the key and the scene's complaint.
    """
    text = scene_yaml(bag)
    if text is None:
        return None
    from flexarm_ros.scene import load_scene_dict
    try:
        return load_scene_dict(load_yaml(text, "scene_yaml"))
    except (yaml.YAMLError, ValueError, TypeError, KeyError, AttributeError) as err:
        raise BagError(f"{bag.path}: metadata {INFO_METADATA_NAME}.scene_yaml is not a valid "
                       f"scene: {err}") from err


def recorded_changes(bag) -> list:
    """The live parameter sets a twin bag recorded (``controller/parameter_changes``), as
    the ``control.changes`` entries that rerun them, in time order."""
    out = []
    for _, m in twin_messages(bag, T.PARAMETER_CHANGES):
        try:
            rec = json.loads(m["data"] if isinstance(m, dict) else m.data)
        except (ValueError, TypeError, KeyError, AttributeError) as err:
            raise BagError(f"{bag.path}: {T.PARAMETER_CHANGES}: an entry that is not a JSON "
                           f"object ({err})") from err
        out.append(rec)
    return out


def rerun_scene_text(bag) -> str:
    """The scene a twin bag ran, with the live parameter sets it recorded as its
    ``control.changes``: YAML text that ``flexarm simulate`` runs to the same ticks
    (``flexarm bag scene``). BagError when the bag has no embedded scene."""
    text = scene_yaml(bag)
    if text is None:
        raise BagError(f"{bag.path}: no embedded scene (metadata "
                       f"{INFO_METADATA_NAME}.scene_yaml), expected a bag of flexarm run "
                       f"--record")
    data = load_yaml(text, "scene_yaml")
    changes = recorded_changes(bag)
    if changes:
        ctl = data.setdefault("control", {})
        ctl["changes"] = list(ctl.get("changes") or []) + changes
    head = (f"# the scene {bag.path} recorded, with its {len(changes)} live parameter "
            f"changes as control.changes (flexarm bag scene)\n")
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def twin_messages(bag, topic: str, ns: str | None = None) -> list:
    """``[(log time ns, message)]`` of a twin topic (relative name, resolved under ``ns``,
    default :func:`namespace`); empty when the bag lacks it."""
    return bag.messages.get(T.resolve(ns if ns is not None else namespace(bag), topic), [])


# ----------------------------------------------------------------------------- batches

@dataclass(frozen=True)
class BatchLayout:
    """Where the values of one [sample, channel] batch sit in its ``data``:
    ``value[i, j] = data[offset + stride * i + j]``, ``0 <= i < samples``,
    ``0 <= j < channels``."""

    samples: int
    channels: int
    stride: int
    offset: int


def batch_layout(layout, size: int, columns: int | None = None,
                 where: str = "batch") -> BatchLayout:
    """The :class:`BatchLayout` of a message's ``layout`` (a MultiArrayLayout, or None)
    over ``size`` data values.

    Two dims: samples ``dim[0].size``, channels ``dim[1].size``, stride ``dim[1].stride``
    (0: the channel count), offset ``data_offset``. Any other layout (one dim, none, or
    ``layout=None``): rows of ``columns`` values from ``data_offset`` on, as many as the data
    holds (``columns`` None: one channel).

    Raises:
        BagError: the layout points past the data, or (no two dims) the values after the
            offset are not whole rows; ``where`` names the message.
    """
    dims = list(getattr(layout, "dim", None) or []) if layout is not None else []
    offset = int(getattr(layout, "data_offset", 0) or 0) if layout is not None else 0
    if len(dims) == 2:
        n, c = int(dims[0].size), int(dims[1].size)
        stride = int(dims[1].stride) or c
        if n * c and offset + stride * (n - 1) + c > size:
            raise BagError(f"{where}: layout says {n} samples x {c} channels (stride "
                           f"{stride}, data_offset {offset}), the data has only {size} "
                           f"values")
        return BatchLayout(n, c, stride, offset)
    c = int(columns or 1)
    if c < 1 or (size - offset) % c or offset > size:
        raise BagError(f"{where}: {size} values after data_offset {offset} are not whole rows "
                       f"of {c} channels")
    return BatchLayout((size - offset) // c, c, c, offset)


def batch_times_ns(log_time_ns: int, samples: int, rate_hz: float) -> np.ndarray:
    """Sample times (int64 ns) of a batch of ``samples`` rows logged at ``log_time_ns``:
    ``log_time_ns - round((samples - 1 - i) * 1e9 / rate_hz)``."""
    back = np.rint((samples - 1 - np.arange(samples)) * 1e9 / rate_hz).astype(np.int64)
    return np.int64(log_time_ns) - back


def expand_batch(msg, log_time_ns: int, rate_hz: float, columns: int | None = None,
                 where: str = "batch") -> tuple[np.ndarray, np.ndarray]:
    """``(t_ns (n,), values (n, c))`` of one Float64MultiArray batch (layout as
    :func:`batch_layout`, times as :func:`batch_times_ns`).

    Raises:
        BagError: the layout does not fit the data.
    """
    data = np.asarray(msg.data, dtype=np.float64).ravel()
    lay = batch_layout(getattr(msg, "layout", None), data.size, columns, where)
    idx = (lay.offset + lay.stride * np.arange(lay.samples)[:, None]
           + np.arange(lay.channels)[None, :])
    return batch_times_ns(log_time_ns, lay.samples, rate_hz), data[idx]


def expand_batches(messages, rate_hz: float, columns: int | None = None,
                   where: str = "batch") -> tuple[np.ndarray, np.ndarray]:
    """:func:`expand_batch` over ``[(log time ns, message)]``, concatenated in order:
    ``(t_ns (N,), values (N, c))``.

    Raises:
        BagError: a layout does not fit its data, or the channel count changes between
            messages.
    """
    ts, vs = [], []
    for t, m in messages:
        tt, vv = expand_batch(m, t, rate_hz, columns, where=f"{where} at {t} ns")
        if vs and vv.shape[1] != vs[0].shape[1]:
            raise BagError(f"{where} at {t} ns: {vv.shape[1]} channels, the earlier batches "
                           f"have {vs[0].shape[1]}; expected one layout per topic")
        ts.append(tt)
        vs.append(vv)
    if not ts:
        return np.zeros(0, np.int64), np.zeros((0, columns or 0))
    return np.concatenate(ts), np.concatenate(vs)


@dataclass
class SensorBatches:
    """The samples of one sensor batch topic of a twin bag.

    ``names``: one per column, the scene's sensors of ``kind`` in scene order (``sensors``
    their specs) or, when the scene has none of that kind or another count,
    ``<kind>_<j>`` (``sensors`` empty). ``rate_hz``: the sensors' rate, else estimated from
    the message spacing (``notes`` says so)."""

    topic: str                      # absolute
    kind: str
    names: list
    sensors: list
    rate_hz: float
    t_ns: np.ndarray                # (N,) int64
    values: np.ndarray              # (N, channels)
    notes: list


def _spacing_rate(messages, columns) -> float | None:
    """Rows of the last batch over the log-time spacing of the last two, or None."""
    if len(messages) < 2:
        return None
    (t0, _), (t1, m1) = messages[-2], messages[-1]
    rows = batch_layout(getattr(m1, "layout", None), len(m1.data), columns).samples
    return rows / ((t1 - t0) * 1e-9) if rows and t1 > t0 else None


def sensor_batches(bag, topic: str, scene, ns: str | None = None) -> SensorBatches | None:
    """The batches of ``topic`` (one of :data:`~flexarm_ros.twin.topics.BATCH_KINDS`, a
    relative name) expanded to one time per sample, or None when the bag has no message on
    it or (no sensor of that kind in ``scene``) fewer than two to estimate the rate from.

    ``scene`` (usually :func:`embedded_scene`; None: no scene) gives the names and rate.

    Raises:
        BagError: a batch's layout does not fit its data, or the layouts differ.
    """
    ns = namespace(bag) if ns is None else ns
    where = f"{bag.path}: {T.resolve(ns, topic)}"
    msgs = twin_messages(bag, topic, ns)
    if not msgs:
        return None
    kind = T.BATCH_KINDS[topic]
    spec = [s for s in (scene.sensors if scene is not None else ()) if s.kind == kind]
    notes = []
    if spec:
        rate = float(spec[0].rate_hz)
        if any(s.rate_hz != spec[0].rate_hz for s in spec):
            notes.append(f"{where}: the {kind} sensors have different rates "
                         f"{[s.rate_hz for s in spec]}; {rate:g} Hz used")
    else:
        rate = _spacing_rate(msgs, None)
        if rate is None:
            return None
        notes.append(f"{where}: no {kind} sensor in the scene; sample rate {rate:.6g} Hz "
                     f"estimated from the message spacing")
    cols = T.batch_columns(spec)
    t_ns, values = expand_batches(msgs, rate, len(cols) or None, where)
    if spec and values.shape[1] != len(cols):
        notes.append(f"{where}: {values.shape[1]} channels, the scene's {len(spec)} "
                     f"{kind} sensors have {len(cols)}; named {kind}_0, {kind}_1, ...")
        spec, cols = [], []
    if kind == "tip_position":                   # one spec per column (x, y)
        spec = [s for s in spec for _ in range(2)]
    names = cols or [f"{kind}_{j}" for j in range(values.shape[1])]
    return SensorBatches(T.resolve(ns, topic), kind, names, spec, rate, t_ns, values, notes)


def missing_messages(published: dict | None, recorded: dict | None) -> dict | None:
    """topic -> {"published": n, "recorded": m} where the bag holds fewer of the
    simulator's messages than it published (absolute topic names both); None: none
    missing or nothing to compare."""
    if not published or recorded is None:
        return None
    out = {t: {"published": n, "recorded": recorded.get(t, 0)}
           for t, n in sorted(published.items()) if recorded.get(t, 0) < n}
    return out or None
