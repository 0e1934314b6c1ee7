"""Throughput of the ROS 2 twin (not a unit test).

Seed 000 rates (scene ``two_link_case1``: 1 kHz control and encoders, four accelerometers
at 4 kHz batched four samples per message):

1. the plant alone: :class:`~flexarm_ros.twin.cosim.Lockstep` ticks per second (no ROS);
2. ``lockstep`` through ROS, all nodes on one executor: ticks per second, with and
   without the recorder;
3. ``realtime`` with the recorder for ``--seconds`` of wall clock: real-time factor and
   overruns (ticks that started more than one control period behind the wall-clock
   schedule).

    python bench/bench_realtime.py                  # 60 s of realtime (the issue's run)
    python bench/bench_realtime.py --seconds 5      # shorter
    python bench/bench_realtime.py --json

DDS stays on loopback; the ROS domain is 1 + pid mod 101 unless ROS_DOMAIN_ID is set.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def plant_only(scene_name: str, ticks: int) -> float:
    from flexarm_ros.model.scene import load_scene
    from flexarm_ros.twin.cosim import Lockstep
    ls = Lockstep(load_scene(scene_name))
    ls.tick()                                     # compile / warm up
    t0 = time.perf_counter()
    for _ in range(ticks):
        ls.tick()
    return ticks / (time.perf_counter() - t0)


def ros_run(scene_name: str, mode: str, duration: float, record: Path | None,
            wall_limit: float | None = None, executor: str = "single") -> dict:
    """One in-process run: ``duration`` simulated s (inf: until ``wall_limit`` s)."""
    from flexarm_ros.run import InProcessGraph
    g = InProcessGraph(scene_name, mode, duration, record, executor=executor)
    try:
        sim = g["simulator"]
        if not g.spin_until(lambda: sim.started, 60):
            raise RuntimeError("the graph did not start (subscriptions not matched)")
        g.spin_until(lambda: sim.finished, timeout=wall_limit)
        sim.halt()
        if record:
            g.spin_until(g.recorded_all, 30)
        wall = sim.t_wall_end - sim.t_wall0
        return {"mode": mode, "executor": executor, "record": bool(record), "sim_s": sim.core.t,
                "ticks": sim.core.k, "wall_s": wall, "ticks_per_s": sim.core.k / wall,
                "real_time_factor": sim.core.t / wall, "overruns": sim.overruns,
                "rejected_commands": g["motor_driver"].rejected}
    finally:
        g.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0,
                    help="wall-clock seconds of the realtime run (default 60)")
    ap.add_argument("--lockstep-seconds", type=float, default=1.0,
                    help="simulated seconds of each lockstep run (default 1)")
    ap.add_argument("--scene", default="two_link_case1")
    ap.add_argument("--executor", choices=("single", "events"), default="single",
                    help="rclpy executor of the ROS runs (events: the experimental "
                         "EventsExecutor)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from flexarm_ros.run import ros_environment
    env = ros_environment()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plant = plant_only(args.scene, int(args.lockstep_seconds * 1000))
        rows.append({"mode": "plant only (cosim)", "ticks_per_s": plant,
                     "real_time_factor": plant / 1000.0})
        for rec in (None, Path(tmp) / "lockstep.mcap"):
            rows.append(ros_run(args.scene, "lockstep", args.lockstep_seconds, rec,
                                executor=args.executor))
        rows.append(ros_run(args.scene, "realtime", float("inf"), Path(tmp) / "realtime.mcap",
                            wall_limit=args.seconds, executor=args.executor))
    out = {"scene": args.scene, "ros_domain_id": env["ROS_DOMAIN_ID"], "runs": rows}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"scene {args.scene} (control 1 kHz), {args.executor} executor")
    for r in rows:
        extra = ""
        if "wall_s" in r:
            extra = (f", {r['sim_s']:.3f} s simulated in {r['wall_s']:.2f} s wall"
                     + (", recorder on" if r["record"] else ", no recorder"))
        if r["mode"] == "realtime":
            extra += f", {r['overruns']} overruns of {r['ticks']} ticks"
        print(f"  {r['mode']:<20} {r['ticks_per_s']:8.0f} ticks/s  real-time factor "
              f"{r['real_time_factor']:.3f}{extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
