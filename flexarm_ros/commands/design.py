"""``flexarm design``: vibration control designed on the scene's own position loop
(:mod:`flexarm_ros.control.design`): its modes at the move's target pose and an input
shaper on the target step, written as a scene every command runs."""

from __future__ import annotations

from pathlib import Path

from flexarm_ros.commands.common import load, scene_arg, set_values
from flexarm_ros.io.arguments import integer, set_option


def add_parser(sub) -> None:
    from flexarm_ros.control.shapers import SHAPERS
    d = sub.add_parser("design", help="input shaper designed on the scene's position loop")
    scene_arg(d)
    d.add_argument("--shaper", choices=SHAPERS, required=True,
                   help="zv, zvd, zvdd or ei (extra-insensitive, 5 %% at the design "
                        "frequency) on each mode that carries the last link's deflection in "
                        "the move (convolved)")
    d.add_argument("--modes", type=integer, metavar="K",
                   help="shape the K lowest oscillating modes of the loop instead")
    d.add_argument("--out", type=Path, required=True,
                   help="the scene to write (.yaml): this scene with control.shaper set")
    set_option(d.add_argument_group("scene overrides"))
    d.set_defaults(func=main)


def main(args):
    import yaml
    from flexarm_ros import __version__
    from flexarm_ros.control.design import require_position, shaper_record
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
    ctl = ControllerCore(scene)
    record, modes = shaper_record(scene, args.shaper, ctl.q_goal, ctl.q_start, args.modes,
                                  __version__)
    times, design = record["times"], record["design"]
    data = scene_mapping(scene)
    data["name"] = f"{scene.name}_{args.shaper}"
    data["control"]["shaper"] = record
    load_scene_dict(data)                                  # what is written loads
    head = (f"# {scene.name} with an input shaper, written by flexarm design "
            f"{__version__}\n# {design}\n"
            + (f"# --set: {set_values(args)}\n" if set_values(args) else ""))
    out.write_text(head + yaml.safe_dump(data, sort_keys=False, allow_unicode=True),
                   encoding="utf-8")
    print(f"{scene.name}: the position loop at the target pose, lowest modes:")
    for m in modes:
        print(f"  {m.frequency_hz:.4g} Hz (damped {m.damped_hz:.4g} Hz), ζ {m.damping_ratio:.3g}, "
              f"{100 * m.share:.3g} % of the largest deflection share")
    print(f"  {args.shaper}: {len(times)} impulses over {times[-1]:.4g} s "
          f"(the move lengthens by that) → {out}")
    return 0
