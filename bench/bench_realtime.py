"""Throughput of the ROS 2 twin (not a unit test).

Seed 000 rates (scene ``two_link_case1``: 1 kHz control and encoders, four accelerometers
at 4 kHz batched four samples per message):

1. the plant alone: :class:`~flexarm_ros.twin.cosim.Lockstep` ticks per second (no ROS),
   and the simulator node's tick split into physics (``SimulatorCore.step``), building the
   messages (``outputs``), converting them to rclpy objects and publishing them (no
   subscriber) — the floor of a realtime tick before any other node runs;
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
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin.cosim import Lockstep
    ls = Lockstep(load_scene(scene_name))
    ls.tick()                                     # compile / warm up
    t0 = time.perf_counter()
    for _ in range(ticks):
        ls.tick()
    return ticks / (time.perf_counter() - t0)


def simulator_tick_budget(scene_name: str, ticks: int) -> dict:
    """Mean µs per simulator tick: physics, message dicts, rclpy objects, publish."""
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from flexarm_ros.scene import load_scene
    from flexarm_ros.nodes import _common as C
    from flexarm_ros.nodes._msgconv import to_msg
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.cores import SimulatorCore
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("tick_budget", context=ctx)
        core = SimulatorCore(load_scene(scene_name))
        tau = np.zeros(len(core.names))
        core.outputs()
        core.step(tau)                                # compile / warm up
        pubs = {t: C.publisher(node, T.TYPES[t], t)
                for t in [o[0] for o in core.outputs()] + list(core.groups)}
        acc = dict.fromkeys(("physics", "messages", "to_msg", "publish"), 0.0)
        for _ in range(ticks):
            t0 = time.perf_counter()
            core.step(tau)
            t1 = time.perf_counter()
            outs = core.outputs()
            t2 = time.perf_counter()
            msgs = [(topic, to_msg(tp, d)) for topic, tp, d in outs]
            t3 = time.perf_counter()
            for topic, m in msgs:
                pubs[topic].publish(m)
            t4 = time.perf_counter()
            for key, dt in zip(acc, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                acc[key] += dt
        out = {k: 1e6 * v / ticks for k, v in acc.items()}
        out["messages_per_tick"] = len(outs)
        out["total"] = sum(v for k, v in out.items() if k != "messages_per_tick")
        node.destroy_node()
        return out
    finally:
        rclpy.shutdown(context=ctx)


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
    from flexarm_ros.nodes import environment
    env = environment.private_graph()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plant = plant_only(args.scene, int(args.lockstep_seconds * 1000))
        rows.append({"mode": "plant only (cosim)", "ticks_per_s": plant,
                     "real_time_factor": plant / 1000.0})
        budget = simulator_tick_budget(args.scene, int(args.lockstep_seconds * 1000))
        for rec in (None, Path(tmp) / "lockstep.mcap"):
            rows.append(ros_run(args.scene, "lockstep", args.lockstep_seconds, rec,
                                executor=args.executor))
        rows.append(ros_run(args.scene, "realtime", float("inf"), Path(tmp) / "realtime.mcap",
                            wall_limit=args.seconds, executor=args.executor))
    out = {"scene": args.scene, "ros_domain_id": env["ROS_DOMAIN_ID"], "runs": rows,
           "simulator_tick_us": budget}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"scene {args.scene} (control 1 kHz), {args.executor} executor")
    b = budget
    print(f"  simulator tick (no subscriber): {b['total']:.0f} µs = physics {b['physics']:.0f}"
          f" + messages {b['messages']:.0f} + to_msg {b['to_msg']:.0f} + publish "
          f"{b['publish']:.0f} ({b['messages_per_tick']} messages)")
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
