"""The ensemble runner: many independent simulations as tasks, one table back.

``run_ensemble(base, assignments, metrics)`` runs one task per assignment (``{scene key
path: value}``): the task sets the values on the base scene (re-validated,
:func:`flexarm_ros.ensemble.keys.set_keys`), builds the model *in the worker*, simulates
and returns the metrics (:mod:`flexarm_ros.ensemble.metrics`), and the requested time
series only when asked. A sample that diverges, is refused (a value the scene does not
accept, a step or work budget refused) or fails otherwise is a row with its status and a
one-line message; the ensemble never stops for it.

Executors (:func:`open_executor`)
    ``workers=0``: in this process, one task after the other (no Dask; what ``flexarm
    study`` uses, since its rows time themselves). ``workers=N`` (default: one per core):
    a Dask ``LocalCluster`` of N single-threaded worker processes on 127.0.0.1.
    ``scheduler='tcp://host:8786'``: an existing Dask cluster (``dask scheduler`` +
    ``dask worker``, or dask-jobqueue on Slurm/PBS; docs/ensembles.md). Worker processes
    are warmed up once each (the numba kernels loaded from their on-disk cache, compiled
    at most once per worker and machine) by a worker plugin, so a restarted worker warms
    itself up too.

Determinism
    The table depends on the inputs only: the assignments are made on the client, every
    task is a pure function of (base scene, assignment), and the rows are gathered by
    sample index whatever order they complete in. The same inputs give the same table, to
    the bit, on the serial executor, one worker, a local cluster or a remote one on the
    same kind of machine (the compiled kernels use ``fastmath`` contraction flags, so a
    different CPU family may round differently). Dask workers set ``OMP_NUM_THREADS=1``
    and friends; the serial executor runs in the calling process with its BLAS threads,
    which this code's small matrices do not split. The exception is the
    ``wall_s_per_sim_s`` metric, a measurement of the machine.

Worker failures
    A worker process that dies (killed, out of memory) loses its running task; the Dask
    scheduler reschedules it on another worker (``distributed.scheduler.allowed-failures``,
    default 3, before a task counts as poisoning workers), the nanny starts a fresh worker,
    and the table comes back complete. A task that still fails becomes a row with status
    ``error`` and the reason.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from flexarm_ros.errors import InputError, SimulationDiverged, StepTooLarge

STATUSES = ("ok", "diverged", "refused", "error")


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


# ------------------------------------------------------------------------------ tasks
class SceneModel:
    """The task of one sample: base scene + assignment → metrics (and series).

    ``__call__(assignment)`` returns ``{"status", "message", "metrics": {column: float},
    "series": {name: array} or None}``; it never raises for a sample's own failure."""

    def __init__(self, base, metrics, duration=None, series: Sequence[str] = (),
                 open_loop: bool = False):
        self.base = base
        self.metrics = tuple(metrics)
        self.duration = duration
        self.series = tuple(series)
        # False: a scene with a controller runs it in the loop (twin.batch.run_scene)
        self.open_loop = bool(open_loop)

    @property
    def columns(self) -> list[str]:
        return [m.column for m in self.metrics]

    def warm_up(self) -> None:
        """Load the compiled kernels (a short run of the base scene, as the samples run)."""
        from flexarm_ros.twin.batch import probe_duration, run_scene
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                run_scene(self.base, probe_duration(self.base, self.open_loop),
                          open_loop=self.open_loop)
        except (InputError, SimulationDiverged):
            pass

    def __call__(self, assignment: dict) -> dict:
        from flexarm_ros.ensemble.keys import set_keys
        from flexarm_ros.ensemble.metrics import channel, evaluate
        from flexarm_ros.twin.batch import run_scene
        nan = {c: math.nan for c in self.columns}
        try:
            scene = set_keys(self.base, assignment)
        except InputError as exc:
            return {"status": "refused", "message": _one_line(exc), "metrics": nan}
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                res = run_scene(scene, self.duration, open_loop=self.open_loop)
                values = evaluate(res, self.metrics)
                series = None
                if self.series:
                    series = {}
                    for name in self.series:
                        t, y = channel(res, name)
                        series.setdefault("t", t)
                        if len(series["t"]) != len(t):
                            y = np.interp(series["t"], t, y)
                        series[name] = y
        except StepTooLarge as exc:
            return {"status": "refused", "message": _one_line(exc), "metrics": nan}
        except SimulationDiverged as exc:
            return {"status": "diverged", "message": _one_line(exc), "metrics": nan}
        except InputError as exc:
            return {"status": "refused", "message": _one_line(exc), "metrics": nan}
        except (ArithmeticError, ValueError, KeyError, np.linalg.LinAlgError) as exc:
            return {"status": "error", "message": f"{type(exc).__name__}: {_one_line(exc)}",
                    "metrics": nan}
        return {"status": "ok", "message": "", "metrics": values, "series": series}


# -------------------------------------------------------------------------- progress
class Progress:
    """``[#####.....] 12/40 samples, 1 not ok, 3.1 /s, 8 s left`` on stderr, at most 5
    times a second, cleared at the end; nothing when ``quiet``."""

    WIDTH = 78

    def __init__(self, total: int, quiet: bool = False, label: str = "samples"):
        self.total, self.quiet, self.label = total, quiet, label
        self.done = self.bad = 0
        self.t0 = time.perf_counter()
        self._last = 0.0
        from flexarm_ros.io.progress import ProgressLine
        self.line = ProgressLine(self.WIDTH)

    def update(self, status: str = "ok") -> None:
        self.done += 1
        self.bad += status != "ok"
        now = time.perf_counter()
        if self.quiet or (now - self._last < 0.2 and self.done < self.total):
            return
        self._last = now
        frac = self.done / max(self.total, 1)
        rate = self.done / max(now - self.t0, 1e-9)
        left = (self.total - self.done) / rate if rate > 0 else math.inf
        bar = "#" * int(20 * frac) + "." * (20 - int(20 * frac))
        text = (f"  [{bar}] {self.done}/{self.total} {self.label}"
                + (f", {self.bad} not ok" if self.bad else "")
                + f", {rate:.3g}/s, {left:.0f} s left")
        self.line.show(text)

    def clear(self) -> None:
        if not self.quiet:
            self.line.clear()


# ------------------------------------------------------------------------- executors
class SerialExecutor:
    """Tasks in this process, in order (``workers=0``)."""

    description = "in this process (serial)"
    dashboard = None

    def map(self, fn: Callable, items: Sequence, progress: Progress | None = None,
            status=lambda r: "ok", on_result=None, errors: str = "raise") -> list:
        out = []
        for i, item in enumerate(items):
            r = fn(item)
            out.append(r)
            if progress:
                progress.update(status(r))
            if on_result:
                on_result(i, r)
        return out

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_executor(workers: int | None = None, scheduler: str | None = None,
                  warm_up: Callable | None = None, timeout_s: float = 10.0):
    """``workers=0`` → :class:`SerialExecutor`; otherwise a Dask executor on a new local
    cluster (``workers`` processes, default one per core, at most
    :data:`~flexarm_ros.ensemble.limits.WORKERS_PER_CORE` per core) or on ``scheduler``;
    ``timeout_s`` (``--timeout``) a finite number > 0 for every executor (a bad one is the
    caller's mistake whichever executor it asked for)."""
    from flexarm_ros.ensemble.limits import check_timeout
    check_timeout(timeout_s)
    if scheduler is None and workers == 0:
        return SerialExecutor()
    if scheduler is None:
        from flexarm_ros.ensemble.limits import check_workers
        check_workers(workers)
    else:
        from flexarm_ros.ensemble.limits import check_scheduler_address
        check_scheduler_address(scheduler)
    try:
        from flexarm_ros.ensemble.cluster import DaskExecutor
    except ImportError as exc:
        raise InputError(f"--workers: got {workers}, the Dask runner needs dask and "
                         f"distributed ({exc}), expected pip install -e .[ensemble], or "
                         f"--workers 0 (in this process)") from None
    return DaskExecutor(workers=workers, scheduler=scheduler, warm_up=warm_up,
                        timeout_s=timeout_s)


def run_tasks(fn: Callable, items: Sequence, executor=None, progress: Progress | None = None,
              status=lambda r: "ok", on_result=None) -> list:
    """``[fn(item) for item in items]`` on the executor (default serial), in input order;
    ``on_result(index, result)`` as each completes (in completion order)."""
    executor = executor or SerialExecutor()
    return executor.map(fn, list(items), progress, status, on_result)


# ------------------------------------------------------------------------------ table
@dataclass
class EnsembleTable:
    """The rows of an ensemble, one per sample, in sample order.

    Columns: ``sample`` (index), one per parameter (the key path or unknown's name), then
    ``status``, the metric columns and ``message`` (empty when ok). ``meta`` says how it
    was made (scene, design, seed, duration, units, executor); ``series`` holds the
    requested time series per row (None for a row that is not ok)."""
    params: list[str]
    metrics: list[str]
    rows: list[dict]
    meta: dict = field(default_factory=dict)
    series: list | None = None

    @property
    def columns(self) -> list[str]:
        return ["sample", *self.params, "status", *self.metrics, "message"]

    def column(self, name: str) -> np.ndarray:
        vals = [r[name] for r in self.rows]
        try:
            return np.asarray(vals, float)
        except (TypeError, ValueError):
            return np.asarray(vals, object)

    @property
    def ok(self) -> np.ndarray:
        return np.array([r["status"] == "ok" for r in self.rows], bool)

    def counts(self) -> dict:
        return {s: sum(r["status"] == s for r in self.rows) for s in STATUSES}

    @property
    def public_meta(self) -> dict:
        return {k: v for k, v in self.meta.items() if not k.startswith("_")}

    def deterministic_rows(self) -> list[dict]:
        """Rows without the machine-measurement columns (``wall_s_per_sim_s``)."""
        from flexarm_ros.ensemble.metrics import NONDETERMINISTIC
        return [{k: v for k, v in r.items() if k not in NONDETERMINISTIC} for r in self.rows]

    # -- output
    def write(self, path) -> Path:
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".csv":
            self._write_csv(path)
        elif suffix == ".parquet":
            self._write_parquet(path)
        else:
            raise InputError(f"--out: got {str(path)!r}, expected a .csv or .parquet file")
        from flexarm_ros.io.paths import note_written
        note_written(path)
        meta_path = path.with_name(path.name + ".meta.json")
        meta_path.write_text(json.dumps(self.public_meta, indent=2, default=_json_default)
                             + "\n")
        note_written(meta_path)
        if self.series is not None:
            self.write_series(path)
        return path

    def _write_csv(self, path: Path) -> None:
        tmp = path.with_name(path.name + ".part")
        try:
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(self.columns)
                for r in self.rows:
                    w.writerow([_cell(r.get(c)) for c in self.columns])
            os.replace(tmp, path)
        except BaseException:        # a full disk, a Ctrl-C: no half-written .part left
            tmp.unlink(missing_ok=True)
            raise

    def _write_parquet(self, path: Path) -> None:
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise InputError(f"--out: got {str(path)!r}, a .parquet table needs pyarrow "
                             f"(pip install -e .[ensemble]), expected it installed or a "
                             f".csv") from None
        data = {c: [r.get(c) for r in self.rows] for c in self.columns}
        table = pa.table(data).replace_schema_metadata(
            {"flexarm_ros.ensemble": json.dumps(self.public_meta, default=_json_default)})
        tmp = path.with_name(path.name + ".part")
        pq.write_table(table, tmp)
        os.replace(tmp, path)

    def series_dir(self, path) -> Path:
        path = Path(path)
        return path.with_name(path.stem + ".samples")

    def write_series(self, path) -> Path:
        """Per-sample time series next to the table: ``<table>.samples/sample_00012.csv``
        (``t [s]``, ``name [unit]`` headers, readable by ``flexarm compare``)."""
        from flexarm_ros.io.tables import write_table
        from flexarm_ros.io.units import table_units
        d = self.series_dir(path)
        d.mkdir(parents=True, exist_ok=True)
        for r, s in zip(self.rows, self.series or []):
            if s:
                write_table(d / f"sample_{r['sample']:05d}.csv", s,
                            table_units(s, self.meta.get("_scene")))
        return d

    def to_json(self) -> dict:
        return {"columns": self.columns,
                "rows": [{c: _json_value(r.get(c)) for c in self.columns} for r in self.rows],
                "counts": self.counts(),
                "meta": self.public_meta}


def _cell(v):
    if isinstance(v, float):
        return repr(v)               # shortest text that reads back to the same bits
    return "" if v is None else v


def _json_value(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def read_table(path) -> list[dict]:
    """Rows of a table written by :meth:`EnsembleTable.write` (.csv: numbers parsed back
    to the same floats; .parquet)."""
    path = Path(path)
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq
        return pq.read_table(path).to_pylist()
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            out = {}
            for k, v in r.items():
                try:
                    out[k] = int(v) if k == "sample" else float(v)
                except ValueError:
                    out[k] = v
            rows.append(out)
    return rows


# ---------------------------------------------------------------------------- runner
def run_ensemble(base, assignments: Sequence[dict], metrics=None, duration=None, *,
                 params: Sequence[str] | None = None, executor=None,
                 workers: int | None = 0, scheduler: str | None = None,
                 series: Sequence[str] = (), quiet: bool = True, model=None,
                 meta: dict | None = None, labels: Sequence[dict] | None = None
                 ) -> EnsembleTable:
    """Run one simulation per assignment and return the table (see module doc).

    ``base``: the Scene; ``assignments``: ``[{key path: value}, ...]`` (a parameter may
    be a list of key paths set to one value: give ``params`` names and assignments keyed
    by them, with ``model`` resolving them); ``metrics``: names
    (:func:`flexarm_ros.ensemble.metrics.resolve_metrics`); ``duration``: simulated s
    (default the scene's); ``executor``: an open executor, else one is opened from
    ``workers`` / ``scheduler`` and closed at the end; ``series``: channels returned per
    sample; ``model``: the task (default :class:`SceneModel`), a picklable callable
    ``assignment → {"status", "message", "metrics", "series"}`` with ``columns``;
    ``labels``: per sample the values of the ``params`` columns when they are not the
    assignment's keys (an unknown setting several keys).
    """
    from flexarm_ros.ensemble.metrics import resolve_metrics
    if model is None:
        model = SceneModel(base, resolve_metrics(metrics, base), duration, series)
    assignments = [dict(a) for a in assignments]
    if params is None:
        params = []
        for a in assignments:
            params += [k for k in a if k not in params]
    own = executor is None
    if own:
        executor = open_executor(workers, scheduler,
                                 warm_up=getattr(model, "warm_up", None))
    prog = Progress(len(assignments), quiet)
    t0 = time.perf_counter()
    try:
        results = executor.map(model, assignments, prog, status=lambda r: r["status"],
                               errors="row")
    finally:
        prog.clear()
        if own:
            executor.close()
    wall = time.perf_counter() - t0
    rows, series_out = [], []
    for i, (a, r) in enumerate(zip(assignments, results)):
        row = {"sample": i}
        lab = labels[i] if labels is not None else a
        row.update({p: lab.get(p) for p in params})
        row["status"] = r["status"]
        row.update({c: float(r["metrics"].get(c, math.nan)) for c in model.columns})
        row["message"] = r.get("message", "")
        rows.append(row)
        series_out.append(r.get("series"))
    info = {"samples": len(rows), "executor": executor.description,
            "wall_s": wall, "scene": getattr(base, "name", None),
            "duration_s": duration if duration is not None else getattr(base, "duration",
                                                                        None)}
    info.update(meta or {})
    info["_scene"] = base
    want_series = series or getattr(model, "series", ())
    return EnsembleTable(list(params), list(model.columns), rows, info,
                         series_out if want_series else None)
