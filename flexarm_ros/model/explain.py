"""``flexarm explain``: the model that was built from a scene, and what was left out."""

from __future__ import annotations

import numpy as np

from .chain import Chain
from .linear import natural_modes


def explain(scene) -> str:
    """A human-readable account of the model: coordinates, rung, forces kept and omitted."""
    chain = Chain(scene)
    fid = scene.fidelity
    lines = [f"scene {scene.name}: {scene.description.strip()}".rstrip(": "),
             f"rung {fid.rung} (refine {chain.links[0].beam.refine}), integrator "
             f"{fid.integrator}" + (f", dt {fid.dt} s" if fid.dt else ", automatic step"),
             f"{chain.n} generalized coordinates:"]
    for lm in chain.links:
        b = lm.beam
        idx = np.arange(chain.n)
        coords = [chain.names[i] for i in idx[lm.eta]]
        lines.append(f"  {lm.name}: joint {chain.names[lm.i_joint]}"
                     + (f", motor {chain.names[lm.i_motor]}" if lm.i_motor >= 0 else "")
                     + f"; beam L = {b.length} m, {b.n} elastic coordinate(s) "
                       f"[{', '.join(coords[:6])}{', …' if len(coords) > 6 else ''}], "
                       f"{len(b.x)} mass points")
    kept, omitted = [], []
    (kept if chain.has_gravity else omitted).append(
        "gravity" + (f" {tuple(scene.gravity)} m/s²" if chain.has_gravity else
                     " (horizontal plane: gravity vector is zero)"))
    (kept if fid.foreshortening else omitted).append(
        "foreshortening / geometric stiffening" + ("" if fid.foreshortening else
                                                   " (switched off: linear floating frame)"))
    flex = [lm.name for lm in chain.links if lm.i_motor >= 0]
    (kept if flex else omitted).append(
        f"joint flexibility ({', '.join(flex)})" if flex else
        "joint flexibility (no joint declares it: no motor-side coordinate)")
    damped = bool(np.any(chain.D))
    (kept if damped else omitted).append("damping" if damped else "damping (none declared)")
    presc = [chain.names[i] for i in chain.presc_idx]
    if presc:
        kept.append(f"prescribed motion of {', '.join(presc)} (not integrated)")
    if chain.torque_inputs:
        kept.append("joint torque programs on " +
                    ", ".join(chain.names[i] for i, _ in chain.torque_inputs))
    omitted.append("contact (no wall in this scene)")
    omitted.append("drives, sensors (not part of this scene)")
    lines.append("modelled: " + "; ".join(kept))
    lines.append("left out: " + "; ".join(omitted))
    from .simulate import initial_state
    m = natural_modes(chain, initial_state(chain)[0], joints="locked")
    f = ", ".join(f"{v:.4g}" for v in m.frequencies_hz[:4])
    where = " at the static deflection" if scene.initial.static_equilibrium else ""
    lines.append(f"first frequencies{where}, drives locked: {f} Hz (highest "
                 f"{m.frequencies_hz[-1]:.4g} Hz sets the explicit step)")
    for a in scene.assumptions:
        lines.append(f"assumption {a.key}: {a.note}")
    return "\n".join(lines)
