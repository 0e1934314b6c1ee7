"""A zoo of plausible planar flexible arms, for testing every command on arms it has never
seen (:func:`arm`, :func:`zoo`).

Each arm is a scene mapping written in the datasheet's terms, as a user would write it
from docs/scenes.md: 1–4 links of aluminium, steel or carbon-fibre strips (a rectangle
bending the easy way) or tubes, 0.15–0.8 m long; geared DC motors given by their datasheet
(rotor inertia, gear ratio and efficiency, K_t = K_b, R) or, on a one-link arm, the seed
002 servovalve and rotary actuator; with or without tip bodies; in a horizontal plane or
a vertical one (gravity in the plane, starting at rest in its static deflection); driven
open loop by voltage steps or by the joint PD position controller. The values are drawn
from ranges of catalogue parts (Maxon RE/DCX motors with planetary gearheads; 6061-T6
aluminium E 69 GPa, ρ 2700 kg/m³; steel 200 GPa, 7850 kg/m³; unidirectional CFRP strip
125 GPa, 1550 kg/m³), so each arm is one an engineer could build, not an extreme (the
extremes are the hostile tests' business).

Deterministic: ``arm(seed)`` is the same mapping on every machine.
"""

from __future__ import annotations

import math

import numpy as np

MATERIALS = {"aluminium": (69e9, 2700.0), "steel": (200e9, 7850.0),
             "cfrp": (125e9, 1550.0)}

#: the seed 002 servovalve and Hyd-Ro-Wrist actuator (config/hydraulic_2kg.yaml)
HYDRAULIC = {"type": "hydraulic", "displacement": 6.2271e-5, "torque_efficiency": 0.9,
             "leakage": 3.7064772e-13, "valve_gain": 2.402963e-6,
             "supply_pressure": 1.37889e7, "total_volume": 3.05127e-4,
             "bulk_modulus": 6.9e8, "rated_current": 0.010, "null_bias": True}


def _section(rng, tube=False):
    """A strip (width 15–40 mm, thickness 1.5–4 mm) or a tube (Ø 10–25 mm, wall 1–2 mm)."""
    if not tube and rng.random() < 0.7:
        return {"shape": "rectangle", "width": round(float(rng.uniform(0.015, 0.04)), 4),
                "thickness": round(float(rng.uniform(0.0015, 0.004)), 5)}
    d = float(rng.uniform(0.010, 0.025))
    return {"shape": "tube", "outer_diameter": round(d, 4),
            "wall_thickness": round(float(rng.uniform(0.001, min(0.002, d / 4))), 5)}


def _dc_motor(rng, inertia):
    """A geared DC motor sized for the load it swings (Maxon-like catalogue ranges): the
    gearhead of the catalogue whose reflected rotor inertia n²·J_m is nearest to the
    link's swing inertia (the matched-inertia rule of thumb)."""
    kt = float(rng.uniform(0.015, 0.06))
    jm = float(f"{rng.uniform(1e-6, 2e-5):.3g}")
    ratios = [4.8, 9.0, 19.0, 33.0, 51.0, 66.0, 100.0, 156.0]
    ratio = min(ratios, key=lambda r: abs(math.log(r * r * jm / max(inertia, 1e-6))))
    return {"type": "dc_motor", "gear_ratio": ratio,
            "gear_efficiency": round(float(rng.uniform(0.6, 0.9)), 2),
            "torque_constant": round(kt, 4), "back_emf_constant": round(kt, 4),
            "resistance": round(float(rng.uniform(0.5, 4.0)), 3),
            "rotor_inertia": jm, "supply_voltage": 12.0}


def _area(section) -> float:
    if section["shape"] == "rectangle":
        return section["width"] * section["thickness"]
    D, t = section["outer_diameter"], section["wall_thickness"]
    return math.pi * (D * D - (D - 2 * t) ** 2) / 4.0


def _swing_inertias(lengths, tips, rho_a):
    """Each joint's inertia about its axis of everything outboard, the arm straight,
    kg·m² (beams as rods, tip bodies as points)."""
    n = len(lengths)
    out = []
    for k in range(n):
        J, r = 0.0, 0.0
        for j in range(k, n):
            L = lengths[j]
            J += rho_a[j] * ((r + L) ** 3 - r ** 3) / 3.0
            r += L
            J += tips[j] * r * r
        out.append(J)
    return out


def arm(seed: int, *, links: int | None = None, control: str | None = None) -> dict:
    """The scene mapping of zoo arm ``seed`` (``links`` / ``control``: force that many
    links or ``"open_loop"`` / ``"position"``)."""
    rng = np.random.default_rng(seed)
    n = int(links if links is not None else rng.integers(1, 5))
    hydraulic = n == 1 and rng.random() < 0.5
    # in a vertical plane: at most two links, tubes (a strip on its flat sags past the
    # small-deflection bound under its own weight and the outboard motors)
    vertical = hydraulic or (n <= 2 and rng.random() < 0.4)
    mode = control or ("open_loop" if hydraulic else
                       str(rng.choice(["open_loop", "position"])))
    lengths = sorted((float(rng.uniform(0.15, 0.8)) for _ in range(n)), reverse=True)
    out, tips, rho_a = [], [], []
    for k in range(n):
        mat = str(rng.choice(list(MATERIALS)))
        E, rho = MATERIALS[mat]
        L = round(lengths[k], 3)
        tip = rng.random() < 0.7 or k < n - 1
        tip_mass = round(float(rng.uniform(0.05, 0.5 if k < n - 1 else 0.3)), 3) if tip \
            else 0.0
        section = _section(rng, tube=vertical)
        link = {"name": f"link{k + 1}",
                "joint": {"drive_damping": round(float(rng.uniform(0.0, 0.05)), 4)},
                "beam": {"length": L, "E": E, "density": rho, "section": section,
                         "damping": ({"stiffness_proportional":
                                      float(f"{rng.uniform(1e-5, 2e-4):.2g}")}
                                     if rng.random() < 0.3 else
                                     {"viscous_per_length":
                                      float(f"{rng.uniform(0.01, 0.3):.2g}")})}}
        if tip_mass:
            link["tip"] = {"mass": tip_mass,
                           "inertia": float(f"{0.4 * tip_mass * 0.03 ** 2:.3g}")}
        if hydraulic:
            link["joint"]["drive"] = dict(HYDRAULIC)
            link["hub"] = {"mass": 1.0, "inertia": 0.05}
        out.append(link)
        tips.append(tip_mass)
        rho_a.append(rho * _area(section))
    swing = _swing_inertias([lk["beam"]["length"] for lk in out], tips, rho_a)
    if not hydraulic:
        for link, J in zip(out, swing):
            link["joint"]["drive"] = _dc_motor(rng, J)
    scene = {"name": f"zoo_{seed}",
             "description": f"zoo arm {seed}: {n} link(s), "
                            f"{'hydraulic' if hydraulic else 'DC motors'}, "
                            f"{'vertical plane' if vertical else 'horizontal plane'}, "
                            f"{mode}",
             "gravity": [0.0, -9.81] if vertical else [0.0, 0.0],
             "links": out, "duration": 1.5}
    if vertical:
        scene["initial"] = {"static_equilibrium": True}
    if hydraulic:
        scene["inputs"] = [{"joint": 1, "current": {"type": "step", "amplitude": 0.002,
                                                    "start": 0.1}}]
        scene["control"] = {"rate_hz": 500.0}
    elif mode == "position":
        # joint PD of about 0.3-0.6 Hz bandwidth on each joint's swing and reflected rotor
        # inertia, damping ratio 0.7, towards targets 0.05-0.15 rad away (a step of the
        # target: gentle enough for a thin strip)
        kp, kd = [], []
        for link, J in zip(out, swing):
            d = link["joint"]["drive"]
            J_eff = J + d["gear_ratio"] ** 2 * d["rotor_inertia"]
            w = 2 * math.pi * float(rng.uniform(0.3, 0.6))
            kp.append(float(f"{J_eff * w * w:.3g}"))
            kd.append(float(f"{1.4 * J_eff * w:.3g}"))
        q = [round(float(rng.uniform(0.05, 0.15)) * (-1) ** k, 3) for k in range(n)]
        scene["control"] = {"mode": "position", "rate_hz": 1000.0, "kp": kp, "kd": kd,
                            "joint_target": q}
    else:
        # a voltage step that turns each joint at 0.2-0.5 rad/s at no load
        scene["inputs"] = [{"joint": k + 1, "voltage": {
            "type": "step",
            "amplitude": round(float(rng.uniform(0.2, 0.5)) * (-1) ** k
                               * lk["joint"]["drive"]["back_emf_constant"]
                               * lk["joint"]["drive"]["gear_ratio"], 3),
            "start": round(float(rng.uniform(0.05, 0.2)), 3)}} for k, lk in enumerate(out)]
    scene["sensors"] = [{"name": f"enc{k + 1}", "kind": "encoder", "joint": k + 1,
                         "rate_hz": 1000.0, "lines_per_rev": 500}
                        for k in range(n) if not hydraulic] + [
        {"name": f"acc{n}", "kind": "accelerometer", "link": f"link{n}", "body": "tip",
         "rate_hz": 2000.0, "sensitivity": 0.0005, "noise_std": 1e-4, "seed": seed}]
    if hydraulic:
        scene["sensors"].append({"name": "pot1", "kind": "potentiometer", "joint": 1,
                                 "rate_hz": 500.0})
    return scene


def zoo(count: int, first: int = 0) -> list[dict]:
    """Arms ``first`` … ``first + count − 1``."""
    return [arm(s) for s in range(first, first + count)]


def reach(scene: dict) -> float:
    """The arm's straight reach, m (for the tests' sanity bounds)."""
    return math.fsum(lk["beam"]["length"] for lk in scene["links"])
