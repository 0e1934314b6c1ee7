"""``flexarm linearize``: the state-space model (A, B, C, D) about the initial state, with
names, units and the PBH controllability test."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from flexarm_ros.commands.common import fidelity_args, load, scene_arg, set_line, set_values


LINEARIZE_EPILOG = """\
units: --json and --out give state_units, input_units and output_units aligned with
states, inputs and outputs (rad, m, rad/s, m/s, A, Pa for the state; N·m, V or A per input;
rad, m, counts, m/s², m/m for the outputs).

controllability: do not take the rank of the controllability matrix [B, AB, ...]: for a
flexible model its condition number is 1e20 or more and its computed rank is meaningless.
"controllable" in --json is the PBH test instead: rank [A - λI, B] = n at every eigenvalue
λ of the balanced A, a mode failing when σ_min/σ_max of that matrix is below tol = 1e-14;
"controllability" gives tol, the eigenvalues that fail and the smallest margin. A margin
near tol is at the limit of double precision, where a controllability Gramian or a
balanced realization grades the answer (flexarm_ros.model.controllability)."""


def add_parser(sub) -> None:
    li = sub.add_parser("linearize", help="state-space model (A, B, C, D) about the initial "
                                          "state", epilog=LINEARIZE_EPILOG,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_arg(li)
    li.add_argument("--out", type=Path, help="write A, B, C, D, x0, names and units to this "
                                             ".npz")
    li.add_argument("--json", action="store_true",
                    help="print A, B, C, D, x0, states, inputs, outputs, their units and the "
                         "PBH controllability as JSON")
    li.add_argument("--closed-loop", action="store_true",
                    help="the scene's position loop (its joint PD through the voltage map) "
                         "about the move's target pose: inputs the joint targets, "
                         "A − B·F (flexarm design's model, docs/control_design.md)")
    fidelity_args(li)
    li.set_defaults(func=main)


def main(args):
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.controllability import pbh_test
    from flexarm_ros.model.statespace import linearize
    from flexarm_ros.io.paths import check_output_file
    if args.out:
        check_output_file("--out", args.out, (".npz",))
    scene = load(args)
    if args.closed_loop:
        ss = closed_loop_model(scene)
    else:
        ss = linearize(Chain(scene))
    pbh = pbh_test(ss.A, ss.B)
    if args.out:
        out = Path(args.out)
        np.savez(out, A=ss.A, B=ss.B, C=ss.C, D=ss.D, x0=ss.x0,
                 states=np.array(ss.states), inputs=np.array(ss.inputs),
                 outputs=np.array(ss.outputs), state_units=np.array(ss.state_units),
                 input_units=np.array(ss.input_units),
                 output_units=np.array(ss.output_units))
    if args.json:
        print(json.dumps({**ss.as_dict(), "controllable": pbh.controllable,
                          "controllability": pbh.as_dict(), "set": set_values(args)},
                         indent=1))
    else:
        eig = np.linalg.eigvals(ss.A)
        osc = sorted(eig[eig.imag > 0], key=abs)

        def named(names, units):
            return ", ".join(f"{n} [{u}]" for n, u in zip(names, units)) or "none"
        print(f"{scene.name}: {len(ss.states)} states, {len(ss.inputs)} inputs, "
              f"{len(ss.outputs)} outputs" + (f" → {args.out}" if args.out else ""))
        if set_values(args):
            print(set_line(set_values(args)))
        print("  states: " + named(ss.states, ss.state_units))
        print("  inputs: " + named(ss.inputs, ss.input_units))
        print("  outputs: " + named(ss.outputs, ss.output_units))
        print("  oscillating modes, natural frequency |λ|/2π (damped Im λ/2π, damping ratio "
              "−Re λ/|λ|): " + ", ".join(
                  f"{abs(l) / (2 * np.pi):.4g} Hz ({l.imag / (2 * np.pi):.4g} Hz, "
                  f"ζ {-l.real / abs(l):.3g})" for l in osc[:10]))
        print("  compare with: " + (
            "flexarm design (the same loop's modes)" if args.closed_loop else
            "flexarm modes --joints free (the undamped arm with its joints free, as here; "
            "the drives' back-EMF and the beams' damping move these eigenvalues from "
            "those)"))
        print(f"  controllable (PBH, tol {pbh.tol:g}): "
              + ("yes" if pbh.controllable else
                 f"no, {len(pbh.uncontrollable)} of {len(ss.states)} eigenvalues fail")
              + (f"; smallest margin {pbh.margins.min():.2g}" if pbh.margins.size else ""))
    return 0



def closed_loop_model(scene):
    """The StateSpace of the scene's position loop about its target pose
    (:func:`flexarm_ros.control.design.closed_loop_statespace`)."""
    from flexarm_ros.control.design import closed_loop_statespace
    from flexarm_ros.errors import InputError
    from flexarm_ros.twin.cores import ControllerCore
    if scene.control is None or scene.control.mode != "position":
        raise InputError(f"--closed-loop: got control.mode "
                         f"{scene.control.mode if scene.control else None!r}, expected "
                         f"'position' (the loop of the joint PD)")
    return closed_loop_statespace(scene, ControllerCore(scene).q_goal)
