"""``flexarm modes``: natural frequencies (and mode shapes with ``--json``) of the chain
linearized about its initial state."""

from __future__ import annotations

import json

from flexarm_ros.commands.common import (
    fail, fidelity_args, load, scene_arg, set_line, set_values)
from flexarm_ros.io.arguments import integer


def add_parser(sub) -> None:
    m = sub.add_parser("modes", help="natural frequencies of the linearized chain")
    scene_arg(m)
    m.add_argument("--joints", choices=("locked", "free"),
                   help="drives clamped or free (default: locked when the scene drives a "
                        "joint, else free)")
    m.add_argument("--count", type=integer, default=10, help="number of modes to print (>= 1)")
    m.add_argument("--json", action="store_true")
    fidelity_args(m)
    m.set_defaults(func=main)


def main(args):
    from flexarm_ros.model.modes import scene_modes
    if args.count < 1:
        fail(f"--count: got {args.count}, expected an integer >= 1 (modes to print)")
    scene = load(args)
    chain, m = scene_modes(scene, args.joints)
    joints = m.joints
    n = min(args.count, len(m.frequencies_hz))
    out = {"scene": scene.name, "rung": chain.fidelity.rung, "joints": joints,
           "coordinates": list(m.coordinates),
           "frequencies_hz": [float(f) for f in m.frequencies_hz[:n]],
           "mode_shapes": [[float(v) for v in m.shapes[:, k]] for k in range(n)],
           "set": set_values(args)}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{scene.name}: rung {out['rung']}, joints {joints}")
        if out["set"]:
            print(set_line(out["set"]))
        for k, f in enumerate(out["frequencies_hz"], 1):
            print(f"  mode {k:2d}: {f:12.5f} Hz")
        other = "free" if joints == "locked" else "locked"
        why = ("the joints held (the scene drives them: its default)" if joints == "locked"
               and args.joints is None else f"--joints {joints}")
        print(f"  {why}; --joints {other} for the other condition. flexarm linearize's "
              f"eigenvalues are those of the arm with its joints free, damped; flexarm "
              f"design's are the position loop's")
    return 0
