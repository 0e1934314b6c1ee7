"""The README's test command on a cold or a warm numba cache, alone or beside a CPU hog
(not a unit test; issue 37's targets: ≤ 5 min on 2 cores beside a hog, from a fresh
clone, whose first run compiles every kernel).

    python bench/bench_suite.py --cache cold --hog           # a fresh clone's first run
    python bench/bench_suite.py --cache warm --hog --runs 2
    python bench/bench_suite.py --cache cold --cache warm    # alternating, no hog

A cold run points ``NUMBA_CACHE_DIR`` at an empty directory (the state of a fresh clone:
the package's ``__pycache__`` holds no kernel), a warm one at the directory the previous
run of this bench filled. The hog is ``sh -c 'while :; do :; done'``, one process started
before and stopped after each run. Each run prints its wall time, the suite's own
summary line and the CPU time the suite's processes took (user + sys of the children, the hog's left out).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, "-m", "pytest", "-m", "not slow and not extended", "-q",
           "-p", "no:cacheprovider"]


def _cpu_of(pid: int) -> float:
    """User + system CPU seconds of a live process (/proc/PID/stat fields 14, 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(cache: str, hog: bool, warm_dir: Path) -> dict:
    cache_dir = Path(tempfile.mkdtemp(prefix="bench-suite-cold-")) if cache == "cold" \
        else warm_dir
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    hog_proc = subprocess.Popen(["sh", "-c", "while :; do :; done"]) if hog else None
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    try:
        r = subprocess.run(COMMAND, cwd=REPO, env=env, capture_output=True, text=True)
    finally:
        wall = time.monotonic() - t0
        hog_cpu = 0.0
        if hog_proc is not None:
            hog_cpu = _cpu_of(hog_proc.pid)
            hog_proc.kill()
            hog_proc.wait()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime) - hog_cpu
    lines = [ln for ln in r.stdout.splitlines() if " in " in ln and ("passed" in ln or
                                                                     "failed" in ln)]
    return {"cache": cache, "hog": hog, "wall_s": wall, "cpu_s": cpu,
            "exit": r.returncode, "summary": lines[-1] if lines else r.stdout[-300:],
            "cache_dir": cache_dir}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", action="append", choices=("cold", "warm"),
                    help="cold: an empty numba cache; warm: the one the last run filled "
                         "(repeat to alternate; default cold)")
    ap.add_argument("--hog", action="store_true", help="a busy-loop process beside each run")
    ap.add_argument("--warm-dir", type=Path, help="the warm cache to start from (default: "
                    "the one a cold run of this invocation fills)")
    ap.add_argument("--runs", type=int, default=1, help="rounds over --cache (default 1)")
    a = ap.parse_args(argv)
    if a.runs < 1:
        ap.error(f"--runs: got {a.runs}, expected an integer >= 1")
    warm_dir = a.warm_dir or Path(tempfile.mkdtemp(prefix="bench-suite-warm-"))
    print(f"{os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.2f}; "
          f"{' '.join(COMMAND[1:])}", flush=True)
    for _ in range(a.runs):
        for cache in a.cache or ["cold"]:
            res = one_run(cache, a.hog, warm_dir)   # a warm run before any cold: cold
            if cache == "cold":
                warm_dir = res["cache_dir"]
            print(f"{cache:4s} {'hog' if a.hog else 'quiet'}: {res['wall_s']:6.1f} s wall, "
                  f"{res['cpu_s']:6.1f} s CPU, exit {res['exit']}: {res['summary']}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
