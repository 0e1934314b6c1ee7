"""``flexarm estimate BAG``: the arm's bending estimated from the bench's own topics of a
twin bag (encoder counts, accelerometer samples, the commands sent) by a Kalman filter on
the model (:mod:`flexarm_ros.estimation`), scored against the bag's ground truth where it
has one."""

from __future__ import annotations

import json
from pathlib import Path

from flexarm_ros.io.arguments import number, set_option


def add_parser(sub) -> None:
    e = sub.add_parser("estimate", help="tip deflections and position estimated from a "
                                        "bag's encoders and accelerometers")
    e.add_argument("bag", type=Path, help="a twin bag (.mcap) with encoders/counts and "
                                          "motor_driver/commands")
    e.add_argument("--scene", help="the model to estimate with (default: the scene the bag "
                                   "recorded; a rig and its model always differ)")
    e.add_argument("--sensors", choices=("all", "encoders"), default="all",
                   help="the measurements the filter reads (default all: encoders and "
                        "accelerometers)")
    e.add_argument("--process-noise", type=number, metavar="SHARE",
                   help="the model error's std as a share of the acceleration the full "
                        "command gives each coordinate (default 0.1)")
    e.add_argument("--out", type=Path, required=True, help="the estimate (.csv or .npz)")
    e.add_argument("--json", action="store_true", help="the score as JSON on stdout")
    set_option(e.add_argument_group("scene overrides (on --scene)"))
    e.set_defaults(func=main)


def main(args):
    from flexarm_ros.commands.common import Progress, set_values
    from flexarm_ros.errors import InputError
    from flexarm_ros.estimation.from_bag import UNITS, estimate_bag
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.io.tables import write_table
    out = check_output_file("--out", args.out, (".csv", ".npz"))
    if not args.bag.is_file():
        raise InputError(f"BAG: got {str(args.bag)!r}, expected an existing .mcap file")
    scene = None
    if args.scene is not None or set_values(args):
        from flexarm_ros.scene import load_scene
        from flexarm_ros.scene.overrides import with_overrides
        if args.scene is None:
            raise InputError("--set: got values without --scene, expected them with the "
                             "scene they change")
        scene = with_overrides(load_scene(args.scene), set_values(args), {})
    from flexarm_ros.io.progress import ProgressLine
    line = ProgressLine(Progress.WIDTH)
    est = estimate_bag(args.bag, scene, args.sensors, args.process_noise,
                       progress=lambda f: line.show(f"  estimating: {100 * f:5.1f} % of the "
                                                    f"bag's measurements"))
    line.clear()
    write_table(out, est.columns, {k: u for k in est.columns if (u := UNITS(k))})
    if args.json:
        print(json.dumps({"out": str(out), "score": est.score, "notes": est.notes,
                          "cpu_per_tick_us": est.cpu_per_tick_us}, indent=2))
        return 0
    print(f"{args.bag}: {len(est.columns['t'])} ticks estimated from "
          f"{'encoders and accelerometers' if args.sensors == 'all' else 'encoders'}, "
          f"{est.cpu_per_tick_us:.0f} µs of CPU per tick → {out}")
    for n in est.notes:
        print(f"  note: {n}")
    if est.score is None:
        print("  no ground_truth/coordinates and ground_truth/tip in the bag: not scored")
        return 0
    for name, s in est.score["links"].items():
        if s["rmse_of_peak"] is None:
            print(f"  {name}: no deflection in the run")
            continue
        print(f"  {name}: tip deflection RMSE {s['rmse_m']:.3g} m "
              f"({100 * s['rmse_of_peak']:.3g} % of its peak {s['peak_m']:.3g} m), "
              f"largest error {s['max_error_m']:.3g} m ({100 * s['max_error_of_peak']:.3g} %)")
    print(f"  tip position RMSE {est.score['tip_rmse_m']:.3g} m, largest error "
          f"{est.score['tip_max_error_m']:.3g} m (against ground_truth/*, which the filter "
          f"does not read)")
    return 0
