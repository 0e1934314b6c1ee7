"""``flexarm explain``: the model built from the scene, and why (rung auto's choice)."""

from __future__ import annotations

from flexarm_ros.commands.common import fidelity_args, load, scene_arg, set_line, set_values


def add_parser(sub) -> None:
    e = sub.add_parser("explain", help="print the model built from the scene")
    scene_arg(e)
    fidelity_args(e)
    e.set_defaults(func=main)


def main(args):
    from flexarm_ros.model.explain import explain
    scene = load(args)
    chain = None
    if scene.fidelity.tolerance and scene.fidelity.rung != "auto":
        # what simulate would refuse is refused here too, before the choice is described
        from flexarm_ros.model.chain import Chain
        from flexarm_ros.model.contact import build_contact
        from flexarm_ros.sim.simulate import check_tolerance_applies
        chain = Chain(scene)
        check_tolerance_applies(chain, build_contact(chain) if scene.walls else None)
    print(explain(scene, chain))
    if set_values(args):
        print(set_line(set_values(args)).strip())
    return 0
