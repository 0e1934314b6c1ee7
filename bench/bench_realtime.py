"""Throughput of the ROS 2 twin (not a unit test).

Seed 000 rates (scene ``two_link_case1``: 1 kHz control and encoders, four accelerometers
at 4 kHz batched four samples per message, wall, recorder on):

1. the plant alone: :class:`~flexarm_ros.twin.cosim.Lockstep` ticks per second (no ROS),
   and the simulator node's tick split into physics (``SimulatorCore.step``), its wire
   bytes built from the values (``outputs(build=CdrBuilder())``) and publishing them (no
   subscriber) — the floor of a realtime tick before any other node runs — with the
   former path (message dicts, then ``encode_cdr``) timed beside it;
2. ``lockstep`` through ROS, all nodes on one executor: ticks per second, with and
   without the recorder, with the twin's executor (``TwinExecutor``) and the nodes'
   messages through the intra-process bus (the default) or through DDS, and with rclpy's
   SingleThreadedExecutor (DDS), measured in one run;
3. ``realtime`` with the recorder for ``--seconds`` of simulated time in each layout
   (``--layout split``: the simulator in a process of its own, the default; ``one``;
   ``processes``): real-time factor, ticks late by more than half a period, lateness
   p50/p99/max, and the messages the recorder lost (published minus recorded, per topic);
   ``--rate 2000`` repeats it at 2 kHz control;
   Each realtime row runs with the pacing thread under SCHED_FIFO 50
   (``--thread-priority 50``) and at normal priority (the default), so the two are
   measured in one run;
4. the host's floor (``--floor``, on by default): the simulator's own pacing
   (:class:`~flexarm_ros.twin.pacing.Pacer`) with nothing but a busy loop of W µs per
   tick in place of the twin (W = 0, 250, 500, 750 at 1 kHz), for ``--floor-seconds``
   each: the share of ticks this machine starts on time when the work is known and
   fixed. No twin can do better than its work's row; it separates what the twin costs
   from what the host's scheduler does.

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


def cpu_times() -> list[int] | None:
    """The machine's CPU time counters (``/proc/stat``'s ``cpu`` line; None off Linux)."""
    try:
        with open("/proc/stat") as f:
            return [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None


def steal_share(before, after) -> float | None:
    """The share of CPU time the hypervisor took from this machine between two
    :func:`cpu_times` (``steal``, the 8th counter): time no scheduling policy inside the
    machine can get back — a tick due then starts late whatever its priority."""
    if not before or not after or len(before) < 8:
        return None
    d = [a - b for a, b in zip(after, before)]
    total = sum(d[:8])
    return d[7] / total if total > 0 else None


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
    """Mean µs per simulator tick: physics, the node's wire bytes built straight from the
    values (``outputs(build=CdrBuilder())``, ``wire``), publish; and, for comparison in the
    same run on a second core stepped alike, the former path: message dicts
    (``messages``) then CDR (``encode``). ``total`` = physics + wire + publish."""
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from flexarm_ros.scene import load_scene
    from flexarm_ros.nodes import common as C
    from flexarm_ros.bag.cdr_fixed import CdrBuilder
    from flexarm_ros.bag.writer import encode_cdr
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.cores import SimulatorCore
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("tick_budget", context=ctx)
        core = SimulatorCore(load_scene(scene_name))
        old = SimulatorCore(load_scene(scene_name))
        build = CdrBuilder()
        tau = np.zeros(len(core.names))
        for c in (core, old):
            c.outputs()
            c.step(tau)                               # compile / warm up
        pubs = {t: C.publisher(node, T.TYPES[t], t)
                for t in [o[0] for o in core.outputs()] + list(core.groups)}
        old.outputs()
        acc = dict.fromkeys(("physics", "wire", "publish", "messages", "encode"), 0.0)
        for _ in range(ticks):
            t0 = time.perf_counter()
            core.step(tau)
            t1 = time.perf_counter()
            outs = core.outputs(build=build)
            t2 = time.perf_counter()
            for topic, _, m in outs:
                pubs[topic].publish(m)
            t3 = time.perf_counter()
            old.step(tau)
            t4 = time.perf_counter()
            dicts = old.outputs()
            t5 = time.perf_counter()
            [encode_cdr(tp, d, validate=False) for _, tp, d in dicts]
            t6 = time.perf_counter()
            for key, dt in zip(acc, (t1 - t0, t2 - t1, t3 - t2, t5 - t4, t6 - t5)):
                acc[key] += dt
        out = {k: 1e6 * v / ticks for k, v in acc.items()}
        out["messages_per_tick"] = len(outs)
        out["total"] = out["physics"] + out["wire"] + out["publish"]
        node.destroy_node()
        return out
    finally:
        rclpy.shutdown(context=ctx)


def lockstep_run(scene_name: str, duration: float, record: Path | None,
                 executor: str = "twin", intraprocess: bool = True) -> dict:
    """One in-process lockstep run of ``duration`` simulated s: ticks per wall second
    (``intraprocess``: the nodes' messages through the process's bus, else DDS)."""
    from flexarm_ros.run import InProcessGraph
    g = InProcessGraph(scene_name, "lockstep", duration, record, executor=executor,
                       intraprocess=intraprocess)
    try:
        sim = g["simulator"]
        if not g.spin_until(lambda: sim.started, 60):
            raise RuntimeError("the graph did not start (subscriptions not matched)")
        g.spin_until(lambda: sim.finished)
        sim.finish(g.executor)
        if record:
            g.spin_until(g.recorded_all, 30)
        wall = sim.t_wall_end - sim.t_wall0
        return {"mode": "lockstep", "executor": executor, "record": bool(record),
                "intraprocess": intraprocess and executor == "twin",
                "sim_s": sim.core.t, "ticks": sim.core.k, "wall_s": wall,
                "ticks_per_s": sim.core.k / wall, "real_time_factor": sim.core.t / wall}
    finally:
        g.close()


def realtime_run(scene, seconds: float, record: Path, layout: str,
                 thread_priority: int | None = None) -> dict:
    """``flexarm run SCENE --mode realtime --layout LAYOUT --thread-priority P`` for
    ``seconds`` of simulated time: the run summary plus the recorder's losses per topic
    (published − recorded)."""
    from flexarm_ros.run import run
    before = cpu_times()
    res = run(scene, seconds, "realtime", record=record, layout=layout, progress=False,
              simulator={"thread_priority": thread_priority}).to_json()
    res["steal_share"] = steal_share(before, cpu_times())
    res["thread_priority"] = thread_priority
    lost = {}
    for topic, n in (res["published"] or {}).items():      # absolute names, as recorded
        got = (res["recorded"] or {}).get(topic, 0)
        if got != n:
            lost[topic] = n - got
    res["lost"] = lost
    res["ticks_per_s"] = res["ticks"] / res["sim_time_s"] * res["real_time_factor"]
    return res


def host_floor(seconds: float, work_us: float, rate_hz: float = 1000.0,
               thread_priority: int = 0) -> dict:
    """The twin's pacing loop with a busy loop of ``work_us`` µs per tick in place of the
    twin's tick (no ROS, no allocation), in a thread of its own scheduled as the
    simulator's pacing thread is at ``thread_priority``: lateness statistics as in a
    realtime run."""
    import threading
    from flexarm_ros.twin.pacing import Pacer, realtime_scheduling
    out = {}

    def loop():
        granted, how = realtime_scheduling(thread_priority)
        pacer = Pacer(1.0 / rate_hz, late_bound=0.1, late_policy="slow")
        n = int(round(seconds * rate_hz))
        clock = time.perf_counter
        pacer.start()
        t0 = time.monotonic()
        for _ in range(n):
            pacer.wait()
            end = clock() + work_us * 1e-6
            while clock() < end:
                pass
        wall = time.monotonic() - t0
        out.update(pacer.summary())
        out.update({"work_us": work_us, "rate_hz": rate_hz, "scheduling": how,
                    "thread_priority": thread_priority,
                    "real_time_factor": n / rate_hz / wall,
                    "on_time_share": 1.0 - out["late_ticks"] / max(out["ticks"], 1)})
    th = threading.Thread(target=loop, name="floor")
    before = cpu_times()
    th.start()
    th.join()
    out["steal_share"] = steal_share(before, cpu_times())
    return out


def scene_at_rate(scene_name: str, rate_hz: float, tmp: Path) -> str:
    """A copy of the scene file with ``control.rate_hz`` set."""
    import yaml
    from flexarm_ros.scene import resolve_scene_path
    data = yaml.safe_load(resolve_scene_path(scene_name).read_text())
    data.setdefault("control", {})["rate_hz"] = rate_hz
    path = tmp / f"{scene_name}_{int(rate_hz)}hz.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def _steal(r) -> str:
    return "" if r.get("steal_share") is None else \
        f"; hypervisor steal {100 * r['steal_share']:.1f} %"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0,
                    help="simulated seconds of each realtime run (default 60)")
    ap.add_argument("--lockstep-seconds", type=float, default=2.0,
                    help="simulated seconds of each lockstep run (default 2)")
    ap.add_argument("--scene", default="two_link_case1")
    ap.add_argument("--rate", type=float, action="append", default=None,
                    help="control rates (Hz) of the realtime runs (default: the scene's, "
                         "then 2000)")
    ap.add_argument("--layout", action="append", choices=("one", "split", "processes"),
                    help="the realtime runs' layouts (default: split, one, processes)")
    ap.add_argument("--thread-priority", type=int, action="append", default=None,
                    help="the pacing thread's SCHED_FIFO priorities to run each realtime "
                         "and floor row with (default 50, then 0: normal "
                         "scheduling, the twin's default)")
    ap.add_argument("--no-lockstep", action="store_true", help="realtime runs only")
    ap.add_argument("--floor-seconds", type=float, default=10.0,
                    help="seconds of each host-floor run (0: none; default 10)")
    ap.add_argument("--floor-work", type=float, action="append", default=None,
                    help="µs of busy work per tick of the host-floor runs "
                         "(default 0, 250, 500, 750)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from flexarm_ros.nodes import environment
    env = environment.private_graph()
    lockstep, realtime, floor = [], [], []
    priorities = args.thread_priority or [50, 0]
    for prio in priorities:
        for work in ((args.floor_work or [0.0, 250.0, 500.0, 750.0]) if args.floor_seconds
                     else ()):
            floor.append(host_floor(args.floor_seconds, work, thread_priority=prio))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        plant = plant_only(args.scene, int(args.lockstep_seconds * 1000))
        budget = simulator_tick_budget(args.scene, int(args.lockstep_seconds * 1000))
        for executor, bus in (() if args.no_lockstep else
                              (("twin", True), ("twin", False), ("single", False))):
            for rec in (None, tmp / "lockstep.mcap"):
                lockstep.append(lockstep_run(args.scene, args.lockstep_seconds, rec, executor,
                                             bus))
        for rate in args.rate or [None, 2000.0]:
            scene = args.scene if rate is None else scene_at_rate(args.scene, rate, tmp)
            for layout in args.layout or ["split", "one", "processes"]:
                for prio in priorities:
                    r = realtime_run(scene, args.seconds, tmp / "realtime.mcap", layout, prio)
                    r["rate_hz"] = rate or "scene"
                    realtime.append(r)
    out = {"scene": args.scene, "ros_domain_id": env["ROS_DOMAIN_ID"],
           "plant_only_ticks_per_s": plant, "simulator_tick_us": budget,
           "lockstep": lockstep, "realtime": realtime, "host_floor": floor}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    b = budget
    print(f"scene {args.scene}")
    print(f"  plant + controller + driver cores, no ROS: {plant:.0f} ticks/s")
    print(f"  simulator tick (no subscriber): {b['total']:.0f} µs = physics {b['physics']:.0f}"
          f" + wire bytes {b['wire']:.0f} + publish {b['publish']:.0f} "
          f"({b['messages_per_tick']} messages; the former dicts + encode: "
          f"{b['messages']:.0f} + {b['encode']:.0f})")
    for r in floor:
        print(f"  host floor, {r['scheduling'].split(' (')[0]:<13}, {r['work_us']:4.0f} µs busy "
              f"per 1 ms tick: RTF "
              f"{r['real_time_factor']:.3f}, {100 * r['on_time_share']:.1f} % on time, lateness "
              f"p50 {r['lateness_p50_s'] * 1e3:.3f} / p99 {r['lateness_p99_s'] * 1e3:.2f} / max "
              f"{r['lateness_max_s'] * 1e3:.2f} ms" + _steal(r))
    for r in lockstep:
        print(f"  lockstep, {r['executor']:<6} executor, "
              f"{'bus' if r['intraprocess'] else 'DDS'}, "
              f"{'recorder on ' if r['record'] else 'no recorder'}: {r['ticks_per_s']:6.0f} "
              f"ticks/s")
    for r in realtime:
        how = r["layout"]
        lost = sum(r["lost"].values())
        sched = (r.get("scheduling") or "?").split(" (")[0]
        print(f"  realtime {r['rate_hz']} Hz, {how:<9}, {sched:<13}: RTF "
              f"{r['real_time_factor']:.3f}, "
              f"{r['late_ticks']} of {r['ticks']} ticks late "
              f"({100 * (1 - r['late_ticks'] / r['ticks']):.1f} % on time), lateness p50 "
              f"{r['lateness_p50_s'] * 1e3:.2f} / p99 {r['lateness_p99_s'] * 1e3:.2f} / max "
              f"{r['lateness_max_s'] * 1e3:.2f} ms, {lost} messages lost by the recorder"
              + _steal(r))
        if r.get("cpu_ms_per_tick"):
            print("      CPU per tick: " + ", ".join(
                f"{k} {v:.2f}" for k, v in sorted(r["cpu_ms_per_tick"].items(),
                                                  key=lambda kv: -kv[1]))
                  + f" ms = {r['cpu_ms_per_tick_total']:.2f} ms, "
                  f"{100 * r['cpu_share']:.0f} % of {r['cpus_available']} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
