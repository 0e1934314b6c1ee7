"""Output tables: CSV with a header row, or NumPy ``.npz`` (one array per column). Columns
are numbers (``%.10g`` in CSV) or text (e.g. ``contact_phase``).

With units (:func:`flexarm_ros.io.units.table_units`) a CSV header cell reads
``name [unit]`` (``t [s]``, ``tip_x [m]``, ``contact_phase [text]``): the CSV convention
``flexarm compare`` reads (:mod:`flexarm_ros.io.experiment`). ``.npz`` keys are the bare
names. :func:`read_table` returns bare names either way."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from flexarm_ros.errors import SceneError

_UNIT = re.compile(r"\s*\[[^\[\]]*\]\s*$")


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
    num = [k for k in names if k not in text]
    data = np.column_stack([np.asarray(columns[k], float) for k in num]) if num else None
    if data is not None and not np.all(np.isfinite(data)):
        bad = num[int(np.nonzero(~np.isfinite(data).all(axis=0))[0][0])]
        raise SceneError(f"--out: column {bad!r} has non-finite values; nothing written")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise SceneError(f"--out: got {str(path)!r}, expected a .csv or .npz file name")
    tmp = path.with_name(path.name + ".part")
    if suffix == ".csv":
        cols = [(np.asarray(columns[k]).astype(str) if k in text else
                 np.char.mod("%.10g", np.asarray(columns[k], float))) for k in names]
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(",".join(f"{k} [{units[k]}]" if k in units else k for k in names)
                     + "\n")
            for row in zip(*cols):
                fh.write(",".join(row) + "\n")
    else:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: (np.asarray(columns[k]).astype(str) if k in text else
                                np.asarray(columns[k], float)) for k in names})
    tmp.replace(path)
    return path


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
