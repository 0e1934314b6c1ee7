"""``flexarm bag export BAG.mcap --out run.csv [--topics T ...] [--json]``: a twin bag's
channels as ``name [unit]`` CSV tables that ``flexarm compare`` and ``flexarm calibrate``
read (the convention of :mod:`flexarm_ros.io.experiment`).

The channels are exactly the ones ``flexarm compare`` reads from the bag
(:func:`flexarm_ros.analysis.channels.load_bag`: one code path, the table in
docs/compare.md), written as ``flexarm simulate --out`` lays out a run:

* **the main table** ``run.csv`` on one time base, the bag's control ticks: the log times of
  ``ground_truth/joint_states`` (published every tick in every mode; else
  ``joint_states``, ``ground_truth/coordinates``, ``/clock``, the first the bag has). A
  channel sampled at those instants is copied (``exact``); any other is resampled onto
  them: a command, target, count or 0/1 flag (held values: ``<link>_command``,
  ``*_target``, ``tip_target_x``/``_y``, unit ``count``, ``contact``) takes its last
  sample at or before the tick (``previous``), a continuous signal is interpolated
  linearly (``linear``; the ground truth at a lower rate in realtime). Ticks before a
  channel's first or after its last sample are empty cells (no extrapolation); rows with
  no value at all are left out. The derived ``wall_gap`` is a column like the others
  (without ``--topics``).
* **one sensor table per sample rate** ``run.sensors_<rate>hz.csv`` (the name ``flexarm
  simulate`` gives its sensor tables, :func:`flexarm_ros.io.tables.sensor_table_path`):
  the batch topics (``accelerometers/batch``, ``strain/batch``, ``potentiometer/batch``)
  expanded to one row per sample (row i of n logged at t is the sample at
  t - (n - 1 - i) / rate), at their own instants, not resampled. ``flexarm compare
  run.csv`` reads them with the main table.

Values and times are written as the shortest decimal that reads back as the same double
(Python's ``repr``): read back, they equal the bag's messages bit for bit (log times in
ns → s as ``flexarm compare`` computes them).
A channel whose unit the bag does not tell (a sensor without a scene) is written
``[unknown]`` (it then matches any unit in ``flexarm compare``).

Bad input (exit status 2, one line naming the key, the value and the expectation): a
missing file, a file that is not MCAP, a bag the twin did not record, a ``--topics`` entry
that is not in the bag or gives no channel, an ``--out`` that is not a writable ``.csv``
path.
"""

from __future__ import annotations

import json
import sys
import warnings as _w
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm_ros.analysis.channels import Channel, load_bag
from flexarm_ros.analysis.metrics import is_boolean
from flexarm_ros.twin import recording
from flexarm_ros.io.experiment import CompareInputError, write_experiment_csv
from flexarm_ros.io.tables import sensor_table_path
from flexarm_ros.twin import topics as T

__all__ = ["TICK_TOPICS", "ExportReport", "cli", "export_bag"]

#: Where the time base of the main table comes from: the first of these topics (relative to
#: the bag's namespace) that has messages.
TICK_TOPICS = (T.GT_JOINT_STATES, T.JOINT_STATES, T.GT_COORDINATES, T.CLOCK)
#: The unit written for a channel whose unit the bag does not tell.
UNKNOWN_UNIT = "unknown"
#: Numbers as the shortest text that reads back as the same float (Python's repr).
FMT = "%r"


@dataclass
class ExportReport:
    """What :func:`export_bag` wrote (``as_dict`` is the ``--json`` document)."""

    bag: str
    scene: str | None
    out: str
    time_base: dict
    rows: int
    columns: dict
    sensor_tables: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"bag": self.bag, "scene": self.scene, "out": self.out,
                "time_base": self.time_base, "rows": self.rows, "columns": self.columns,
                "sensor_tables": self.sensor_tables, "warnings": self.warnings}

    def text(self) -> str:
        how = {}
        for c in self.columns.values():
            how[c["resampling"]] = how.get(c["resampling"], 0) + 1
        lines = [f"{self.bag} → {self.out}: {self.rows} rows × {len(self.columns)} columns "
                 f"on the ticks of {self.time_base['topic']} ("
                 + ", ".join(f"{n} {k}" for k, n in sorted(how.items())) + ")"]
        for rate, tab in self.sensor_tables.items():
            lines.append(f"  sensors at {rate} Hz → {tab['path']} ({tab['rows']} rows: "
                         f"{', '.join(tab['columns'])})")
        return "\n".join(lines)


def _held(name: str, ch: Channel) -> bool:
    """A channel whose value is held between samples (a command, a target, a count, a
    flag): resampled by its previous sample, never interpolated."""
    return (name.endswith(("_command", "_target")) or name.startswith("tip_target_")
            or ch.unit == "count" or (ch.unit == "1" and is_boolean(ch.y)))


def _on_base(name: str, ch: Channel, base: np.ndarray) -> tuple[np.ndarray, str]:
    """``(values on the base instants (NaN outside the channel's span), method)``."""
    y = np.full(base.shape, np.nan)
    inside = (base >= ch.t[0]) & (base <= ch.t[-1])
    idx = np.searchsorted(ch.t, base[inside])
    idx = np.minimum(idx, ch.t.size - 1)
    tb = base[inside]
    if np.array_equal(ch.t[idx], tb) and ch.t.size == np.count_nonzero(inside):
        y[inside] = ch.y[idx]
        return y, "exact"
    if _held(name, ch):
        prev = np.searchsorted(ch.t, tb, side="right") - 1
        y[inside] = ch.y[prev]
        return y, "previous"
    y[inside] = np.interp(tb, ch.t, ch.y)
    return y, "linear"


def _rate_of(name: str, ch: Channel, scene) -> float:
    """The sample rate of a sensor channel: the scene's sensor of that name, else 1 / the
    median spacing of its samples (rounded to 6 significant digits)."""
    for s in (scene.sensors if scene is not None else ()):
        if s.name == name:
            return float(s.rate_hz)
    return float(f"{1.0 / float(np.median(np.diff(ch.t))):.6g}") if ch.t.size > 1 else 0.0


def _select_topics(bag, ns: str, topics, channels: dict) -> set | None:
    """The absolute topics of ``--topics`` (each relative to the bag's namespace or
    absolute), checked against the bag; None = every topic."""
    if not topics:
        return None
    have = {ch.topic for ch in channels.values() if ch.topic}
    out = set()
    for t in topics:
        a = T.resolve(ns, t)
        if a not in bag.types:
            raise CompareInputError(f"--topics: got {t!r}, expected a topic of {bag.path} "
                                    f"(absolute, or relative to its namespace {ns}): "
                                    f"{', '.join(sorted(have))}")
        if a not in have:
            raise CompareInputError(f"--topics: got {t!r}: {a} gives no channel (no "
                                    f"numbers flexarm compare reads), expected one of "
                                    f"{', '.join(sorted(have))}")
        out.add(a)
    return out


def export_bag(bag_path, out, topics=None) -> ExportReport:
    """Write the channels of the twin bag ``bag_path`` to ``out`` (.csv) and its sensor
    tables beside it (module docstring); ``topics``: only the channels of these topics.

    Raises:
        CompareInputError: bad input (module docstring); an InputError for ``--out``.
    """
    from flexarm_ros.io.paths import check_output_file
    out = check_output_file("--out", out, (".csv",))
    p = str(bag_path)
    if not Path(p).exists():
        raise CompareInputError(f"{p}: no such file, expected an MCAP bag (flexarm run "
                                f"--record)")
    if Path(p).suffix.lower() == ".csv":
        raise CompareInputError(f"{p}: a CSV table, expected an MCAP bag (flexarm run "
                                f"--record) to export")
    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        cs, bag = load_bag(p, foreign_hint="expected a bag recorded by flexarm run (the "
                                           "twin's topics are what flexarm bag export "
                                           "writes)")
    warn = list(cs.warnings) + [str(w.message) for w in caught
                                if str(w.message) not in cs.warnings]
    ns = recording.namespace(bag)
    chosen = _select_topics(bag, ns, topics, cs.channels)
    batch = {T.resolve(ns, k) for k in T.BATCH_KINDS}
    main, sensors = {}, {}
    for name, ch in cs.channels.items():
        if chosen is not None and ch.topic not in chosen:
            continue                      # with --topics: no derived channel either
        (sensors if ch.topic in batch else main)[name] = ch
    tick = next((T.resolve(ns, k) for k in TICK_TOPICS
                 if bag.messages.get(T.resolve(ns, k))), None)
    if tick is not None:
        base = np.unique(np.array([m[0] for m in bag.messages[tick]], dtype=np.int64)) * 1e-9
    else:
        base = np.unique(np.concatenate([ch.t for ch in main.values()])) if main else \
            np.zeros(0)
        tick = "the union of the channels' sample times"
    columns, info = {}, {}
    for name, ch in main.items():
        y, how = _on_base(name, ch, base)
        ok = ~np.isnan(y)
        columns[name] = (ch.unit or UNKNOWN_UNIT, base[ok], y[ok])
        info[name] = {"unit": ch.unit or UNKNOWN_UNIT, "topic": ch.topic or None,
                      "source": ch.source, "samples": int(ok.sum()), "resampling": how}
    scene_note = f" (scene {cs.scene_name})" if cs.scene_name else ""
    head = [f"Exported from {Path(p).name}{scene_note} by flexarm bag export.",
            f"Time base: the log times of {tick}; channels at other instants resampled "
            f"(held values: previous sample; others: linear); no extrapolation."]
    rows = 0
    if columns:
        write_experiment_csv(out, columns, comments=head, fmt=FMT, time_fmt=FMT)
        rows = int(np.unique(np.concatenate([c[1] for c in columns.values()])).size)
    else:
        warn.append(f"no channel of the main table selected; {out} not written")
    tables = {}
    by_rate: dict = {}
    for name, ch in sensors.items():
        by_rate.setdefault(_rate_of(name, ch, cs.scene), {})[name] = ch
    for rate, chans in sorted(by_rate.items()):
        path = sensor_table_path(out, rate)
        cols = {n: (ch.unit or UNKNOWN_UNIT, ch.t, ch.y) for n, ch in chans.items()}
        write_experiment_csv(path, cols, comments=[
            f"Exported from {Path(p).name}{scene_note} by flexarm bag export: the sensors "
            f"at {rate:g} Hz, one row per sample of their batches (not resampled)."],
            fmt=FMT, time_fmt=FMT)
        tables[f"{rate:g}"] = {
            "path": str(path), "columns": list(chans),
            "rows": int(np.unique(np.concatenate([ch.t for ch in chans.values()])).size),
            "topics": sorted({ch.topic for ch in chans.values()})}
        for n, ch in chans.items():
            info[n] = {"unit": ch.unit or UNKNOWN_UNIT, "topic": ch.topic, "source": ch.source,
                       "samples": int(ch.t.size), "resampling": f"own ({rate:g} Hz table)"}
    written = {Path(t["path"]).name for t in tables.values()}
    stale = sorted(q.name for q in out.parent.glob(f"{out.stem}.sensors_*hz.csv")
                   if q.name not in written)
    if stale:
        warn.append(f"{', '.join(stale)} beside {out} is not from this export: flexarm "
                    f"compare reads it with {out.name} (remove it, or choose another --out)")
    tb = {"topic": tick, "rows": int(base.size),
          "start_s": float(base[0]) if base.size else None,
          "end_s": float(base[-1]) if base.size else None}
    return ExportReport(bag=p, scene=cs.scene_name, out=str(out), time_base=tb, rows=rows,
                        columns={k: v for k, v in info.items() if k in main}
                        | {k: v for k, v in info.items() if k in sensors},
                        sensor_tables=tables, warnings=warn)


def cli(args) -> int:
    """``flexarm bag export`` (options parsed in :mod:`flexarm_ros.commands.bag`): 0
    written; bad input raises :class:`~flexarm_ros.io.experiment.CompareInputError` (exit
    status 2)."""
    topics = None
    if args.topics:
        topics = [t.strip() for item in args.topics for t in item.split(",") if t.strip()]
    rep = export_bag(args.bag, args.out, topics)
    for w in rep.warnings:
        print(f"flexarm bag export: warning: {w}", file=sys.stderr)
    print(json.dumps(rep.as_dict(), indent=2) if args.json else rep.text())
    return 0
