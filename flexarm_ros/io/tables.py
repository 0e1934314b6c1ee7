"""Output tables: CSV with a header row, or NumPy ``.npz`` (one array per column)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model.errors import SceneError


def write_table(path, columns: dict) -> Path:
    """Write named equal-length columns to ``path`` (.csv or .npz), atomically.

    The file is written beside the target and renamed, so a failure never leaves a
    half-written table in place of an earlier one.
    """
    path = Path(path)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[k], float) for k in names])
    if not np.all(np.isfinite(data)):
        bad = names[int(np.nonzero(~np.isfinite(data).all(axis=0))[0][0])]
        raise SceneError(f"--out: column {bad!r} has non-finite values; nothing written")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise SceneError(f"--out: got {str(path)!r}, expected a .csv or .npz file name")
    tmp = path.with_name(path.name + ".part")
    if suffix == ".csv":
        np.savetxt(tmp, data, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    else:
        with open(tmp, "wb") as fh:
            np.savez(fh, **{k: np.asarray(columns[k], float) for k in names})
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
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {k: data[:, j] for j, k in enumerate(names)}
