"""What an ensemble may ask of this machine, checked before any work: the number of
samples, the seed, the worker processes and the memory the table will hold.

Every command that runs an ensemble (``flexarm sweep``, ``uncertainty``, ``sensitivity``,
``study``, ``calibrate``) calls :func:`check_ensemble` after parsing its arguments and
before it loads a model, probes a channel or starts a worker; :func:`open_executor
<flexarm_ros.ensemble.runner.open_executor>` checks the workers again for callers of the
library. Each refusal is an :class:`~flexarm_ros.errors.InputError` (exit 2) naming the
option, the value and the limit with its figure:

* ``--samples``: an integer >= 1 (every command; 0 used to run nothing and exit 0 in
  ``uncertainty``, or fall back to the default in ``sensitivity``).
* ``--seed``: an integer in ``[0, 2**32 - 1]`` (what numpy's and SALib's generators take).
* ``--workers``: at most :data:`WORKERS_PER_CORE` × the cores this process may run on
  (``os.sched_getaffinity``), and their memory (:data:`WORKER_BYTES` each) within the
  share :data:`MEMORY_SHARE` of the available memory. The simulations hold the GIL and use
  one core each: more processes than cores only share them out, and a thousand worker
  processes on two cores never finish starting.
* the runs (samples × the runs per sample of the method) × :data:`SAMPLE_BYTES` (plus
  the time series a sample returns) within :data:`MEMORY_SHARE` of the available memory
  (``psutil.virtual_memory().available``, else ``MemAvailable`` of ``/proc/meminfo``;
  unknown: not checked). The designs, the rows, the Dask tasks and the table are all held
  at once; ``sweep --samples 1000000000`` grew to 23.6 GB before the kernel killed it.
"""

from __future__ import annotations

import math
import numbers
import os

from flexarm_ros.errors import InputError

#: worker processes allowed per core the process may run on
WORKERS_PER_CORE = 4
#: the largest seed (numpy's legacy seeding and SALib take 32-bit seeds)
SEED_MAX = 2 ** 32 - 1
#: client-side memory of one run: the assignment, its result and table row (~1.2 kB,
#: measured with tracemalloc on the serial executor) and the Dask task's state on the
#: client and the scheduler, rounded up generously
SAMPLE_BYTES = 16 * 1024
#: resident memory of one worker process (Python, numpy, numba kernels, distributed:
#: ~240 MiB measured after a warm-up run)
WORKER_BYTES = 256 * 2 ** 20
#: the share of the available memory an ensemble may plan to use
MEMORY_SHARE = 0.8


def usable_cores() -> int:
    """Cores this process may run on (its affinity mask, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation, or None when unknown."""
    try:
        import psutil
        return int(psutil.virtual_memory().available)
    except Exception:  # noqa: BLE001 - psutil missing or unable to read: try /proc
        pass
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _bytes(n: float) -> str:
    for unit, size in (("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def _is_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def check_samples(n, flag: str = "--samples") -> None:
    """``n`` an integer >= 1 (None: the command's default, not checked here)."""
    if n is None:
        return
    if not _is_int(n) or n < 1:
        raise InputError(f"{flag}: got {n!r}, expected an integer >= 1")


def check_seed(seed, flag: str = "--seed") -> None:
    """``seed`` an integer in [0, :data:`SEED_MAX`] (None: the default)."""
    if seed is None:
        return
    if not _is_int(seed) or not 0 <= seed <= SEED_MAX:
        raise InputError(f"{flag}: got {seed!r}, expected an integer from 0 to {SEED_MAX} "
                         f"(2**32 - 1)")


def check_workers(workers, flag: str = "--workers", memory: int | None = -1) -> None:
    """``workers`` (None: one per core) >= 0, at most :data:`WORKERS_PER_CORE` per core
    and their memory within :data:`MEMORY_SHARE` of ``memory`` (default: measured)."""
    if workers is None or workers == 0:
        return
    if not _is_int(workers) or workers < 0:
        raise InputError(f"{flag}: got {workers!r}, expected an integer >= 0 (0: in this "
                         f"process)")
    cores = usable_cores()
    cap = WORKERS_PER_CORE * cores
    if workers > cap:
        raise InputError(f"{flag}: got {workers}, expected at most {cap} ({WORKERS_PER_CORE} "
                         f"x the {cores} cores this process may use; each worker is a "
                         f"process running one simulation at a time, default one per core)")
    memory = available_memory() if memory == -1 else memory
    if memory is not None and workers * WORKER_BYTES > MEMORY_SHARE * memory:
        fit = max(1, int(MEMORY_SHARE * memory // WORKER_BYTES))
        raise InputError(f"{flag}: got {workers}, whose processes need about "
                         f"{_bytes(workers * WORKER_BYTES)} ({_bytes(WORKER_BYTES)} each), "
                         f"expected at most {fit} workers for the {_bytes(memory)} of memory "
                         f"available ({100 * MEMORY_SHARE:.0f} % of it)")


def run_bytes(series_points: int = 0, series_channels: int = 0) -> int:
    """Memory held per run: :data:`SAMPLE_BYTES` and, when the run returns time series,
    their float64 values (time and channels) twice over (the result and the table, or the
    envelope's stack)."""
    return SAMPLE_BYTES + 2 * 8 * int(series_points) * (int(series_channels) + 1)


def check_memory(runs: int, per_run: int, flag: str = "--samples",
                 value=None, memory: int | None = -1) -> None:
    """``runs`` × ``per_run`` bytes within :data:`MEMORY_SHARE` of ``memory`` (default:
    measured; unknown: not checked)."""
    memory = available_memory() if memory == -1 else memory
    need = float(runs) * per_run
    if memory is None or need <= MEMORY_SHARE * memory:
        return
    fit = max(0, int(MEMORY_SHARE * memory // per_run))
    runs_text = f"{runs:,}" if isinstance(runs, numbers.Integral) else f"{runs:.6g}"
    got = (f"{value!r}" if value == runs else
           f"{value!r} ({runs_text} runs)" if value is not None else f"{runs_text} runs")
    raise InputError(f"{flag}: got {got}, which would hold about {_bytes(need)} in memory "
                     f"({_bytes(per_run)} per run), expected at most {fit:,} runs for the "
                     f"{_bytes(memory)} of memory available ({100 * MEMORY_SHARE:.0f} % of "
                     f"it): fewer samples, or a machine with more memory")


def check_ensemble(*, samples=None, seed=None, workers=None, runs: float | None = None,
                   per_run: int = SAMPLE_BYTES, samples_flag: str = "--samples",
                   seed_flag: str = "--seed") -> None:
    """The checks of an ensemble command, in the order of its options: samples, seed,
    workers, then the memory of ``runs`` runs (the total the design makes of ``samples``;
    None: not checked here, the command checks it once it knows the design)."""
    check_samples(samples, samples_flag)
    check_seed(seed, seed_flag)
    check_workers(workers)
    if runs is not None:
        if not math.isfinite(float(runs)):
            raise InputError(f"{samples_flag}: got {samples!r}, expected a finite number of "
                             f"runs")
        check_memory(runs, per_run, samples_flag, samples)


#: the address schemes of Dask's communication layers
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")
SCHEDULER_EXPECT = ("expected the address of a running Dask scheduler, e.g. "
                    "tcp://127.0.0.1:8786 (start one with `dask scheduler` and workers with "
                    "`dask worker ADDRESS`; docs/ensembles.md)")


def check_timeout(timeout_s, flag: str = "--timeout") -> None:
    """``timeout_s`` (the wait for a scheduler and its first worker) a finite number > 0."""
    if not (timeout_s > 0 and math.isfinite(timeout_s)):
        raise InputError(f"{flag}: got {timeout_s}, expected a finite number > 0 s")


def check_scheduler_address(address) -> None:
    """``[SCHEME://]HOST:PORT`` with a Dask scheme and a port in 1..65535, else
    InputError (before any connection is tried)."""
    text = str(address).strip()
    scheme, sep, rest = text.rpartition("://")
    if not sep:
        scheme, rest = "tcp", text
    if scheme not in SCHEDULER_SCHEMES:
        raise InputError(f"--scheduler: got {address!r}, an unknown scheme {scheme!r} "
                         f"(expected one of {', '.join(SCHEDULER_SCHEMES)}); "
                         f"{SCHEDULER_EXPECT}")
    if scheme == "inproc":
        return
    host, colon, port = rest.rpartition(":")
    if not (colon and host.strip("[]") and port.isdigit() and 1 <= int(port) <= 65535):
        raise InputError(f"--scheduler: got {address!r}, not HOST:PORT with a port in "
                         f"1..65535; {SCHEDULER_EXPECT}")
