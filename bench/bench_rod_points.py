"""two_link_free's rod 3 on 4, 5 and 6 Gauss points per beam, and the old modal 3
default, in one run (not a unit test; docs/accuracy.md, issue 36's 800x target).

Each variant: the integration real-time factor, best of ``--repeat`` 2 s runs, and the
tip position and tip deflection errors against the geometrically exact rod with 12
terms on its default quadrature by RK4 at its automatic step (``sim/truth.py``'s
reference), over the whole run; the
variants alternate for ``--rounds`` rounds, so the host's drift hits them alike.

    python bench/bench_rod_points.py [--rounds 2] [--repeat 8]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from flexarm_ros.scene import load_scene
from flexarm_ros.sim.truth import measures, reference_scene
from flexarm_ros.sim.simulate import simulate

T = 2.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=8)
    a = ap.parse_args(argv)
    for name in ("rounds", "repeat"):
        if getattr(a, name) < 1:
            ap.error(f"--{name}: got {getattr(a, name)}, expected an integer >= 1")
    sc = load_scene("two_link_free")
    ref = simulate(reference_scene(sc, 12), T)          # the top rung, as the checks build it
    ref_cols = {k: np.asarray(v) for k, v in ref.columns.items()}
    links = [lm.name for lm in ref.chain.links]
    dt = sc.fidelity.dt
    variants = [(f"rod 3, {p} points", sc.with_fidelity(rod_points=p, dt=dt))
                for p in (4, 5, 6)]
    variants.append(("modal 3 (the default until session 18)",
                     sc.with_fidelity(rung="modal", refine=3, dt=dt, integrator="rkn4")))
    for rnd in range(a.rounds):
        for label, scene in variants:
            best, run = 0.0, None
            for _ in range(a.repeat):
                run = simulate(scene, duration=T)
                best = max(best, run.summary()["real_time_factor"])
            m = measures({k: np.asarray(v) for k, v in run.columns.items()},
                               ref_cols, links)
            print(f"round {rnd + 1}  {label:40s} {best:6.0f}x  tip {m.position_m:.2e} m  "
                  f"deflection {max(m.deflection_m):.2e} m "
                  f"({100 * max(m.deflection_share):.3f} % of peak)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
