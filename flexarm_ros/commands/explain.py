"""``flexarm explain``: the model built from the scene, and why (rung auto's choice), and
the model's error against the physics over the scene's run (the check of
:mod:`flexarm_ros.sim.truth`; ``--no-check`` leaves it out)."""

from __future__ import annotations

from flexarm_ros.commands.common import (fail, fidelity_args, load, open_loop_arg,
                                         scene_arg, set_line, set_values)
from flexarm_ros.io.arguments import number

#: explain's default budget for its model-form check, s (explain answers in seconds)
CHECK_BUDGET_S = 8.0


def add_parser(sub) -> None:
    e = sub.add_parser("explain", help="print the model built from the scene")
    scene_arg(e)
    fidelity_args(e)
    open_loop_arg(e)
    e.add_argument("--no-check", action="store_true",
                   help="leave out the model's error against the geometrically exact rung "
                        "(it runs the scene and the reference rods: a few seconds)")
    e.add_argument("--check-budget", type=number, default=CHECK_BUDGET_S, metavar="S",
                   help=f"run the model-form check only if its reference rods are forecast "
                        f"to take at most S seconds (default {CHECK_BUDGET_S:g}; the "
                        f"forecast and what sets it are printed otherwise)")
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
    if not args.no_check:
        import math
        import sys
        from flexarm_ros.sim import truth
        if not (args.check_budget >= 0 and math.isfinite(args.check_budget)):
            fail(f"--check-budget: got {args.check_budget}, expected a finite number >= 0 s")
        print("flexarm explain: the model-form check (the scene's run against the "
              "geometrically exact rod; --no-check skips it) ...", file=sys.stderr,
              flush=True)
        budget, stream = truth.CHECK_BUDGET_S, truth.ANNOUNCE_STREAM
        truth.CHECK_BUDGET_S, truth.ANNOUNCE_STREAM = args.check_budget, sys.stderr
        try:
            print(model_error_line(scene, args.open_loop))
        finally:
            truth.CHECK_BUDGET_S, truth.ANNOUNCE_STREAM = budget, stream
    if set_values(args):
        print(set_line(set_values(args)).strip())
    return 0


def model_error_line(scene, open_loop: bool = False) -> str:
    """The model's error against the top rung over the scene's duration, in both measures
    (docs/accuracy.md, *Against the physics*): the run as ``flexarm simulate --estimate``
    makes it (its controller in the loop when it has one), or why it was not measured."""
    from flexarm_ros.errors import InputError, SceneError, SimulationDiverged
    from flexarm_ros.model.rod import kept_modes
    from flexarm_ros.twin.batch import closed_loop, run_scene
    fid = scene.fidelity
    checked = fid.tolerance > 0 or fid.rung == "auto"
    sc = scene if checked else scene.with_fidelity(estimate=True)
    head = f"model-form error over the scene's {scene.duration:g} s (whole run)"
    try:
        res = run_scene(sc, open_loop=open_loop)
    except (InputError, SceneError, SimulationDiverged) as exc:
        return f"{head}: not measured ({' '.join(str(exc).split())})"
    chk = res.truth
    if chk is None or not chk.ok:
        why = chk.status if chk is not None else "no check for this run"
        if "above the check's budget" in why:
            why += (" (flexarm explain --check-budget S runs it; --no-check leaves this "
                    "line out)")
        return f"{head}: not measured against the physics ({why})"
    est, obs, own = chk.estimate, chk.observed, chk.reference_error
    names = [lm.name for lm in res.chain.links]
    defl = "; ".join(f"{n} {d:.2g} m ({100 * s:.2g} % of its {p:.3g} m peak)"
                     for n, d, s, p in zip(names, est.deflection_m, est.deflection_share,
                                           est.deflection_peak_m))
    loop = ", its controller in the loop" if closed_loop(sc, open_loop) else ""
    fid = res.chain.fidelity
    refine = res.chain.links[0].beam.refine
    modes = (f", its lowest {fid.rod_modes} modes" if fid.rung == "rod"
             and kept_modes(fid.rod_modes, refine) < refine else "")
    model = f"{fid.rung} (refine {refine}{modes}), {fid.integrator}"
    return (f"{head}, {model}{loop}, against the geometrically exact rod "
            f"({chk.reference} at its automatic step): tip position {est.position_m:.2g} m; "
            f"tip deflection in the hub frame: {defl}. Each is the largest distance to "
            f"{chk.reference} over the run ({obs.position_m:.2g} m, "
            f"{obs.deflection_max_m:.2g} m) plus {chk.reference}'s own bound "
            f"({own.position_m:.2g} m, {own.deflection_max_m:.2g} m: its distance to the "
            f"rod with two terms fewer); checked in {chk.wall_s:.1g} s "
            f"(docs/accuracy.md, 'Against the physics')")
