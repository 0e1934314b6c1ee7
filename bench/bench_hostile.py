"""The issue 12 hostile-user runs, measured (not a unit test): ``flexarm run SCENE
--processes --duration D`` in lockstep while this process publishes one hostile payload at
~1 kHz of wall time on one topic, per case. Reports per case the tip position at the end
against the clean run (a clean ``--processes`` run and the batch co-simulation), the
largest log time in the bag, the non-finite numbers in it, what the recorder filed under
``diagnostics/rejected``, the exit status and the run summary line.

    python bench/bench_hostile.py                       # two_link_case1, 3 s, every case
    python bench/bench_hostile.py --duration 1 --cases effort_nan command_1e300
    python bench/bench_hostile.py --json

DDS stays on loopback; the ROS domain is 1 + pid mod 101 unless ROS_DOMAIN_ID is set.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

NAN, INF = math.nan, math.inf
#: case -> (topic, message type, payload)
CASES = {
    "effort_nan": ("effort_controller/commands", "F", [NAN, NAN]),
    "command_nan": ("motor_driver/commands", "F", [NAN, NAN]),
    "command_short": ("motor_driver/commands", "F", [1.0]),
    "effort_inf": ("effort_controller/commands", "F", [INF, -INF]),
    "command_1e300": ("motor_driver/commands", "F", [1e300, -1e300]),
    "effort_1e300": ("effort_controller/commands", "F", [1e300, -1e300]),
    "command_string": ("motor_driver/commands", "S", "[nan, nan]"),
    "effort_int32": ("effort_controller/commands", "I", [1, 2]),
    "effort_valid_second": ("effort_controller/commands", "F", [5.0, 5.0]),
    "command_valid_second": ("motor_driver/commands", "F", [3.0, -3.0]),
}
NS = "/flexarm"


def _flexarm(scene, duration, out):
    exe = Path(sys.executable).with_name("flexarm")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "flexarm_ros.cli"]
    return subprocess.Popen(cmd + ["run", scene, "--duration", str(duration), "--record",
                                   str(out), "--quiet", "--processes"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _hostile(case):
    """A node in its own context publishing the case's payload every 1 ms of wall time:
    (spin function, close function, sent counter)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray, Int32MultiArray, String

    from flexarm_ros.nodes.common import QOS
    topic, kind, payload = CASES[case]
    cls = {"F": Float64MultiArray, "I": Int32MultiArray, "S": String}[kind]
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("hostile", namespace=NS, context=ctx)
    pub = node.create_publisher(cls, topic, QOS)
    sent = [0]

    def fire():
        pub.publish(cls(data=payload))
        sent[0] += 1
    node.create_timer(0.001, fire)
    exe = SingleThreadedExecutor(context=ctx)
    exe.add_node(node)

    def close():
        node.destroy_node()
        exe.shutdown()
        rclpy.shutdown(context=ctx)
    return (lambda: exe.spin_once(timeout_sec=0.01)), close, sent


def _measure(bag_path):
    from flexarm_ros.bag import read_bag, to_dict
    bag = read_bag(bag_path)
    tip = bag[f"{NS}/ground_truth/tip"][-1][1].point
    nonfinite = 0
    for topic in bag.topics:
        for _, m in bag[topic]:
            d = to_dict(m)
            stack = [d]
            while stack:
                x = stack.pop()
                if isinstance(x, float):
                    nonfinite += not math.isfinite(x)
                elif isinstance(x, dict):
                    stack.extend(x.values())
                elif isinstance(x, (list, tuple)):
                    stack.extend(x)
    diag = {}
    for _, m in bag.messages.get(f"{NS}/diagnostics/rejected", []):
        e = json.loads(m.data)
        key = f"{e['topic']}: {e['reason']}"
        diag[key] = diag.get(key, 0) + 1
    return {"tip": (tip.x, tip.y), "last_log_time_s": max(t for tp in bag.topics
                                                          for t, _ in bag[tp]) * 1e-9,
            "non_finite_numbers": nonfinite, "diagnostics": diag, "truncated": bag.truncated,
            "clock_messages": len(bag["/clock"])}


def run_case(scene, duration, case, tmp):
    out = Path(tmp) / f"{case or 'clean'}.mcap"
    spin, close, sent = (None, None, [0]) if case is None else _hostile(case)
    t0 = time.monotonic()
    proc = _flexarm(scene, duration, out)
    try:
        while proc.poll() is None:
            if spin is not None:
                spin()
            else:
                time.sleep(0.05)
        stdout, stderr = proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
        if close is not None:
            close()
    row = {"case": case or "clean", "exit": proc.returncode, "sent": sent[0],
           "wall_s": time.monotonic() - t0, "summary": stdout.strip().splitlines()[-1:],
           "tracebacks": stderr.count("Traceback")}
    row.update(_measure(out))
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="two_link_case1")
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from flexarm_ros.nodes import environment
    environment.private_graph()           # loopback, a private domain (was a stale import)
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.cosim import cosimulate
    ref = cosimulate(load_scene(args.scene), args.duration).topic(T.GT_TIP)[-1].data["point"]
    ref = (ref["x"], ref["y"])
    rows = []
    with tempfile.TemporaryDirectory(prefix="flexarm_hostile_") as tmp:
        clean = run_case(args.scene, args.duration, None, tmp)
        rows.append(clean)
        for case in args.cases:
            rows.append(run_case(args.scene, args.duration, case, tmp))
            if not args.json:
                print(f"  {case} done", file=sys.stderr)
    for r in rows:
        r["tip_vs_clean_mm"] = 1e3 * math.dist(r["tip"], clean["tip"])
        r["tip_vs_cosim_mm"] = 1e3 * math.dist(r["tip"], ref)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{args.scene}, lockstep --processes, {args.duration} s; hostile payload at ~1 kHz")
    print(f"{'case':22} {'exit':>4} {'sent':>6} {'tip vs clean mm':>16} {'vs cosim mm':>12} "
          f"{'last log s':>10} {'non-finite':>10}  diagnostics/rejected")
    for r in rows:
        diag = "; ".join(f"{k} {n}" for k, n in sorted(r["diagnostics"].items())) or "-"
        print(f"{r['case']:22} {r['exit']:>4} {r['sent']:>6} {r['tip_vs_clean_mm']:>16.3g} "
              f"{r['tip_vs_cosim_mm']:>12.3g} {r['last_log_time_s']:>10.4f} "
              f"{r['non_finite_numbers']:>10}  {diag}")
        if r["tracebacks"]:
            print(f"{'':22} {r['tracebacks']} traceback(s) on stderr")
    return 0


if __name__ == "__main__":
    sys.exit(main())
