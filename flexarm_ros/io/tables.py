"""Output tables: CSV with a header row, or NumPy ``.npz`` (one array per column). Columns
are numbers (``%.10g`` in CSV) or text (e.g. ``contact_phase``).

With units (:func:`flexarm_ros.io.units.table_units`) a CSV header cell reads
``name [unit]`` (``t [s]``, ``tip_x [m]``, ``contact_phase [text]``): the CSV convention
``flexarm compare`` reads (:mod:`flexarm_ros.io.experiment`). ``.npz`` keys are the bare
names. :func:`read_table` returns bare names either way."""

from __future__ import annotations

import re
from itertools import islice
from pathlib import Path

import numpy as np

from flexarm_ros.errors import InputError

_UNIT = re.compile(r"\s*\[[^\[\]]*\]\s*$")
#: a number in a CSV table (ten significant digits)
NUMBER_FORMAT = "%.10g"


def write_table(path, columns: dict, units: dict | None = None) -> Path:
    """Write named equal-length columns to ``path`` (.csv or .npz), atomically.

    ``units`` (``{name: unit}``): CSV headers ``name [unit]`` for the names it holds (the
    others bare). The file is written beside the target and renamed, so a failure never
    leaves a half-written table in place of an earlier one.
    """
    units = units or {}
    path = Path(path)
    names = list(columns)
    text = {k for k in names if np.asarray(columns[k]).dtype.kind in "OUS"}
    if len({np.shape(columns[k]) for k in names}) > 1:
        raise ValueError("write_table: columns of different lengths: "
                         + ", ".join(f"{k} {np.shape(columns[k])}" for k in names))
    for k in names:
        if k not in text and not np.all(np.isfinite(np.asarray(columns[k], float))):
            raise InputError(f"--out: column {k!r} has non-finite values; nothing written")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise InputError(f"--out: got {str(path)!r}, expected a .csv or .npz file name")
    tmp = path.with_name(path.name + ".part")
    try:
        if suffix == ".csv":
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(",".join(f"{k} [{units[k]}]" if k in units else k for k in names)
                         + "\n")
                lines = csv_rows(columns, names, text)
                while chunk := "".join(islice(lines, CSV_CHUNK_ROWS)):
                    fh.write(chunk)
        else:
            with open(tmp, "wb") as fh:
                np.savez(fh, **{k: (np.asarray(columns[k]).astype(str) if k in text else
                                    np.asarray(columns[k], float)) for k in names})
        tmp.replace(path)
    except BaseException:            # a full disk, a Ctrl-C: no half-written .part left
        tmp.unlink(missing_ok=True)
        raise
    from flexarm_ros.io.paths import note_written
    note_written(path)
    return path


#: rows formatted per write (bounds the memory of a long table's text)
CSV_CHUNK_ROWS = 8192


def csv_rows(columns: dict, names, text=()):
    """The CSV data lines (each ending in a newline) of the named columns: a number as
    ``"%.10g" % value``, text (names in ``text``) as ``str``. One row format applied to
    each row of Python values: the same text as formatting each value with
    ``np.char.mod("%.10g", …)`` (which applies Python's ``%`` per element) and joining,
    ~3× faster. ``%.10g`` keeps ten significant digits: a CSV does not round-trip
    float64 exactly (``.npz`` does)."""
    fmt = ",".join("%s" if k in text else NUMBER_FORMAT for k in names) + "\n"
    cols = [np.asarray(columns[k]).astype(str).tolist() if k in text else
            np.asarray(columns[k], float).tolist() for k in names]
    return map(fmt.__mod__, zip(*cols))


def read_table(path) -> dict:
    """Read a table written by :func:`write_table` back into named columns (bare names: a
    header's `` [unit]`` is dropped)."""
    path = Path(path)
    if path.suffix.lower() == ".npz":
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    with open(path, encoding="utf-8") as fh:
        names = [_UNIT.sub("", h) for h in fh.readline().strip().split(",")]
        rows = [line.rstrip("\n").split(",") for line in fh if line.strip()]
    out = {}
    for j, k in enumerate(names):
        col = [r[j] for r in rows]
        try:
            out[k] = np.array(col, dtype=float)
        except ValueError:            # a text column (e.g. contact_phase)
            out[k] = np.array(col)
    return out


def sensor_table_path(out, rate_hz) -> Path:
    """``run.csv`` → ``run.sensors_4000hz.csv``: the table of the sensors sampled at
    ``rate_hz`` beside a main table (``flexarm simulate --out``, ``flexarm bag export``),
    which :func:`flexarm_ros.analysis.channels.sensor_tables_beside` reads with it."""
    out = Path(out)
    return out.with_name(f"{out.stem}.sensors_{rate_hz:g}hz{out.suffix}")
