"""Output tables: CSV with a header row, or NumPy ``.npz`` (one array per column). Columns
are numbers (``%.10g`` in CSV) or text (e.g. ``contact_phase``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flexarm_ros.errors import SceneError


def write_table(path, columns: dict) -> Path:
    """Write named equal-length columns to ``path`` (.csv or .npz), atomically.

    The file is written beside the target and renamed, so a failure never leaves a
    half-written table in place of an earlier one.
    """
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
        with open(tmp, "w") as fh:
            fh.write(",".join(names) + "\n")
            for row in zip(*cols):
                fh.write(",".join(row) + "\n")
    else:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: (np.asarray(columns[k]).astype(str) if k in text else
                                np.asarray(columns[k], float)) for k in names})
    tmp.replace(path)
    return path


def read_table(path) -> dict:
    """Read a table written by :func:`write_table` back into named columns."""
    path = Path(path)
    if path.suffix.lower() == ".npz":
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    with open(path) as fh:
        names = fh.readline().strip().split(",")
        rows = [line.rstrip("\n").split(",") for line in fh if line.strip()]
    out = {}
    for j, k in enumerate(names):
        col = [r[j] for r in rows]
        try:
            out[k] = np.array(col, dtype=float)
        except ValueError:            # a text column (e.g. contact_phase)
            out[k] = np.array(col)
    return out
