"""Start-up cost of a short ``flexarm simulate`` process (not a unit test).

A one-second simulation integrates in ~20 ms; the rest of the process is the interpreter,
imports, loading the compiled (numba) functions from their on-disk cache, building the
model, the output columns and writing the table. This bench times

1. the whole warm process, ``flexarm simulate two_link_free --duration 1 --out x.npz
   --quiet`` (the numba cache already on disk: one unmeasured run first), wall and CPU
   (user + sys) time, best of ``--repeat``;
2. the same run, in a child process with timers around its phases, best of ``--repeat``
   per phase (the phases of one run need not add up to the best process):

   * ``interpreter``: process launch to the child's first statement;
   * ``imports``: ``flexarm_ros.cli`` and the modules ``flexarm simulate`` imports;
   * ``scene``: reading the scene YAML, fidelity overrides applied;
   * ``model build``: :class:`~flexarm_ros.model.chain.Chain` (beam shapes, mass points);
   * ``compiled load``: numba loading the compiled functions a run calls from the cache
     (numba's first-call set-up included: its typing and lowering registries, which import
     ``scipy.linalg`` for BLAS);
   * ``integration``: :func:`~flexarm_ros.sim.integrate.integrate` without the compiled
     load (step choice, work-budget check, the RK4 loop);
   * ``outputs``: the output columns (energy and tip position per sample) and sensor tables;
   * ``write``: :func:`~flexarm_ros.io.tables.write_table`;
   * ``other``: the rest of ``main()`` (argument parsing, initial state, summary line);
   * ``exit``: the child's last statement to the process's end (interpreter teardown).

    python bench/bench_startup.py                  # best of 5
    python bench/bench_startup.py --repeat 9 --scene two_link_case1 --out run.csv
    python bench/bench_startup.py --json

Timings are machine- and load-dependent: compare figures taken on the same machine at the
same moment. docs/performance.md, "Start-up" has the figures of this change.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PHASES = ("interpreter", "imports", "scene", "model build", "compiled load", "integration",
          "outputs", "write", "other", "exit")

# The child of the breakdown: `flexarm simulate` (cli.main) with timers around its phases.
# Each timer's time excludes the timers nested in it (the compiled load inside integrate).
CHILD = r"""
import time; _T0 = time.time()
import json, os, sys
import flexarm_ros.cli as cli
import flexarm_ros.commands.simulate as simulate_command
import flexarm_ros.io.paths, flexarm_ros.io.tables, flexarm_ros.io.units
import flexarm_ros.sim.simulate
_T1 = time.time()
acc, stack = {}, []

def timed(owner, attr, key):
    fn = getattr(owner, attr)
    def wrapper(*a, **k):
        stack.append(0.0)
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            dt = time.perf_counter() - t
            inner = stack.pop()
            acc[key] = acc.get(key, 0.0) + dt - inner
            if stack:
                stack[-1] += dt
    setattr(owner, attr, wrapper)

S, tables = flexarm_ros.sim.simulate, flexarm_ros.io.tables
timed(simulate_command, "load", "scene")
timed(S, "Chain", "model build")
timed(S, "integrate", "integration")
timed(S, "integrate_with_contact", "integration")
timed(S, "output_columns", "outputs")
timed(S, "sensor_tables", "outputs")
timed(S, "contact_columns", "outputs")
timed(tables, "write_table", "write")
try:
    from numba.core.dispatcher import Dispatcher
    timed(Dispatcher, "_compile_for_args", "compiled load")
except ImportError:
    pass
_T2 = time.time()
rc = cli.main()      # argv None: the process's own command line, as the flexarm script
_T3 = time.time()
acc["other"] = (_T3 - _T2) - sum(acc.values())
acc.update(start=_T0, imports=_T1 - _T0, end=_T3)
with open(os.environ["BENCH_STARTUP_OUT"], "w") as fh:
    json.dump(acc, fh)
sys.exit(rc)
"""


def flexarm_command() -> list[str]:
    """The installed ``flexarm`` script beside this interpreter, else ``python -m``."""
    exe = Path(sys.executable).with_name("flexarm")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]


def _run(cmd, env, cwd) -> tuple[float, float]:
    """(wall s, CPU s of the child) of one process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, cwd=cwd)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def process_times(args, workdir, env) -> dict:
    """Best wall and CPU time of the whole warm process."""
    cmd = flexarm_command() + ["simulate", args.scene, "--duration", str(args.duration),
                               "--out", str(workdir / args.out), "--quiet"]
    _run(cmd, env, workdir)                 # the numba cache on disk, the files in the OS cache
    runs = [_run(cmd, env, workdir) for _ in range(args.repeat)]
    return {"command": " ".join(["flexarm"] + cmd[-7:]),
            "wall_s": [w for w, _ in runs], "cpu_s": [c for _, c in runs],
            "best_wall_s": min(w for w, _ in runs), "best_cpu_s": min(c for _, c in runs)}


def breakdown(args, workdir, env) -> dict:
    """Best time per phase over ``repeat`` instrumented runs (and the runs' walls)."""
    out = workdir / "phases.json"
    env = dict(env, BENCH_STARTUP_OUT=str(out))
    cmd = [sys.executable, "-c", CHILD, "simulate", args.scene, "--duration",
           str(args.duration), "--out", str(workdir / args.out), "--quiet"]
    rows = []
    for _ in range(args.repeat):
        t_launch = time.time()
        # cwd: not the source tree (``-c`` puts the cwd first on sys.path)
        subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, cwd=workdir)
        t_done = time.time()
        ph = json.loads(out.read_text())
        ph["interpreter"] = ph.pop("start") - t_launch
        ph["exit"] = t_done - ph.pop("end")
        ph["total"] = t_done - t_launch
        rows.append(ph)
    return {k: min(r.get(k, 0.0) for r in rows) for k in PHASES + ("total",)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="two_link_free")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--out", default="x.npz", help="output file name (.npz or .csv)")
    ap.add_argument("--repeat", type=int, default=5, help="runs per figure (best of)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        whole = process_times(args, workdir, env)
        phases = breakdown(args, workdir, env)
    load = os.getloadavg()[0]
    if args.json:
        print(json.dumps({"process": whole, "phases_best_s": phases, "loadavg_1min": load,
                          "cpus": os.cpu_count()}, indent=2))
        return
    print(f"{whole['command']}")
    print(f"  warm process, best of {args.repeat}: {whole['best_wall_s']:.3f} s wall, "
          f"{whole['best_cpu_s']:.3f} s CPU (walls: "
          + ", ".join(f"{w:.2f}" for w in whole["wall_s"]) + ")")
    print(f"  phases, best of {args.repeat} instrumented runs (1-min load "
          f"{load:.2f} on {os.cpu_count()} CPUs):")
    for k in PHASES:
        print(f"    {k:14s} {1e3 * phases[k]:7.1f} ms")
    print(f"    {'sum':14s} {1e3 * sum(phases[k] for k in PHASES):7.1f} ms   "
          f"(best instrumented process {1e3 * phases['total']:.1f} ms)")


if __name__ == "__main__":
    main()
