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
import contextlib
import logging
import uuid

from distributed import Client, LocalCluster, as_completed
from distributed.diagnostics.plugin import WorkerPlugin

from flexarm_ros.errors import InputError
from flexarm_ros.ensemble.limits import SCHEDULER_EXPECT, check_scheduler_address


def _one_line(exc) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


class WarmUp(WorkerPlugin):
    """Runs ``fn`` once on every worker that joins (restarted ones included), off the
    worker's event loop: the numba kernels are loaded before the first task."""

    name = "flexarm-warm-up"

    def __init__(self, fn):
        self.fn = fn

    async def setup(self, worker):
        try:
            await asyncio.to_thread(self.fn)
        except asyncio.CancelledError:
            # the cluster closes during the warm-up (a Ctrl-C): nothing to report, and
            # Dask would log the cancellation as an error on the worker's stderr
            return


def _probe() -> str:
    import flexarm_ros
    return getattr(flexarm_ros, "__version__", "unknown")


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


def quiet_dask_logs() -> None:
    """Silence what Dask, tornado and asyncio log from here on: after a Ctrl-C the worker
    processes are gone and the scheduler's broadcasts to them fail, which is expected and
    says nothing the command's one line does not."""
    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def _children_ignore_sigint():
    """SIGINT blocked while the local cluster starts its worker processes and its event
    loop thread, which inherit the blocked mask (across fork and exec; Python never
    unblocks it): a Ctrl-C at the terminal reaches the whole process group, and each
    worker had printed a KeyboardInterrupt traceback of its own. The workers leave the
    Ctrl-C to this process, which closes the cluster. Blocked, not ignored: a Ctrl-C
    during these seconds of start-up is taken by another thread of this process (numpy's
    BLAS threads, started before, do not block it) and raised at once, or stays pending
    and is raised once the mask is restored (ignored, it was discarded and the command
    ran on to exit 0: issue 39)."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # multiprocessing's resource tracker, started on the first worker's spawn, unblocks
    # SIGINT in the thread that starts it (the mask it sets for its own child): started
    # first, it leaves the mask below alone
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _Client(Client):
    """A Client whose failed start leaves nothing behind: ``Client(address)`` that cannot
    connect raises, but the half-built object's ``__del__`` later tries to close it on an
    event loop that is gone and prints a TimeoutError traceback ~2 timeouts after the
    command's one-line error (issue 39). A failed start is marked closed at once."""

    def start(self, **kwargs):
        try:
            return super().start(**kwargs)
        except BaseException:
            self.status = "closed"                  # __del__ / close(): nothing to do
            try:
                self._loop_runner.stop()
            except Exception:  # noqa: BLE001 - best effort, the start failed anyway
                pass
            raise


async def _identity(address: str, timeout_s: float) -> dict:
    """The scheduler's identity over one comm (Dask's handshake and an ``identity``
    request), closed at the end."""
    from distributed.comm import connect
    comm = await connect(address, timeout=timeout_s)
    try:
        await comm.write({"op": "identity", "reply": True})
        return await comm.read()
    finally:
        comm.abort()


def probe_scheduler(address: str, timeout_s: float) -> None:
    """InputError unless a Dask scheduler answers at ``address`` within ``timeout_s``:
    tried on a throwaway event loop, so that a refused, silent or foreign peer (one that
    answers with something else than Dask's protocol) leaves no client, thread or
    half-open connection behind to print later."""
    try:
        info = asyncio.run(asyncio.wait_for(_identity(address, timeout_s), timeout_s + 1))
    except Exception as exc:  # noqa: BLE001 - any failure to talk to it is the address's
        why = (_one_line(exc) if isinstance(exc, (OSError, TimeoutError)) else
               f"something answered that does not speak Dask's protocol: "
               f"{type(exc).__name__}: {_one_line(exc)}")
        raise InputError(f"--scheduler: got {address!r}, no Dask scheduler answered within "
                         f"{timeout_s:g} s ({why}); {SCHEDULER_EXPECT}") from None
    if not isinstance(info, dict) or info.get("type") != "Scheduler":
        kind = info.get("type") if isinstance(info, dict) else type(info).__name__
        raise InputError(f"--scheduler: got {address!r}, which answered as {kind!r}, not a "
                         f"Dask scheduler; {SCHEDULER_EXPECT}")


class DaskExecutor:
    """Tasks on a Dask cluster (see module doc); ``map`` returns results in input order."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 warm_up=None, timeout_s: float = 10.0):
        self.cluster = None
        self.client = None
        try:
            self._open(workers, scheduler, warm_up, timeout_s)
        except BaseException as exc:
            # a Ctrl-C while the cluster starts: close what has started, quietly (its
            # processes got the Ctrl-C too), or it logs tracebacks as the process exits
            if isinstance(exc, KeyboardInterrupt):
                quiet_dask_logs()
            try:
                self.close()
            except BaseException:  # noqa: BLE001 - closing a half-started cluster
                pass
            raise

    def _open(self, workers, scheduler, warm_up, timeout_s) -> None:
        if scheduler is not None:
            self._connect(str(scheduler), timeout_s)
            n = len(self.client.scheduler_info().get("workers", {}))
            self.description = f"Dask scheduler {scheduler} ({n} workers)"
        else:
            from flexarm_ros.ensemble.limits import check_workers, usable_cores
            check_workers(workers)
            n = int(workers or usable_cores())
            with _children_ignore_sigint():
                self.cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                    dashboard_address="127.0.0.1:0" if _has_bokeh() else None,
                    silence_logs=logging.ERROR)
            self.client = _Client(self.cluster, set_as_default=False)
            self.description = f"Dask LocalCluster, {n} single-threaded worker processes"
        self.dashboard = self.client.dashboard_link if (self.cluster is None or
                                                         _has_bokeh()) else None
        if warm_up is not None:
            self.client.register_plugin(WarmUp(warm_up))

    def _connect(self, address: str, timeout_s: float) -> None:
        expect = SCHEDULER_EXPECT
        check_scheduler_address(address)
        probe_scheduler(address, timeout_s)
        try:
            self.client = _Client(address, timeout=timeout_s, set_as_default=False)
        except Exception as exc:  # noqa: BLE001 - it answered the probe, then failed
            raise InputError(f"--scheduler: got {address!r}, cannot connect within "
                             f"{timeout_s:g} s ({_one_line(exc)}); {expect}") from None
        try:
            self.client.wait_for_workers(1, timeout=timeout_s)
        except Exception as exc:  # noqa: BLE001 - no worker in time, whatever the form
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
            if self.client is not None:
                self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            quiet_dask_logs()        # the workers got the Ctrl-C too: closing is noisy
        self.close()
