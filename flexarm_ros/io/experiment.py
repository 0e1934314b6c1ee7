"""Experiment records for ``flexarm compare``: the CSV convention and the channel map file.

CSV convention
--------------
* Lines starting with ``#`` are comments (anywhere; the leading ones are kept as the
  file's description); blank lines are skipped.
* The first other line is the header, comma separated. Its first column is the time,
  written exactly ``t [s]``; every other column is ``name [unit]``: a channel name and its
  unit in square brackets (``acc_A [V]``, ``tip_x [m]``, ``contact [1]``; ``[1]`` for a
  dimensionless quantity). A column without a unit is refused: the channel would be
  compared with a number in an unknown unit.
* Every following line holds numbers, one per column. The time column must be strictly
  increasing. An empty cell means "no sample of this channel at this time", so channels
  sampled at different rates share one file (a 4 kHz accelerometer and a 1 kHz tip
  position: the tip cells are empty on three rows out of four).
* A column with the unit ``[text]`` holds labels, not numbers (``flexarm simulate``'s
  ``contact_phase [text]``: free / impact / sliding / sticking); it is read as text.

Channel map file (YAML)
-----------------------
Names the channels of a foreign MCAP bag, or renames and rescales CSV columns::

    time_origin: absolute        # or 'first': count time from the earliest mapped sample
    channels:
      acc_A:                     # channel name, as the twin calls it
        topic: /daq/accel        # MCAP topic ...
        field: data              # ... dotted field path in the decoded message
        index: 0                 # element of an array field (optional)
        unit: V                  # unit after scaling (required for topics)
        scale: 1.0               # value = scale * raw + offset (optional: 1, 0)
        offset: 0.0
        time: log                # 'log' (message log time, default) or 'header'
        rate_hz: 4000            # optional: the field holds rows of samples at this rate
        columns: 4               #   with this many values per row (default: the layout)
      tip_x: {column: x_cam, unit: m, scale: 0.001}   # a CSV column 'x_cam [mm]' -> m

With ``rate_hz`` the field is a batch laid out [sample, channel] (the twin's
``accelerometers/batch`` layout): ``columns`` values per row, ``index`` the column, rows
spaced ``1 / rate_hz`` with the last at the message time. Loading a map validates its
keys; every problem raises :class:`CompareInputError` naming the file, key and
expectation.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.io.units import TEXT as TEXT_UNIT
from flexarm_ros.scene.yaml_input import load_yaml

__all__ = [
    "CompareInputError",
    "ChannelMap",
    "MapEntry",
    "TEXT_UNIT",
    "TIME_HEADER",
    "load_channel_map",
    "read_experiment_csv",
    "write_experiment_csv",
]

#: The required header of the first CSV column.
TIME_HEADER = "t [s]"
_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]*?)\s*\[(?P<unit>[^\[\]]*)\]\s*$")


class CompareInputError(InputError):
    """An input of ``flexarm compare`` (bag, CSV, map, option) is unusable; the message
    names the file, the column / channel / key, the value and the expectation. A
    :class:`~flexarm_ros.errors.InputError`, so the CLI exits with status 2."""


# ------------------------------------------------------------------------------ CSV

def _split_header(path: str, col: int, text: str) -> tuple[str, str]:
    m = _HEADER.match(text)
    if m is None:
        raise CompareInputError(
            f"{path}: column {col} header {text.strip()!r} has no unit; expected "
            f"'name [unit]', e.g. 'acc_A [V]' (write [1] for a dimensionless quantity)")
    name, unit = m.group("name").strip(), m.group("unit").strip()
    if not name:
        raise CompareInputError(f"{path}: column {col} header {text.strip()!r} has no "
                                f"name; expected 'name [unit]'")
    if not unit:
        raise CompareInputError(
            f"{path}: column {col} header {text.strip()!r} has an empty unit; expected "
            f"'name [unit]' (write [1] for a dimensionless quantity)")
    return name, unit


def read_experiment_csv(path) -> tuple[dict[str, tuple[str, np.ndarray, np.ndarray]], list[str]]:
    """Read a CSV written to the convention above.

    Returns:
        ``(columns, comments)``: ``columns[name] = (unit, t, y)`` with only the rows where
        the cell is not empty (so each channel keeps its own sample times), in file order
        (``y`` floats; a ``[text]`` column's ``y`` its labels, a ``str`` array);
        ``comments`` the text of the ``#`` lines before the header.

    Raises:
        CompareInputError: missing/unreadable file, no header, a header without a unit,
            a first column other than ``t [s]``, duplicate names, a non-numeric or
            non-finite cell, a time column that is not strictly increasing, no data.
    """
    p = str(path)
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except FileNotFoundError:
        raise CompareInputError(f"{p}: no such file, expected a CSV file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CompareInputError(f"{p}: cannot read the CSV file ({exc})") from None
    comments: list[str] = []
    header = None
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(lines, 1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if header is None:
                comments.append(stripped[1:].strip())
            continue
        cells = next(csv.reader([line]))
        if header is None:
            header = (lineno, cells)
        else:
            rows.append((lineno, cells))
    if header is None:
        raise CompareInputError(f"{p}: empty CSV (no header line); expected a header "
                                f"'{TIME_HEADER},name [unit],...'")
    hline, hcells = header
    if len(hcells) < 2:
        raise CompareInputError(f"{p}: line {hline}: header has {len(hcells)} column(s); "
                                f"expected '{TIME_HEADER}' and at least one channel")
    tname, tunit = _split_header(p, 1, hcells[0])
    if tname != "t" or tunit != "s":
        raise CompareInputError(f"{p}: column 1 header {hcells[0].strip()!r}: expected the "
                                f"time column '{TIME_HEADER}' first")
    names, units = [], []
    for j, cell in enumerate(hcells[1:], 2):
        name, unit = _split_header(p, j, cell)
        if name in names or name == "t":
            raise CompareInputError(f"{p}: column {j} repeats the name {name!r}; expected "
                                    f"unique channel names")
        names.append(name)
        units.append(unit)
    if not rows:
        raise CompareInputError(f"{p}: no data rows after the header (line {hline})")
    ncol = len(hcells)
    data = np.full((len(rows), ncol), np.nan)
    text = {j: [""] * len(rows) for j, u in enumerate(units, 1) if u == TEXT_UNIT}
    for i, (lineno, cells) in enumerate(rows):
        if len(cells) != ncol:
            raise CompareInputError(f"{p}: line {lineno} has {len(cells)} cells; expected "
                                    f"{ncol} (as the header)")
        for j, cell in enumerate(cells):
            c = cell.strip()
            if not c:
                if j == 0:
                    raise CompareInputError(f"{p}: line {lineno}: empty time cell; expected "
                                            f"a time in s")
                continue
            if j in text:
                text[j][i] = c
                continue
            try:
                v = float(c)
            except ValueError:
                raise CompareInputError(
                    f"{p}: line {lineno}, column {j + 1} ({hcells[j].strip()!r}): got "
                    f"{c!r}, expected a number") from None
            if not math.isfinite(v):
                raise CompareInputError(
                    f"{p}: line {lineno}, column {j + 1} ({hcells[j].strip()!r}): got "
                    f"{c!r}, expected a finite number (leave the cell empty for no sample)")
            data[i, j] = v
    t = data[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise CompareInputError(f"{p}: line {rows[i][0]}: time {t[i]:.10g} s after "
                                f"{t[i - 1]:.10g} s; expected strictly increasing times")
    out = {}
    for j, (name, unit) in enumerate(zip(names, units), 1):
        if j in text:
            labels = np.array(text[j], dtype=str)
            have = labels != ""
            out[name] = (unit, t[have].copy(), labels[have])
            continue
        have = ~np.isnan(data[:, j])
        out[name] = (unit, t[have].copy(), data[have, j].copy())
    return out, comments


def write_experiment_csv(path, columns: dict, comments=(), fmt: str = "%.17g",
                         time_fmt: str = "%.17g") -> Path:
    """Write channels to the CSV convention (the inverse of :func:`read_experiment_csv`).

    ``columns[name] = (unit, t, y)`` (``y`` labels for the unit ``text``); the rows are the
    union of every channel's times (compared exactly), cells without a sample (or NaN)
    left empty. ``comments`` become ``# ``
    lines before the header. ``fmt`` formats the values, ``time_fmt`` the times (the
    default ``%.17g`` round-trips a float exactly).
    """
    path = Path(path)
    times = np.unique(np.concatenate([np.asarray(c[1], float) for c in columns.values()]))
    cells = [[""] * len(columns) for _ in times]
    for j, (unit, t, y) in enumerate(columns.values()):
        idx = np.searchsorted(times, np.asarray(t, float))
        for i, v in zip(idx, y):
            cells[i][j] = (str(v) if unit == TEXT_UNIT else
                           "" if math.isnan(float(v)) else fmt % float(v))
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        for line in comments:
            fh.write(f"# {line}".rstrip() + "\n")
        fh.write(",".join([TIME_HEADER] + [f"{n} [{c[0]}]" for n, c in columns.items()])
                 + "\n")
        for ti, row in zip(times, cells):
            fh.write(",".join([time_fmt % float(ti)] + row) + "\n")
    tmp.replace(path)
    return path


# ------------------------------------------------------------------------------ map

@dataclass(frozen=True)
class MapEntry:
    """One channel of a map file (see the module docstring for the keys)."""

    name: str
    unit: str | None = None
    topic: str | None = None
    field: str | None = None
    index: int | None = None
    column: str | None = None
    scale: float = 1.0
    offset: float = 0.0
    time: str = "log"
    rate_hz: float | None = None
    columns: int | None = None


@dataclass(frozen=True)
class ChannelMap:
    """A parsed channel map file."""

    path: str
    entries: tuple[MapEntry, ...]
    time_origin: str = "absolute"

    @property
    def topic_entries(self) -> tuple[MapEntry, ...]:
        return tuple(e for e in self.entries if e.topic is not None)

    @property
    def column_entries(self) -> tuple[MapEntry, ...]:
        return tuple(e for e in self.entries if e.column is not None)


_ENTRY_KEYS = {"topic", "field", "index", "column", "unit", "scale", "offset", "time",
               "rate_hz", "columns"}


def _number(p, where, value, *, positive=False, integer=False):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(float(value))
    if ok and integer:
        ok = float(value) == int(value) and value >= 0
    if ok and positive:
        ok = value > 0
    if not ok:
        what = ("a positive integer" if integer and positive else
                "a non-negative integer" if integer else
                "a positive finite number" if positive else "a finite number")
        raise CompareInputError(f"{p}: {where}: got {value!r}, expected {what}")
    return int(value) if integer else float(value)


def load_channel_map(path) -> ChannelMap:
    """Parse and validate a channel map YAML file (format in the module docstring)."""
    from flexarm_ros.scene.yaml_input import read_yaml_text
    p = str(path)
    try:
        text = read_yaml_text(p, "map file")
    except InputError as exc:
        raise CompareInputError(str(exc)) from None
    try:
        data = load_yaml(text, str(p))       # bounded: depth, alias expansion, duplicates
    except InputError as exc:
        raise CompareInputError(str(exc)) from None
    if not isinstance(data, dict) or not isinstance(data.get("channels"), dict) \
            or not data["channels"]:
        raise CompareInputError(f"{p}: channels: missing or empty; expected a mapping "
                                f"'channels: {{name: {{topic: ..., field: ..., unit: ...}}}}'")
    extra = set(data) - {"channels", "time_origin"}
    if extra:
        raise CompareInputError(f"{p}: unknown top-level key(s) {sorted(extra)}; expected "
                                f"'channels' and optionally 'time_origin'")
    origin = data.get("time_origin", "absolute")
    if origin not in ("absolute", "first"):
        raise CompareInputError(f"{p}: time_origin: got {origin!r}, expected 'absolute' or "
                                f"'first'")
    entries = []
    for name, spec in data["channels"].items():
        where = f"channels.{name}"
        if not isinstance(name, str) or not name.strip():
            raise CompareInputError(f"{p}: channels: got the name {name!r}, expected a "
                                    f"non-empty string")
        if not isinstance(spec, dict):
            raise CompareInputError(f"{p}: {where}: got {spec!r}, expected a mapping with "
                                    f"'topic' and 'field' (MCAP) or 'column' (CSV)")
        unknown = set(spec) - _ENTRY_KEYS
        if unknown:
            raise CompareInputError(f"{p}: {where}: unknown key(s) {sorted(unknown)}; "
                                    f"expected some of {sorted(_ENTRY_KEYS)}")
        topic, column = spec.get("topic"), spec.get("column")
        if (topic is None) == (column is None):
            raise CompareInputError(f"{p}: {where}: expected exactly one of 'topic' (a bag "
                                    f"topic with 'field') or 'column' (a CSV column name)")
        unit = spec.get("unit")
        if unit is not None and (not isinstance(unit, str) or not unit.strip()):
            raise CompareInputError(f"{p}: {where}.unit: got {unit!r}, expected a unit such "
                                    f"as 'V', 'm', 'rad' or '1'")
        if topic is not None:
            if not isinstance(topic, str) or not topic:
                raise CompareInputError(f"{p}: {where}.topic: got {topic!r}, expected a "
                                        f"topic name")
            fld = spec.get("field")
            if not isinstance(fld, str) or not fld.strip():
                raise CompareInputError(f"{p}: {where}.field: got {fld!r}, expected a dotted "
                                        f"field path such as 'point.x' or 'data'")
            if unit is None:
                raise CompareInputError(f"{p}: {where}.unit: missing; expected the unit of "
                                        f"the (scaled) values, e.g. 'V' or 'm'")
        else:
            if not isinstance(column, str) or not column.strip():
                raise CompareInputError(f"{p}: {where}.column: got {column!r}, expected a "
                                        f"CSV column name (without its unit)")
            for k in ("field", "index", "time", "rate_hz", "columns"):
                if k in spec:
                    raise CompareInputError(f"{p}: {where}.{k}: only for 'topic' entries; "
                                            f"a CSV column takes column, unit, scale, offset")
        time = spec.get("time", "log")
        if time not in ("log", "header"):
            raise CompareInputError(f"{p}: {where}.time: got {time!r}, expected 'log' or "
                                    f"'header'")
        index = spec.get("index")
        entries.append(MapEntry(
            name=name.strip(), unit=None if unit is None else unit.strip(),
            topic=topic, field=spec.get("field"), column=column,
            index=None if index is None else _number(p, f"{where}.index", index,
                                                     integer=True),
            scale=_number(p, f"{where}.scale", spec.get("scale", 1.0)),
            offset=_number(p, f"{where}.offset", spec.get("offset", 0.0)),
            time=time,
            rate_hz=(None if spec.get("rate_hz") is None else
                     _number(p, f"{where}.rate_hz", spec["rate_hz"], positive=True)),
            columns=(None if spec.get("columns") is None else
                     _number(p, f"{where}.columns", spec["columns"], integer=True,
                             positive=True)),
        ))
    return ChannelMap(path=p, entries=tuple(entries), time_origin=origin)
