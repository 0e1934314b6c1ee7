"""The Dask side of the runner: a local cluster on loopback or a remote scheduler.

Local: ``LocalCluster(n_workers=N, threads_per_worker=1, processes=True,
host='127.0.0.1')`` — one single-threaded worker process per core (the simulations hold
the GIL), scheduler, workers and dashboard bound to the loopback interface only, the
dashboard on a free port (shown when bokeh is installed). Remote: ``Client(address)`` to a
scheduler started separately (``dask scheduler``; workers ``dask worker ADDRESS``, or
dask-jobqueue's ``SLURMCluster`` / ``PBSCluster``); every worker must have flexarm_ros
installed (checked before the first task).
"""

from __future__ import annotations

import asyncio
import logging
import os
import uuid

from distributed import Client, LocalCluster, as_completed
from distributed.diagnostics.plugin import WorkerPlugin

from flexarm_ros.errors import InputError


def _one_line(exc) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


class WarmUp(WorkerPlugin):
    """Runs ``fn`` once on every worker that joins (restarted ones included), off the
    worker's event loop: the numba kernels are loaded before the first task."""

    name = "flexarm-warm-up"

    def __init__(self, fn):
        self.fn = fn

    async def setup(self, worker):
        await asyncio.to_thread(self.fn)


def _probe() -> str:
    import flexarm_ros
    return getattr(flexarm_ros, "__version__", "unknown")


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


class DaskExecutor:
    """Tasks on a Dask cluster (see module doc); ``map`` returns results in input order."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 warm_up=None, timeout_s: float = 10.0):
        self.cluster = None
        if scheduler is not None:
            self._connect(str(scheduler), timeout_s)
            n = len(self.client.scheduler_info().get("workers", {}))
            self.description = f"Dask scheduler {scheduler} ({n} workers)"
        else:
            n = int(workers or os.cpu_count() or 1)
            if n < 1:
                raise InputError(f"--workers: got {n}, expected an integer >= 0 (0: in this "
                                 f"process)")
            self.cluster = LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address="127.0.0.1:0" if _has_bokeh() else None,
                silence_logs=logging.ERROR)
            self.client = Client(self.cluster, set_as_default=False)
            self.description = f"Dask LocalCluster, {n} single-threaded worker processes"
        self.dashboard = self.client.dashboard_link if (self.cluster is None or
                                                         _has_bokeh()) else None
        if warm_up is not None:
            self.client.register_plugin(WarmUp(warm_up))

    def _connect(self, address: str, timeout_s: float) -> None:
        expect = ("expected the address of a running Dask scheduler, e.g. "
                  "tcp://127.0.0.1:8786 (start one with `dask scheduler` and workers with "
                  "`dask worker ADDRESS`; docs/ensembles.md)")
        try:
            self.client = Client(address, timeout=timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(f"--scheduler: got {address!r}, cannot connect within "
                             f"{timeout_s:g} s ({_one_line(exc)}); {expect}") from None
        try:
            self.client.wait_for_workers(1, timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            self.client.close()
            raise InputError(f"--scheduler: got {address!r}, a scheduler without workers "
                             f"after {timeout_s:g} s ({_one_line(exc)}), expected at least "
                             f"one `dask worker {address}`") from None
        try:
            self.client.run(_probe)
        except Exception as exc:  # a worker without flexarm_ros: bad setup, say so
            self.client.close()
            raise InputError(f"--scheduler: got {address!r}, whose workers cannot import "
                             f"flexarm_ros ({_one_line(exc)}), expected flexarm_ros "
                             f"installed on every worker (pip install flexarm_ros[ensemble])"
                             ) from None

    def map(self, fn, items, progress=None, status=lambda r: "ok", on_result=None,
            errors: str = "raise") -> list:
        """Results in input order. A task that raises (or is lost with its worker more
        than ``allowed-failures`` times): ``errors='row'`` gives ``{"status": "error",
        "message": ...}`` in its place, ``'raise'`` re-raises (as the serial executor)."""
        token = uuid.uuid4().hex[:12]
        keys = [f"flexarm-{token}-{i}" for i in range(len(items))]
        futures = self.client.map(fn, items, key=keys, pure=False)
        where = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(items)
        for fut in as_completed(futures, loop=self.client.loop):
            try:
                r = fut.result()
            except Exception as exc:  # noqa: BLE001 - the task's failure is a row
                if errors != "row":
                    raise
                r = {"status": "error", "message": f"{type(exc).__name__}: {_one_line(exc)}",
                     "metrics": {}}
            out[where[fut.key]] = r
            fut.release()
            if progress:
                progress.update(status(r))
            if on_result:
                on_result(where[fut.key], r)
        return out

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
