"""Cost of one right-hand side of the compiled kernel, by how it sums the beams and whether
numba counts references (not a unit test — timings are the machine's).

Per case, µs per right-hand side evaluation inside the compiled RK4 loop
(``loops.rk4_span``, best of ``REPEATS``), three ways measured in one run:

- ``points + NRT``: every beam summed over its mass points, compiled with numba's
  reference counting (the kernel before session 9; ``FLEXARM_KERNEL_NRT=1`` in a child
  process with its own numba cache, since numba's cache does not key on that option);
- ``points``: the same sums without reference counting (``jit_raw``);
- ``invariants``: beams whose invariants are cheaper than their points summed through them
  (``chain.by_invariants``, the default; ``FLEXARM_BEAM_SUMS=points`` turns it off).

    python bench/bench_kernel.py [--json]

The ratios, not the absolute figures, are what carries from machine to machine
(docs/decisions/0016-the-compiled-kernel.md, "No reference counting in the hot loops").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

CASES = [  # (label, scene, fidelity overrides)
    ("seed 001 link, rigid", "link_tipmass", {"rung": "rigid"}),
    ("seed 001 link, cubic", "link_tipmass", {"rung": "cubic"}),
    ("seed 001 link, modal 3 (default)", "link_tipmass", {}),
    ("seed 001 link, modal 6", "link_tipmass", {"rung": "modal", "refine": 6}),
    ("seed 001 link, fem 4", "link_tipmass", {"rung": "fem", "refine": 4}),
    ("spin-up, modal 4 (default)", "spin_up", {}),
    ("seed 000 two-link, cubic", "two_link_free", {"rung": "cubic", "integrator": "rk4"}),
    ("seed 000 two-link, modal 3", "two_link_free", {"integrator": "rk4", "dt": 0.0}),
]
REPEATS = 30     # best of: short repeats, many — the host's noise comes in bursts
STEPS = 1000


def _per_rhs(scene_name, over, sums) -> float:
    """µs per right-hand side: ``STEPS`` RK4 steps from the scene's initial state."""
    from flexarm_ros.model import rung_chain as chain_mod
    from flexarm_ros.model.compiled import chain as kchain, loops
    from flexarm_ros.model.statics import initial_state
    from flexarm_ros.scene import load_scene

    auto, default = chain_mod.by_invariants, chain_mod.BEAM_SUMS
    if sums == "points":
        chain_mod.by_invariants = lambda ne, points, fs: False
    else:
        chain_mod.BEAM_SUMS = "invariants"          # the default (FLEXARM_BEAM_SUMS)
    try:
        ch = chain_mod.RungChain(load_scene(scene_name).with_fidelity(**over))
    finally:
        chain_mod.by_invariants, chain_mod.BEAM_SUMS = auto, default
    q0, qd0, z0 = initial_state(ch)
    x0 = np.concatenate([q0[ch.free], qd0[ch.free], z0])
    ws = kchain.workspace(ch.kernel_args)
    h = 1e-5          # small: the state stays near the start whatever the rung's stiffness
    loops.rk4_span(x0, 0.0, h, 2, 10.0, ch.kernel_args, ws, False)      # compile / load
    best = np.inf
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        loops.rk4_span(x0, 0.0, h, STEPS, 10.0, ch.kernel_args, ws, False)
        best = min(best, time.perf_counter() - t0)
    return best / (4 * STEPS) * 1e6


def _child(variants) -> dict:
    return {label: {v: _per_rhs(scene, over, v) for v in variants}
            for label, scene, over in CASES}


def _best(a, b):
    """Element-wise minimum of two {case: {variant: µs}} tables (a may be None)."""
    return b if a is None else {c: {v: min(a[c][v], b[c][v]) for v in b[c]} for c in b}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--child", choices=["nrt"], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_child(["points"])))
        return 0
    # the child (with reference counting) before and after this process's own figures,
    # each the best of both: the host's load drifts over a run
    nrt, now = None, None
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, FLEXARM_KERNEL_NRT="1", NUMBA_CACHE_DIR=cache)
        for _ in range(2):
            out = subprocess.run([sys.executable, __file__, "--child", "nrt"], env=env,
                                 capture_output=True, text=True, check=True).stdout
            nrt = _best(nrt, json.loads(out.strip().splitlines()[-1]))
            now = _best(now, _child(["points", "invariants"]))
    rows = [{"case": label, "points_nrt_us": nrt[label]["points"],
             "points_us": now[label]["points"], "invariants_us": now[label]["invariants"]}
            for label, _, _ in CASES]
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print("| case | points + NRT (µs) | points (µs) | invariants (µs) | NRT / now |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['points_nrt_us']:.2f} | {r['points_us']:.2f} | "
              f"{r['invariants_us']:.2f} | {r['points_nrt_us'] / r['invariants_us']:.1f}× |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
