"""``flexarm urdf``: the arm of a scene as a URDF (:mod:`flexarm_ros.twin.robot_description`),
for robot_state_publisher's ``robot_description`` parameter and RViz2's RobotModel."""

from __future__ import annotations

from pathlib import Path

from flexarm_ros.commands.common import fidelity_args, load, scene_arg
from flexarm_ros.io.arguments import integer


def add_parser(sub) -> None:
    p = sub.add_parser("urdf", help="write the arm as a URDF (each beam a chain of "
                                    "segments on virtual joints; robot_state/joint_states "
                                    "drives them)")
    scene_arg(p)
    p.add_argument("--out", type=Path, metavar="ARM.urdf",
                   help="the file to write (default: print it)")
    p.add_argument("--segments", type=integer, default=None,
                   help="rigid segments per beam (default 10, as the ROS twin publishes)")
    fidelity_args(p)
    p.set_defaults(func=main)


def main(args):
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.twin.robot_description import SEGMENTS, Description
    n = SEGMENTS if args.segments is None else args.segments
    if not 2 <= n <= 200:
        raise InputError(f"--segments: got {n}, expected 2 to 200 segments per beam")
    out = None if args.out is None else check_output_file("--out", args.out, (".urdf",
                                                                               ".xml"))
    scene = load(args)
    text = Description(Chain(scene), n).urdf()
    if out is None:
        print(text, end="")
    else:
        out.write_text(text, encoding="utf-8")
        print(f"{scene.name}: URDF of {len(scene.links)} link(s), {n} segments per beam → "
              f"{out}")
    return 0
