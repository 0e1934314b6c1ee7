"""two_link_free's rod variants against rod 12, timed alternating in one run.

Not a unit test: docs/accuracy.md, issue 36's two_link_free target,
docs/decisions/0033-rod-modes.md.

``--part points``: rod 3 on 4, 5 and 6 Gauss points per beam (``fidelity.rod_points``) and
the old modal 3 default. ``--part modes``: the shipped rod 3 and the variants that meet
1e-6 m in both measures — the lowest 4 bending modes of rod 8 (``fidelity.rod_modes``)
and the Legendre rod 5, each near its RKN4 stability limit — with rod 8's lowest 3 modes
and the Legendre rod 4 beside them, and the old modal 3 default.

Each variant: the integration real-time factor, best of ``--repeat`` 2 s runs, and the
tip position and tip deflection errors against the geometrically exact rod with 12
terms on its default quadrature by RK4 at its automatic step (``sim/truth.py``'s
reference), over the whole run; the variants alternate for ``--rounds`` rounds, so the
host's drift hits them alike.

    python bench/bench_rod_points.py [--part points|modes] [--rounds 2] [--repeat 8]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from flexarm_ros.scene import load_scene
from flexarm_ros.sim.truth import measures, reference_scene
from flexarm_ros.sim.simulate import simulate

T = 2.0


def variants(part, sc):
    """[(label, scene)] of ``part``."""
    dt = sc.fidelity.dt
    modal3 = ("modal 3 (the default until session 18), 7.5 ms",
              sc.with_fidelity(rung="modal", refine=3, dt=dt, integrator="rkn4"))
    if part == "points":
        return [(f"rod 3, {p} points", sc.with_fidelity(rod_points=p, dt=dt))
                for p in (4, 5, 6)] + [modal3]
    return [("rod 3, 4 points, 7.5 ms (shipped)", sc),
            ("rod 8 lowest 3 modes, 4 points, 7.5 ms",
             sc.with_fidelity(refine=8, rod_modes=3, rod_points=4, dt=dt)),
            ("rod 8 lowest 3 modes, 4 points, 4 ms",
             sc.with_fidelity(refine=8, rod_modes=3, rod_points=4, dt=0.004)),
            ("rod 4, 5 points, 3.5 ms", sc.with_fidelity(refine=4, rod_points=5, dt=0.0035)),
            ("rod 8 lowest 4 modes, 5 points, 3.5 ms",
             sc.with_fidelity(refine=8, rod_modes=4, rod_points=5, dt=0.0035)),
            ("rod 5, 6 points, 1.7 ms", sc.with_fidelity(refine=5, rod_points=6, dt=0.0017)),
            modal3]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("points", "modes"), default="points",
                    help="the Gauss points of rod 3, or the 1e-6 m variants (default points)")
    ap.add_argument("--rounds", type=int, default=2,
                    help="rounds of the alternating variants (default 2)")
    ap.add_argument("--repeat", type=int, default=8,
                    help="2 s runs per variant and round, the best timed (default 8; fewer "
                         "are noisy on a busy host)")
    a = ap.parse_args(argv)
    for name in ("rounds", "repeat"):
        if getattr(a, name) < 1:
            ap.error(f"--{name}: got {getattr(a, name)}, expected an integer >= 1")
    sc = load_scene("two_link_free")
    ref = simulate(reference_scene(sc, 12), T)          # the top rung, as the checks build it
    ref_cols = {k: np.asarray(v) for k, v in ref.columns.items()}
    links = [lm.name for lm in ref.chain.links]
    for rnd in range(a.rounds):
        for label, scene in variants(a.part, sc):
            best, run = 0.0, None
            for _ in range(a.repeat):
                run = simulate(scene, duration=T)
                best = max(best, run.summary()["real_time_factor"])
            m = measures({k: np.asarray(v) for k, v in run.columns.items()},
                         ref_cols, links)
            print(f"round {rnd + 1}  {label:48s} {best:6.0f}x  tip {m.position_m:.2e} m  "
                  f"deflection {max(m.deflection_m):.2e} m "
                  f"({100 * max(m.deflection_share):.4f} % of peak)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
