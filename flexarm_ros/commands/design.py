"""``flexarm design``: vibration control designed on the scene's own position loop
(:mod:`flexarm_ros.control.design`): its modes at the move's target pose and an input
shaper on the target step, written as a scene every command runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from flexarm_ros.commands.common import load, scene_arg, set_values
from flexarm_ros.io.arguments import integer, set_option


def add_parser(sub) -> None:
    from flexarm_ros.control.shapers import SHAPERS
    d = sub.add_parser("design", help="input shaper or LQG designed on the scene's position "
                                      "loop")
    scene_arg(d)
    how = d.add_mutually_exclusive_group(required=True)
    how.add_argument("--shaper", choices=SHAPERS,
                   help="zv, zvd, zvdd or ei (extra-insensitive, 5 %% at the design "
                        "frequency) on each mode that carries the last link's deflection in "
                        "the move (convolved)")
    how.add_argument("--lqg", action="store_true",
                     help="LQG in place of the joint PD: python-control's dlqr and dlqe on "
                          "the plant sampled at the control rate, estimated from the encoder "
                          "angles")
    d.add_argument("--weights", metavar="KEY=V,...",
                   help="--lqg: Bryson scales angle=rad, deflection=m, rate=rad/s, "
                        "voltage=V (default: 2 %% of the move, 1 mm, 10 rad/s, and the "
                        "largest voltage whose first command stays within the PD's)")
    d.add_argument("--modes", type=integer, metavar="K",
                   help="shape the K lowest oscillating modes of the loop instead")
    d.add_argument("--out", type=Path, required=True,
                   help="the scene to write (.yaml): this scene with control.shaper or "
                        "control.lqg set")
    set_option(d.add_argument_group("scene overrides"))
    d.set_defaults(func=main)


def main(args):
    import yaml
    from flexarm_ros import __version__
    from flexarm_ros.control.design import require_position, shaper_record
    from flexarm_ros.control.lqg import lqg_for_core
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.scene.keys import scene_mapping
    from flexarm_ros.scene.loading import load_scene_dict
    from flexarm_ros.twin.cores import ControllerCore
    out = check_output_file("--out", args.out, (".yaml", ".yml"))
    if args.modes is not None and args.modes < 1:
        raise InputError(f"--modes: got {args.modes}, expected an integer >= 1")
    scene = load(args)
    require_position(scene)
    if args.weights is not None and not args.lqg:
        raise InputError(f"--weights: got {args.weights!r} with --shaper, expected it with "
                         f"--lqg only")
    if args.lqg and args.modes is not None:
        raise InputError(f"--modes: got {args.modes} with --lqg, expected it with --shaper "
                         f"only (the LQG acts on every state)")
    ctl = ControllerCore(scene)
    data = scene_mapping(scene)
    if args.lqg:
        record, lqg = lqg_for_core(scene, ctl, args.weights, __version__)
        data["name"] = f"{scene.name}_lqg"
        data["control"]["lqg"] = record
        what, design = "LQG", record["design"]
    else:
        record, modes = shaper_record(scene, args.shaper, ctl.q_goal, ctl.q_start,
                                      args.modes, __version__)
        data["name"] = f"{scene.name}_{args.shaper}"
        data["control"]["shaper"] = record
        what, design = "an input shaper", record["design"]
    load_scene_dict(data)                                  # what is written loads
    head = (f"# {scene.name} with {what}, written by flexarm design "
            f"{__version__}\n# {design}\n"
            + (f"# --set: {set_values(args)}\n" if set_values(args) else ""))
    out.write_text(head + yaml.safe_dump(data, sort_keys=False, allow_unicode=True),
                   encoding="utf-8")
    if args.lqg:
        w = record["weights"]
        print(f"{scene.name}: LQG on {len(record['states'])} states at the target pose, "
              f"weights angle {w['angle']:.4g} rad, deflection {w['deflection']:.4g} m, "
              f"rate {w['rate']:.4g} rad/s, voltage {w['voltage']:.4g} V")
        for name, poles in (("regulator", lqg.poles_regulator),
                            ("estimator", lqg.poles_estimator)):
            s = np.log(poles.astype(complex)) * scene.control.rate_hz
            slow = s[np.argmax(s.real)]
            print(f"  {name}: slowest pole {abs(slow) / (2 * math.pi):.4g} Hz, "
                  f"ζ {-slow.real / max(abs(slow), 1e-300):.3g} (time constant "
                  f"{-1.0 / slow.real:.3g} s)")
        print(f"  → {out}")
        return 0
    times = record["times"]
    print(f"{scene.name}: the position loop at the target pose, lowest modes:")
    for m in modes:
        print(f"  {m.frequency_hz:.4g} Hz (damped {m.damped_hz:.4g} Hz), ζ {m.damping_ratio:.3g}, "
              f"{100 * m.share:.3g} % of the largest deflection share")
    print(f"  {args.shaper}: {len(times)} impulses over {times[-1]:.4g} s "
          f"(the move lengthens by that) → {out}")
    return 0

