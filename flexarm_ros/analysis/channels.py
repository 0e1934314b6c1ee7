"""Named time series from a twin bag, a foreign bag (through a channel map) or a CSV.

A :class:`Channel` is one scalar signal: ``name``, ``unit``, times ``t`` (s, strictly
increasing) and values ``y``. :func:`load_channels` turns an input file into a
:class:`ChannelSet` that :mod:`flexarm_ros.analysis.compare` lines up against another.

Channels of a twin bag (``flexarm run --record``; topic contract in
:mod:`flexarm_ros.twin.topics`, namespace from the bag's ``flexarm_ros`` metadata, sensor
names and units from the scene embedded there):

* ``<sensor>`` — accelerometers, strain gauges, potentiometers by their scene names; V with
  a ``sensitivity``, else m/s² / 1 / rad; from ``accelerometers/batch``, ``strain/batch``,
  ``potentiometer/batch``, one time per sample (layout, stride, offset and timing as
  :mod:`flexarm_ros.twin.recording` reads them: row i of a batch of n rows logged at t_m is
  the sample at ``t_m - (n - 1 - i) / rate_hz``); without sensors of that kind in the
  scene ``<kind>_<j>``, unit unknown;
* ``<encoder sensor>`` — count, ``encoders/counts``;
* ``<link>_joint_measured`` — rad, ``joint_states`` (the angle from the quantized encoder);
* ``<coordinate>`` — ``<link>_joint``, ``<link>_motor``, ``<link>_tip_disp``,
  ``<link>_tip_rot``, ``<link>_w1`` ..., rad or m (:func:`flexarm_ros.io.units.coordinate_unit`),
  ``ground_truth/coordinates``
  (``ground_truth/joint_states`` for bags without it);
* ``<link>_drive`` — rad, ``ground_truth/joint_states``, only where it differs from
  ``<link>_joint`` (a compliant drive train);
* ``tip_x``, ``tip_y`` — m, ``ground_truth/tip``;
* ``normal_force``, ``friction_force`` — N, ``tool/wrench`` force x, y;
* ``contact`` — 1 in contact, 0 free, ``tool/contact``;
* ``<link>_command`` — V, A or N·m, ``motor_driver/commands``;
* ``<link>_joint_target`` — rad, ``controller/joint_targets`` (sensor_msgs/JointState,
  names ``<link>_joint``, position = the commanded joint angles), when the bag has it: the
  target :mod:`flexarm_ros.analysis.control` measures ``<link>_joint`` and
  ``<link>_joint_measured`` against (:func:`target_names`);
* ``wall_gap`` — m, derived: ``min_k (p_tool - a_k) · n_k`` over the scene's walls: the
  tool point is the recorded tip when the scene's ``tool.position`` is (0, 0), else the
  last tip frame o + A(ψ)·``tool.position`` of the coordinates of
  ``ground_truth/coordinates`` through the scene's kinematics.

Channels of a CSV (:func:`flexarm_ros.io.experiment.read_experiment_csv`: an experiment,
or ``flexarm simulate --out``): one per numeric column, by its header's name and unit; a
``[text]`` column is no channel, but ``contact_phase`` (``flexarm simulate`` with a wall)
gives ``contact`` — 1 unless the phase is ``free``, the rule of the twin's ``tool/contact``
— when the file has no ``contact`` column. The sensor tables ``flexarm simulate`` writes
beside its main table (``run.sensors_<rate>hz.csv``) are read with it (without a channel
map): a simulated run is one record, main columns and declared sensors.

``wall_gap`` is also derived for any input (a CSV, a mapped bag) that has ``tip_x`` and
``tip_y`` (or, with the tool offset from the tip body, every coordinate of the scene's
chain) when the comparison supplies a scene with walls (:func:`add_wall_gap`).
Channels flagged ``vibration`` (accelerometers, strain gauges, elastic beam coordinates,
tip position; in a CSV by name: ``tip_x``, ``tip_y`` and the beam coordinates) are the
ones whose dominant frequency is a pass criterion.
"""

from __future__ import annotations

import glob
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from flexarm_ros.twin import recording
from flexarm_ros.bag.reader import BagError, TruncatedBagWarning, read_bag
from flexarm_ros.io.experiment import ChannelMap, CompareInputError, MapEntry, read_experiment_csv
from flexarm_ros.io.units import TEXT, beam_coordinate, coordinate_unit
from flexarm_ros.twin import topics as T

__all__ = ["Channel", "ChannelSet", "JOINT_TARGETS", "add_wall_gap", "bag_channels",
           "load_bag", "load_channels", "mapped_bag_channels", "same_unit", "scene_of_bag",
           "target_names"]

_SI_UNIT = {"accelerometer": "m/s^2", "strain": "1", "potentiometer": "rad", "tip_position": "m"}
_DRIVE_UNIT = {"dc_motor": "V", "hydraulic": "A", None: "N*m"}
#: The controller's commanded joint angles (sensor_msgs/JointState, names ``<link>_joint``):
#: the topic contract's name when :mod:`flexarm_ros.twin.topics` declares it.
JOINT_TARGETS = getattr(T, "JOINT_TARGETS", "controller/joint_targets")


def target_names(name: str) -> list[str]:
    """The channels that may hold the target (the command) of channel ``name``, in order of
    preference: ``<name>_target``; for a measured joint angle ``<link>_joint_measured`` also
    ``<link>_joint_target``; for the tip ``tip_target_x`` / ``tip_target_y`` (the names the
    batch simulator writes for closed-loop scenes)."""
    out = [f"{name}_target"]
    if name.endswith("_measured"):
        out.append(f"{name[:-len('_measured')]}_target")
    if name in ("tip_x", "tip_y"):
        out.append(f"tip_target_{name[-1]}")
    return out


@dataclass(frozen=True, eq=False)
class Channel:
    """One scalar signal: times ``t`` (s, strictly increasing, finite), values ``y``."""

    name: str
    unit: str
    t: np.ndarray
    y: np.ndarray
    source: str = ""
    vibration: bool = False
    topic: str = ""                 # the bag topic it was read from ('' for a CSV column)

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass
class ChannelSet:
    """The channels of one input file and what is known about it."""

    path: str
    kind: str                                   # 'mcap' or 'csv'
    channels: dict[str, Channel] = field(default_factory=dict)
    scene: Any = None                           # flexarm_ros.scene.Scene or None
    scene_name: str | None = None
    truncated: bool = False
    warnings: list[str] = field(default_factory=list)
    comments: list[str] = field(default_factory=list)

    def __contains__(self, name: str) -> bool:
        return name in self.channels

    def __getitem__(self, name: str) -> Channel:
        return self.channels[name]

    @property
    def names(self) -> list[str]:
        return list(self.channels)


def same_unit(a: str, b: str) -> bool:
    """Whether two unit strings name the same unit (spelling variants ``m/s²`` =
    ``m/s^2``, ``N·m`` = ``N*m`` = ``N m``, ``-`` = ``1``). Unknown units (``''``) match."""
    def norm(u: str) -> str:
        u = u.strip().replace("²", "^2").replace("³", "^3").replace("·", "*")
        u = re.sub(r"\s+", "*", u)
        return {"-": "1", "": ""}.get(u, u)
    na, nb = norm(a), norm(b)
    return not na or not nb or na == nb


def _clean(t, y) -> tuple[np.ndarray, np.ndarray]:
    """Sort by time (stable), keep the last of repeated stamps, drop non-finite values."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    order = np.argsort(t, kind="stable")
    t, y = t[order], y[order]
    if t.size > 1:
        last = np.append(t[1:] != t[:-1], True)
        t, y = t[last], y[last]
    return t, y


def _channel(name, unit, t, y, source, vibration=False, topic="") -> Channel | None:
    t, y = _clean(t, y)
    if t.size == 0:
        return None
    return Channel(name, unit, t, y, source, vibration, topic)


# ----------------------------------------------------------------------------- twin bags

def scene_of_bag(bag):
    """``(scene, problem)``: the scene embedded in a twin bag
    (:func:`flexarm_ros.twin.recording.embedded_scene`), or ``(None, why)``."""
    try:
        scene = recording.embedded_scene(bag)
    except BagError as exc:           # a scene from another software version
        return None, f"the embedded scene does not load ({exc})"
    if scene is None:
        return None, "the bag has no embedded scene (flexarm_ros metadata scene_yaml)"
    return scene, None


def _batch_channels(bag, topic, scene, ns, notes) -> list[Channel]:
    """One channel per column of a sensor batch topic
    (:func:`flexarm_ros.twin.recording.sensor_batches`: per-sample times, layout stride and
    offset honoured); V with a ``sensitivity``, else the kind's SI unit; '' unnamed."""
    sb = recording.sensor_batches(bag, topic, scene, ns)
    if sb is None:
        return []
    notes.extend(sb.notes)
    if sb.sensors:
        units = ["V" if s.sensitivity is not None else _SI_UNIT[sb.kind] for s in sb.sensors]
    else:
        units = [""] * len(sb.names)
    t = sb.t_ns * 1e-9
    out = []
    for j, (name, unit) in enumerate(zip(sb.names, units)):
        ch = _channel(name, unit, t, sb.values[:, j], f"{sb.topic} [sample, {j}]",
                      sb.kind in ("accelerometer", "strain"), sb.topic)
        if ch is not None:
            out.append(ch)
    return out


def _coordinate_unit(name: str) -> str:
    return coordinate_unit(name) or ""


def _joint_state(messages, topic, rename=lambda n: n, unit=_coordinate_unit,
                 vibration=beam_coordinate) -> dict[str, Channel]:
    cols: dict[str, tuple[list, list]] = {}
    for log_ns, msg in messages:
        for name, pos in zip(msg.name, msg.position):
            ts, ys = cols.setdefault(name, ([], []))
            ts.append(log_ns * 1e-9)
            ys.append(pos)
    out = {}
    for name, (ts, ys) in cols.items():
        ch = _channel(rename(name), unit(name), ts, ys, f"{topic} position[{name!r}]",
                      vibration(name), topic)
        if ch is not None:
            out[ch.name] = ch
    return out


def _scalar(messages, get, name, unit, topic, src, vibration=False) -> Channel | None:
    if not messages:
        return None
    t = [m[0] * 1e-9 for m in messages]
    y = [float(get(m[1])) for m in messages]
    return _channel(name, unit, t, y, f"{topic} {src}", vibration, topic)


def bag_channels(bag, scene=None, notes: list | None = None) -> dict[str, Channel]:
    """The channels of a twin bag (table in the module docstring). ``scene`` supplies the
    sensor names, units and drives (default: the scene embedded in the bag); ``notes``
    collects what was guessed (generic sensor names, an estimated sample rate).

    Raises:
        BagError: a sensor batch whose layout does not fit its data.
    """
    if scene is None:
        scene, _ = scene_of_bag(bag)
    notes = [] if notes is None else notes
    ns = recording.namespace(bag)

    def msgs(topic):
        return recording.twin_messages(bag, topic, ns)

    out: dict[str, Channel] = {}

    def put(ch):
        if ch is not None and ch.name not in out:
            out[ch.name] = ch

    sensors = list(scene.sensors) if scene is not None else []
    for topic in T.BATCH_KINDS:
        for ch in _batch_channels(bag, topic, scene, ns, notes):
            put(ch)
    enc = sorted((s for s in sensors if s.kind == "encoder"), key=lambda s: s.joint)
    m = msgs(T.ENCODER_COUNTS)
    for j, s in enumerate(enc):
        put(_scalar(m, lambda msg, j=j: msg.data[j], s.name, "count",
                    T.resolve(ns, T.ENCODER_COUNTS), f"data[{j}]"))
    for ch in _joint_state(msgs(T.JOINT_STATES), T.resolve(ns, T.JOINT_STATES),
                           rename=lambda n: f"{n}_measured", unit=lambda n: "rad",
                           vibration=lambda n: False).values():
        put(ch)
    gt = _joint_state(msgs(T.GT_JOINT_STATES), T.resolve(ns, T.GT_JOINT_STATES))
    coords = _joint_state(msgs(T.GT_COORDINATES), T.resolve(ns, T.GT_COORDINATES))
    for ch in coords.values():
        put(ch)
    for name, ch in gt.items():
        if name.endswith("_drive"):
            twin = gt.get(name[:-len("_drive")] + "_joint")
            if twin is not None and twin.t.shape == ch.t.shape \
                    and np.array_equal(twin.y, ch.y):
                continue            # a rigid drive train: the drive angle is the joint's
        put(ch)
    tip_topic = T.resolve(ns, T.GT_TIP)
    put(_scalar(msgs(T.GT_TIP), lambda msg: msg.point.x, "tip_x", "m", tip_topic,
                "point.x", True))
    put(_scalar(msgs(T.GT_TIP), lambda msg: msg.point.y, "tip_y", "m", tip_topic,
                "point.y", True))
    wr = T.resolve(ns, T.TOOL_WRENCH)
    put(_scalar(msgs(T.TOOL_WRENCH), lambda msg: msg.wrench.force.x, "normal_force", "N",
                wr, "wrench.force.x"))
    put(_scalar(msgs(T.TOOL_WRENCH), lambda msg: msg.wrench.force.y, "friction_force",
                "N", wr, "wrench.force.y"))
    put(_scalar(msgs(T.TOOL_CONTACT), lambda msg: 1.0 if msg.data else 0.0, "contact", "1",
                T.resolve(ns, T.TOOL_CONTACT), "data (1 = in contact)"))
    m = msgs(T.COMMANDS)
    if m:
        links = list(scene.links) if scene is not None else []
        for j in range(len(m[0][1].data)):
            if j < len(links):
                lk = links[j]
                name = f"{lk.name}_command"
                drive = lk.joint.drive.type if lk.joint.drive is not None else None
                unit = _DRIVE_UNIT.get(drive, "")
            else:
                name, unit = f"joint{j + 1}_command", ""
            put(_scalar(m, lambda msg, j=j: msg.data[j], name, unit,
                        T.resolve(ns, T.COMMANDS), f"data[{j}]"))
    for ch in _joint_state(msgs(JOINT_TARGETS), T.resolve(ns, JOINT_TARGETS),
                           rename=lambda n: f"{n}_target", unit=lambda n: "rad",
                           vibration=lambda n: False).values():
        put(ch)
    if scene is not None and any(scene.tool.position) and "tool_x" not in out:
        path = _tool_path(out, scene)      # the point a tool target and a wall refer to
        if not isinstance(path, str):
            t, x, y = path
            src = f"{T.resolve(ns, T.GT_COORDINATES)} through the scene's kinematics"
            put(_channel("tool_x", "m", t, x, src, True))
            put(_channel("tool_y", "m", t, y, src, True))
    return out


def add_wall_gap(channels: dict[str, Channel], scene) -> str | None:
    """Add ``wall_gap`` = ``min_k (p - a_k) · n_k`` (m; a_k a point of wall k, n_k its unit
    inward normal, p the tool point) when the scene has walls and ``channels`` has no
    ``wall_gap``. With the scene's ``tool.position`` at the tip-body origin (0, 0) the
    tool point is the tip, p = (tip_x, tip_y); with the tool offset from it, p is the last
    tip frame o + A(ψ)·``tool.position`` of the coordinate channels (every ``Chain.names``
    entry on one time base, as ``ground_truth/coordinates`` gives them) through the
    scene's kinematics. Returns why nothing was added, or None.
    """
    if "wall_gap" in channels:
        return None
    if scene is None or not getattr(scene, "walls", ()):
        return "no scene with walls"
    if any(float(v) != 0.0 for v in scene.tool.position):
        path = _tool_path(channels, scene)
        if isinstance(path, str):
            return path
        t, x, y = path
        how = "derived: distance of the tool point (the coordinates through the scene's " \
              "kinematics) to the wall line(s)"
    else:
        if "tip_x" not in channels or "tip_y" not in channels:
            return "no tip_x / tip_y channels"
        tx, ty = channels["tip_x"], channels["tip_y"]
        if tx.t.shape != ty.t.shape or not np.array_equal(tx.t, ty.t):
            from flexarm_ros.analysis.spectra import resample
            lo, hi = max(tx.t[0], ty.t[0]), min(tx.t[-1], ty.t[-1])
            t = tx.t[(tx.t >= lo) & (tx.t <= hi)]
            if t.size < 2:
                return "tip_x and tip_y do not overlap in time"
            x, y = resample(tx.t, tx.y, t), resample(ty.t, ty.y, t)
        else:
            t, x, y = tx.t, tx.y, ty.y
        how = "derived: distance of (tip_x, tip_y) to the wall line(s)"
    gaps = []
    for w in scene.walls:
        n = np.asarray(w.normal, float)
        n = n / np.linalg.norm(n)
        gaps.append((x - w.point[0]) * n[0] + (y - w.point[1]) * n[1])
    channels["wall_gap"] = Channel("wall_gap", "m", t, np.min(gaps, axis=0), how)
    return None


def _tool_path(channels: dict[str, Channel], scene):
    """``(t, x, y)`` of the tool point offset from the last tip body, from the coordinate
    channels through the scene's kinematics, or why not (a string)."""
    where = f"the tool point sits at {list(scene.tool.position)} m from the tip body"
    from flexarm_ros.model import Chain
    try:
        chain = Chain(scene, backend="numpy")
    except Exception as exc:            # noqa: BLE001 - a scene the model refuses
        return f"{where} and the scene's model does not build ({exc})"
    names = list(chain.names)
    missing = [n for n in names if n not in channels]
    if missing:
        return f"{where}, not at the recorded tip, and the coordinates {missing} are missing"
    t = channels[names[0]].t
    if any(channels[n].t.shape != t.shape or not np.array_equal(channels[n].t, t)
           for n in names):
        return f"{where}, not at the recorded tip, and the coordinates are not on one time base"
    Q = np.column_stack([channels[n].y for n in names])
    try:                      # the compiled kernel's frames when it builds (one pass)
        chain = Chain(scene)
    except Exception:         # noqa: BLE001 - the numpy model above does
        pass
    xy = chain.tool_points(t, Q, np.zeros_like(Q), np.zeros((len(t), chain.nz)))
    return t, xy[:, 0], xy[:, 1]


# ----------------------------------------------------------------------------- mapped bags

def _field(msg, path: str):
    value = msg
    for part in path.split("."):
        if isinstance(value, dict):
            if part not in value:
                raise KeyError(part)
            value = value[part]
        elif re.fullmatch(r"\d+", part) and isinstance(value, (list, tuple)):
            value = value[int(part)]
        else:
            if not hasattr(value, part):
                raise KeyError(part)
            value = getattr(value, part)
    return value


def _map_entry(bag, cmap: ChannelMap, e: MapEntry):
    """``(t_ns, values)`` of one map entry (int64 ns, scaled floats)."""
    where = f"map {cmap.path}, channels.{e.name}"
    if e.topic not in bag.messages:
        have = ", ".join(sorted(bag.messages)) or "none"
        raise CompareInputError(f"{bag.path}: topic {e.topic!r} ({where}) is not in the "
                                f"bag; topics present: {have}")
    messages = bag.messages[e.topic]
    if not messages:
        raise CompareInputError(f"{bag.path}: topic {e.topic!r} ({where}) has no messages")
    ts, ys = [], []
    for log_ns, msg in messages:
        if isinstance(msg, (bytes, bytearray)):
            raise CompareInputError(f"{bag.path}: topic {e.topic!r} ({where}) is not CDR "
                                    f"encoded; expected ROS 2 messages")
        try:
            value = _field(msg, e.field)
        except (KeyError, IndexError):
            raise CompareInputError(
                f"{bag.path}: topic {e.topic!r} ({bag.types.get(e.topic, '?')}) has no "
                f"field {e.field!r} ({where})") from None
        if e.time == "header":
            try:
                st = msg.header.stamp
                t_ns = int(st.sec) * 1_000_000_000 + int(st.nanosec)
            except AttributeError:
                raise CompareInputError(f"{bag.path}: topic {e.topic!r} ({where}) has no "
                                        f"header.stamp; use time: log") from None
        else:
            t_ns = log_ns
        if e.rate_hz is not None:
            data = np.asarray(value, dtype=float).ravel()
            try:        # explicit 'columns': plain rows; else the message's layout
                lay = recording.batch_layout(None if e.columns else getattr(msg, "layout", None),
                                            data.size, e.columns,
                                            where=f"{bag.path}: topic {e.topic!r} ({where}) "
                                                  f"at {log_ns} ns")
            except BagError as exc:
                raise CompareInputError(str(exc)) from None
            col = e.index or 0
            if col >= lay.channels:
                raise CompareInputError(f"{bag.path}: {where}: index {col} with "
                                        f"{lay.channels} columns per row; expected an index "
                                        f"< {lay.channels}")
            if lay.samples:
                ts.append(recording.batch_times_ns(t_ns, lay.samples, e.rate_hz))
                ys.append(data[lay.offset + lay.stride * np.arange(lay.samples) + col])
            continue
        if e.index is not None:
            try:
                value = value[e.index]
            except (IndexError, TypeError, KeyError):
                raise CompareInputError(
                    f"{bag.path}: topic {e.topic!r} ({where}): field {e.field!r} has no "
                    f"element {e.index}") from None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise CompareInputError(
                f"{bag.path}: topic {e.topic!r} ({where}): field {e.field!r} is "
                f"{type(value).__name__}, expected a number (give 'index' for an array "
                f"element)") from None
        ts.append(np.array([t_ns], dtype=np.int64))
        ys.append(np.array([v]))
    t_ns, y = np.concatenate(ts), np.concatenate(ys)
    if not np.any(np.isfinite(y)):
        raise CompareInputError(f"{bag.path}: topic {e.topic!r} ({where}) has no finite "
                                f"values")
    return t_ns, e.scale * y + e.offset


def mapped_bag_channels(bag, cmap: ChannelMap) -> dict[str, Channel]:
    """The channels a map file names in a (foreign) bag: ``value = scale * raw + offset``
    at the message log time (or header stamp); ``time_origin: first`` counts time from the
    earliest mapped sample (in integer nanoseconds, so epoch stamps keep their precision).
    """
    entries = cmap.topic_entries
    if not entries:
        raise CompareInputError(f"{cmap.path}: no channel with a 'topic'; an MCAP input "
                                f"needs topic/field entries")
    raw = {e.name: (e, *_map_entry(bag, cmap, e)) for e in entries}
    t0 = min(int(t.min()) for _, t, _ in raw.values()) if cmap.time_origin == "first" else 0
    out = {}
    for name, (e, t_ns, y) in raw.items():
        ch = _channel(name, e.unit, (t_ns - t0) * 1e-9, y,
                      f"{e.topic} {e.field}" + ("" if e.index is None else f"[{e.index}]"))
        if ch is not None:
            out[name] = ch
    return out


def _vibration_name(name: str) -> bool:
    """A channel whose frequency is a criterion, by its name: the tip position and the
    elastic beam coordinates (:func:`flexarm_ros.io.units.beam_coordinate`)."""
    return name in ("tip_x", "tip_y") or beam_coordinate(name)


def _table_channels(path, columns, cmap: ChannelMap | None) -> dict[str, Channel]:
    renames = {} if cmap is None else {e.column: e for e in cmap.column_entries}
    if cmap is not None:
        missing = [c for c in renames if c not in columns]
        if missing:
            raise CompareInputError(f"{path}: no column {missing[0]!r} (map {cmap.path}, "
                                    f"channels.{renames[missing[0]].name}); columns: "
                                    f"{', '.join(columns)}")
    out = {}
    labels = {}
    for col, (unit, t, y) in columns.items():
        e = renames.get(col)
        if unit == TEXT:
            if e is not None:
                raise CompareInputError(f"{path}: column {col!r} holds text (unit [text]); "
                                        f"map {cmap.path}, channels.{e.name} expects numbers")
            labels[col] = (t, y)
            continue
        if e is None:
            ch = _channel(col, unit, t, y, f"column {col!r}", _vibration_name(col))
        else:
            ch = _channel(e.name, e.unit or unit, t, e.scale * y + e.offset,
                          f"column {col!r} x {e.scale:g} + {e.offset:g}",
                          _vibration_name(e.name))
        if ch is not None:
            if ch.name in out:
                raise CompareInputError(f"{path}: two columns give the channel {ch.name!r}")
            out[ch.name] = ch
    if "contact_phase" in labels and "contact" not in out:
        t, phase = labels["contact_phase"]
        ch = _channel("contact", "1", t, (phase != "free").astype(float),
                      "column 'contact_phase' (1 unless 'free')")
        if ch is not None:
            out["contact"] = ch
    return out


# ----------------------------------------------------------------------------- loading

_SENSOR_TABLE = re.compile(r"\.sensors_[0-9.]+hz\.csv$")


def sensor_tables_beside(path) -> list[Path]:
    """The sensor tables ``flexarm simulate --out run.csv`` writes next to its main table
    (``run.sensors_<rate>hz.csv``), so that the run reads as one record: its declared
    sensors (``acc_A``, ``enc1``, ``acc_A_true``, …) beside the main columns. None for a
    file that is itself a sensor table."""
    p = Path(path)
    if _SENSOR_TABLE.search(p.name):
        return []
    return sorted(p.parent.glob(f"{glob.escape(p.stem)}.sensors_*hz.csv"))


def load_channels(path, channel_map: ChannelMap | None = None) -> ChannelSet:
    """Read ``path`` (``.csv`` by the CSV convention, anything else as MCAP) into a
    :class:`ChannelSet`. A twin bag gives the channels of :func:`bag_channels` (a map, if
    given, replaces them); a foreign bag needs ``channel_map``. A truncated or damaged bag
    is read up to the damage: the :class:`~flexarm_ros.bag.reader.TruncatedBagWarning` is
    re-issued and its text kept in ``ChannelSet.warnings``.

    Raises:
        CompareInputError: missing file, unreadable/empty bag, CSV or map problem, no
            channel found.
    """
    p = str(path)
    if not Path(p).exists():
        raise CompareInputError(f"{p}: no such file, expected an MCAP bag or a CSV file")
    if Path(p).suffix.lower() == ".csv":
        columns, comments = read_experiment_csv(p)
        cs = ChannelSet(path=p, kind="csv", comments=comments)
        cs.channels = _table_channels(p, columns, channel_map)
        if channel_map is None:
            for side in sensor_tables_beside(p):
                more, _ = read_experiment_csv(side)
                for name, ch in _table_channels(str(side), more, None).items():
                    cs.channels.setdefault(name, ch)
                cs.comments.append(f"sensor channels from {side.name}")
        return cs
    return load_bag(p, channel_map)[0]


def load_bag(path, channel_map: ChannelMap | None = None,
             foreign_hint: str = "pass a channel map (--map MAP.yaml) that names its "
                                 "topics"):
    """``(ChannelSet, Bag)`` of an MCAP bag: the channels :func:`load_channels` gives (a
    twin bag's, or a map's), and the decoded bag they came from (for the tools that need
    its topics and tick times besides the channels, e.g. ``flexarm bag export``).
    ``foreign_hint`` completes the error for a bag the twin did not record.

    Raises:
        CompareInputError: unreadable or empty bag, a foreign bag without a map, no
            channel found.
    """
    p = str(path)
    if not Path(p).exists():
        raise CompareInputError(f"{p}: no such file, expected an MCAP bag")
    caught = []
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        try:
            bag = read_bag(p)
        except BagError as exc:
            raise CompareInputError(str(exc)) from None
        except OSError as exc:
            raise CompareInputError(f"{p}: cannot read ({exc})") from None
        caught = list(rec)
    cs = ChannelSet(path=p, kind="mcap", truncated=bag.truncated)
    for w in caught:
        if issubclass(w.category, TruncatedBagWarning):
            cs.warnings.append(str(w.message))
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if bag.message_count == 0:
        raise CompareInputError(
            f"{p}: the bag holds no messages{' (it is truncated)' if bag.truncated else ''}"
            f"; expected a recording (flexarm run --record, or a foreign bag with --map)")
    meta = recording.twin_info(bag)
    if meta is not None:
        cs.scene_name = meta.get("scene")
        cs.scene, why = scene_of_bag(bag)
        if why:
            cs.warnings.append(f"{p}: {why}; sensor channels get generic names")
    if channel_map is not None:
        cs.channels = mapped_bag_channels(bag, channel_map)
    elif meta is None:
        raise CompareInputError(f"{p}: not recorded by flexarm run (no flexarm_ros "
                                f"metadata); {foreign_hint}")
    else:
        try:
            cs.channels = bag_channels(bag, cs.scene, cs.warnings)
        except BagError as exc:
            raise CompareInputError(str(exc)) from None
        add_wall_gap(cs.channels, cs.scene)
    if not cs.channels:
        raise CompareInputError(
            f"{p}: no channel found (the bag holds {bag.message_count} messages"
            f"{'; it is truncated' if bag.truncated else ''}); expected the twin's topics "
            f"under {recording.namespace(bag) if meta is not None else 'the map'}")
    return cs, bag
