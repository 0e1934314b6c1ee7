"""The measured trade of vibration control designed on the twin (not a unit test; the
figures of docs/control_design.md come from here).

For each arm — seed 000's two_link_position and examples/three_link_position.yaml — the
joint PD alone, with each input shaper that ``flexarm design`` writes (zv, zvd, ei on
every mode that carries the outer tip's deflection) and the LQG of ``flexarm design --lqg``
in place of the PD (default weights, and a 1 V voltage scale), each design kept at the nominal
model and run on the nominal rig and on rigs whose beams are 30 % stiffer and 20 % softer
(EI, or E for a beam given by its datasheet, scaled with ``--set``):

``residual_m``    the outer link's largest hub-frame tip deflection over a 2 s window
                  from 0.5 s after the *latest* last impulse among the designs — the same
                  window for every design, PD included
``settle_s``      the time from which, for good, the outer tip deflection stays within
                  1 mm and every joint within 2 % of its move
``move_s``        the shaper's last impulse (0 for PD and LQG): what the shaping adds to the
                  move
``peak_V``        the largest motor voltage
``ctl_us``        the controller core's CPU per 1 kHz tick (3000 ticks, process time)

    python bench/bench_vibration.py                  # ~1 min
    python bench/bench_vibration.py --json
"""

from __future__ import annotations

import argparse
import json

import numpy as np

ARMS = ("two_link_position", "examples/three_link_position.yaml")
DESIGNS = ("pd", "zv", "zvd", "ei")
#: the LQG designs compared: flexarm design --lqg with its default weights (the voltage
#: weight bounded by the PD's first command) and with a voltage scale of 1 V
LQGS = {"lqg": None, "lqg 1V": {"voltage": 1.0}}
RIGS = {"nominal": 1.0, "stiffer 30 %": 1.3, "softer 20 %": 0.8}
WINDOW_S = 2.0
AFTER_S = 0.5


def _rig(scene, factor):
    """The scene with every beam's bending stiffness scaled by ``factor``."""
    from flexarm_ros.scene.keys import set_keys
    sets = {}
    for k, lk in enumerate(scene.links):
        key = "E" if lk.beam.E is not None and "EI" in lk.beam.derived_keys else "EI"
        sets[f"links[{k}].beam.{key}"] = factor * getattr(lk.beam, key)
    return set_keys(scene, sets)


def _metrics(res, scene, window):
    t = np.asarray(res.columns["t"])
    w = np.asarray(res.columns[f"{scene.links[-1].name}_tip_deflection"])
    inside = (t >= window[0]) & (t <= window[1])
    from flexarm_ros.twin.cores import ControllerCore
    ctl = ControllerCore(scene)
    ok = np.abs(w) <= 1e-3
    for k, lk in enumerate(scene.links):
        move = abs(ctl.q_goal[k] - ctl.q_start[k])
        q = np.asarray(res.columns[f"{lk.name}_joint"])
        ok &= np.abs(q - ctl.q_goal[k]) <= 0.02 * max(move, 1e-9)
    bad = np.nonzero(~ok)[0]
    settle = float(t[bad[-1] + 1]) if len(bad) and bad[-1] + 1 < len(t) else (
        0.0 if not len(bad) else float("nan"))
    volts = [np.max(np.abs(res.columns[f"{lk.name}_voltage"])) for lk in scene.links]
    return {"residual_m": float(np.max(np.abs(w[inside]))), "settle_s": settle,
            "peak_V": float(max(volts))}


def _controller_us(scene, ticks: int = 3000) -> float:
    """CPU per update of the scene's controller core, µs."""
    import time
    from flexarm_ros.twin.cores import ControllerCore
    ctl = ControllerCore(scene)
    q = np.array(ctl.q_start)
    t0 = time.process_time()
    for k in range(ticks):
        ctl.update(k * 1e-3, 1e-3, q)
    return (time.process_time() - t0) / ticks * 1e6


def measure(arm: str) -> list[dict]:
    from flexarm_ros.api import design
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin.batch import run_scene
    base = load_scene(arm)
    scenes = {"pd": base}
    for kind in DESIGNS[1:]:              # what flexarm design --shaper KIND writes
        scenes[kind] = design(base, shaper=kind)
    for kind, weights in LQGS.items():   # what flexarm design --lqg [--weights] writes
        scenes[kind] = design(base, lqg=True, weights=weights)
    moves = {k: (s.control.shaper.times[-1] if s.control.shaper else 0.0)
             for k, s in scenes.items()}
    start = max(moves.values()) + AFTER_S
    window = (start, start + WINDOW_S)
    T = max(base.duration, window[1])
    cpu = {kind: _controller_us(sc) for kind, sc in scenes.items()}
    rows = []
    for rig, factor in RIGS.items():
        for kind, sc in scenes.items():
            res = run_scene(_rig(sc, factor), T)
            m = _metrics(res, sc, window)
            rows.append({"arm": base.name, "rig": rig, "design": kind, "move_s": moves[kind],
                         "window_s": list(window), "ctl_us": cpu[kind], **m})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [r for arm in ARMS for r in measure(arm)]
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    for arm in dict.fromkeys(r["arm"] for r in rows):
        sub = [r for r in rows if r["arm"] == arm]
        w = sub[0]["window_s"]
        print(f"\n{arm} (window {w[0]:.3g}-{w[1]:.3g} s)")
        print(f"{'rig':14s} {'design':7s} {'residual m':>11s} {'/PD':>6s} {'settle s':>9s} "
              f"{'move s':>7s} {'peak V':>7s} {'ctl us':>7s}")
        for r in sub:
            pd = next(x for x in sub if x["rig"] == r["rig"] and x["design"] == "pd")
            print(f"{r['rig']:14s} {r['design']:7s} {r['residual_m']:11.3g} "
                  f"{r['residual_m'] / pd['residual_m']:6.3f} {r['settle_s']:9.3g} "
                  f"{r['move_s']:7.3g} {r['peak_V']:7.3g} {r['ctl_us']:7.3g}")


if __name__ == "__main__":
    main()
