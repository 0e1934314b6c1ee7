"""Scaling of the ensemble runner (not a unit test; wall-clock figures live here only).

Measures, on this machine:

1. a bare ``flexarm simulate SCENE --duration T --quiet`` (a fresh process: interpreter,
   imports, numba cache load, model build, integration, output columns) and the same
   simulation in a warm process (``simulate()`` after a first run: what a task costs);
2. the same ensemble of ``--samples`` samples (a sweep of the base motor resistance)
   in this process (``--workers 0``) and on a local Dask cluster of 1 and 2 worker
   processes: cluster start-up, samples per second once started, and the overhead per
   task = wall per sample on 1 worker − the warm in-process simulation, and the wall per
   task of 400 empty tasks (the runner's and Dask's own cost);
3. what a Sobol study of Case 1 costs: the per-sample time of Case 1 over the
   sensitivity window (3.0 s simulated, ``examples/sensitivity_case1.yaml``) × 1000
   samples, on 1, 2 and N workers (N workers: 1000 · t_sample / (N · efficiency) + start-up,
   the efficiency measured here from 1 → 2 workers).

    python bench/bench_ensemble.py                       # ~5 min on 2 cores
    python bench/bench_ensemble.py --samples 8 --json

The machine may be shared: every figure is a best of ``--repeat`` where cheap, and the
load average is printed with the results.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np


def _bare_cli(scene, duration) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "simulate", scene, "--duration",
                    str(duration), "--quiet"], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _warm(scene, duration, repeat) -> float:
    from flexarm_ros.sim.simulate import simulate
    simulate(scene, duration)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        simulate(scene, duration)
        best = min(best, time.perf_counter() - t0)
    return best


class Timed:
    """A task that also reports the CPU seconds its process spent on it (a figure the
    other load on a shared machine does not inflate, unlike wall time)."""

    def __init__(self, model):
        self.model = model
        self.columns = model.columns + ["cpu_s"]

    def warm_up(self):
        self.model.warm_up()

    def __call__(self, a):
        c0 = time.process_time()
        r = self.model(a)
        r["metrics"]["cpu_s"] = time.process_time() - c0
        return r


def _ensemble(scene, assignments, duration, workers, repeat=1):
    from flexarm_ros.ensemble.metrics import resolve_metrics
    from flexarm_ros.ensemble.runner import SceneModel, open_executor, run_ensemble
    model = Timed(SceneModel(scene, resolve_metrics([], scene), duration))
    t0 = time.perf_counter()
    ex = open_executor(workers, warm_up=model.warm_up)
    start = time.perf_counter() - t0
    try:
        run = np.inf
        for _ in range(repeat):                  # best of: the others measure the load
            t1 = time.perf_counter()
            table = run_ensemble(scene, assignments, model=model, executor=ex)
            run = min(run, time.perf_counter() - t1)
    finally:
        t2 = time.perf_counter()
        ex.close()
        stop = time.perf_counter() - t2
    assert all(r["status"] == "ok" for r in table.rows), table.rows
    cpu = float(np.mean([r["cpu_s"] for r in table.rows]))
    return {"workers": workers, "startup_s": start, "run_s": run, "close_s": stop,
            "samples": len(assignments), "samples_per_s": len(assignments) / run,
            "wall_per_sample_s": run / len(assignments), "cpu_per_sample_s": cpu}


def _task_overhead(workers, n=400):
    """Wall per task of a task that does nothing (the Ishigami function): the runner's
    and Dask's own cost per task (submit, schedule, run, gather, row)."""
    from flexarm_ros.ensemble.runner import open_executor, run_ensemble
    from flexarm_ros.testing.analytic_models import Ishigami
    a = [{"x1": 0.1 * k, "x2": 0.2, "x3": 0.3} for k in range(n)]
    with open_executor(workers) as ex:
        t0 = time.perf_counter()
        run_ensemble(None, a, model=Ishigami(), executor=ex)
        return (time.perf_counter() - t0) / n


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="two_link_case1")
    ap.add_argument("--duration", type=float, default=0.5,
                    help="simulated s per sample of the scaling ensemble")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sobol-duration", type=float, default=3.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    from flexarm_ros.ensemble.designs import make_design, parse_param
    from flexarm_ros.scene import load_scene
    scene = load_scene(args.scene)
    out = {"scene": args.scene, "duration_s": args.duration, "cpus": os.cpu_count(),
           "load_before": os.getloadavg()}
    out["bare_cli_s"] = min(_bare_cli(args.scene, args.duration) for _ in range(2))
    out["warm_simulate_s"] = _warm(scene, args.duration, args.repeat)
    p = parse_param("links[0].joint.drive.resistance=0.98:1.19", scene)
    a = make_design([p], "grid", args.samples)
    runs = [_ensemble(scene, a, args.duration, w, args.repeat) for w in (0, 1, 2)]
    out["ensembles"] = runs
    one = runs[1]
    out["overhead_per_task_s"] = one["wall_per_sample_s"] - out["warm_simulate_s"]
    out["empty_task_s"] = {w: _task_overhead(w) for w in (0, 1, 2)}
    out["speedup_2_workers"] = runs[2]["samples_per_s"] / runs[1]["samples_per_s"]
    # Case 1 over the sensitivity window: one sample, warm
    from flexarm_ros.ensemble.spec import load_spec
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    spec = load_spec(os.path.join(root, "examples", "sensitivity_case1.yaml"))
    base = spec.base_scene()
    t_case1 = _warm(base, args.sobol_duration, 1)
    eff = out["speedup_2_workers"] / 2.0
    per_task = t_case1 + max(out["overhead_per_task_s"], 0.0)
    start = runs[2]["startup_s"]
    out["sobol_1000"] = {
        "case1_sample_s": t_case1, "per_task_s": per_task, "efficiency_2_workers": eff,
        "d": len(spec.unknowns),
        "runs_for_1000": 1000,
        "base_N_for_about_1000": 1000 // (len(spec.unknowns) + 2),
        "wall_s_1_worker": 1000 * per_task + runs[1]["startup_s"],
        "wall_s_2_workers": 1000 * per_task / (2 * eff) + start,
        "wall_s_per_N_workers": "1000 * per_task_s / (N * efficiency) + startup",
        "wall_s_32_workers": 1000 * per_task / (32 * eff) + start,
        "cpu_hours": 1000 * per_task / 3600.0}
    out["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"{args.scene}, {args.duration} s simulated per sample, {out['cpus']} CPUs, "
          f"load {out['load_before'][0]:.2f} → {out['load_after'][0]:.2f}")
    print(f"  bare `flexarm simulate` (new process): {out['bare_cli_s']:.2f} s; warm "
          f"simulate(): {out['warm_simulate_s']:.3f} s")
    for r in runs:
        print(f"  workers {r['workers']}: start-up {r['startup_s']:.2f} s, {r['samples']} "
              f"samples in {r['run_s']:.2f} s = {r['samples_per_s']:.3g} samples/s "
              f"({r['wall_per_sample_s']:.3f} s each, {r['cpu_per_sample_s']:.3f} CPU s in "
              f"the task), close {r['close_s']:.2f} s")
    print(f"  overhead per task (1 worker − warm simulate): "
          f"{1e3 * out['overhead_per_task_s']:.1f} ms; an empty task: "
          + ", ".join(f"{1e3 * v:.2f} ms on {w} workers" for w, v in
                      out["empty_task_s"].items())
          + f"; 2 workers / 1 worker = {out['speedup_2_workers']:.2f}x")
    s = out["sobol_1000"]
    print(f"  Case 1, {args.sobol_duration} s: {s['case1_sample_s']:.2f} s per sample; 1000 "
          f"samples: {s['wall_s_1_worker'] / 60:.1f} min on 1 worker, "
          f"{s['wall_s_2_workers'] / 60:.1f} min on 2, {s['wall_s_32_workers'] / 60:.1f} min "
          f"on 32 ({s['cpu_hours']:.2f} CPU hours; N workers: 1000 × {s['per_task_s']:.2f} s "
          f"/ (N × {s['efficiency_2_workers']:.2f}) + start-up)")


if __name__ == "__main__":
    main()
