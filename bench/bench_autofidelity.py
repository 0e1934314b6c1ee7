"""Rung auto, measured (issue 14 item 3; not a unit test — timings are the machine's).

Per scene: the shipped default and ``--rung auto`` (at the default tolerance 1e-5 m, and at
a tolerance equal to the default's own measured error: "equal error") against a converged
reference computed independently — a finer FEM mesh (:data:`SCENES` names it per scene;
why RK4 at its automatic step and not DOP853: :data:`FEM12`; where FEM converges too
slowly to be affordable, the modal family is named instead). Columns: the
model and step chosen, the measured tip error (max over the 1 kHz output of the distance
from the reference), auto's reported estimate and whether it was met, the whole call's
wall time (model build, the auto analysis and the check after the run, integration,
output columns; best of ``REPEATS``, auto's caches cleared before each) and the
integration alone.

    python bench/bench_autofidelity.py [--scenes link_tipmass,...] [--markdown FILE]
        [--cache DIR]

References are kept in ``--cache`` (default /tmp/flexarm_auto_refs) keyed by scene,
duration and reference: they take minutes each.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model import auto_search, autofidelity, beams
from flexarm_ros.scene import load_scene
from flexarm_ros.sim.simulate import simulate

REPEATS = 3
#: the references: FEM finer than any candidate, by RK4 at its automatic step. DOP853 at
#: rtol 1e-10 on these meshes costs 10 s (FEM 8) and 18 s (FEM 12) per 0.05 s simulated of
#: link_tipmass, hours for the runs here; the automatic RK4 step of a fine mesh is set by its
#: element modes (≈ 5e-6 s for FEM 12), where RK4's error on the modes that move the tip,
#: O((ω h)⁴), is far below the mesh's (the ladder study's reference, docs/ladder.md; the
#: test suite checks it against DOP853)
FEM12 = {"rung": "fem", "refine": 12}
#: (scene, duration s, reference overrides)
SCENES = [
    ("link", 3.0, FEM12),
    ("link_tipmass", 3.0, FEM12),
    ("link_motor", 4.0, FEM12),
    ("link_flexjoint", 3.0, FEM12),
    ("link_flexjoint_notip", 3.0, FEM12),
    # FEM 8 and 12 agree to 1e-9 m here
    ("two_link_free", 2.0, {"rung": "fem", "refine": 8}),
    ("spin_up", 5.0, FEM12),
    # FEM converges slowly on seed 002's arm (FEM 8 vs 16 differ by 9e-5 m in 1 s): the
    # modal family, converged to 3e-7 m between 10 and 12 modes, is the reference there
    ("hydraulic_2kg", 2.5, {"rung": "modal", "refine": 16}),
]


def _tip(res) -> np.ndarray:
    return np.c_[res.columns["tip_x"], res.columns["tip_y"]]


def reference(name, T, over, cache: Path) -> np.ndarray:
    key = f"{name}_{T:g}_" + "_".join(f"{k}{v}" for k, v in sorted(over.items()))
    path = cache / f"{key}.npy"
    if path.exists():
        return np.load(path)
    t0 = time.perf_counter()
    tip = _tip(simulate(load_scene(name).with_fidelity(**over), T))
    cache.mkdir(parents=True, exist_ok=True)
    np.save(path, tip)
    print(f"  reference {key}: {time.perf_counter() - t0:.0f} s", flush=True)
    return tip


def _clear():
    auto_search._choose.cache_clear()
    beams._mode_shapes.cache_clear()


def timed(scene, T, auto=False):
    """(result, best whole-call wall s, best integration wall s)."""
    best, best_int, res = math.inf, math.inf, None
    for _ in range(REPEATS):
        if auto:
            _clear()
        t0 = time.perf_counter()
        res = simulate(scene, T)
        best = min(best, time.perf_counter() - t0)
        best_int = min(best_int, res.run.wall_time_s)
    return res, best, best_int


def row(name, T, over, cache) -> dict:
    ref = reference(name, T, over, cache)
    scene = load_scene(name)
    simulate(scene, min(T, 0.05))                          # compile outside the timing
    out = {"scene": name, "duration_s": T,
           "reference": ", ".join(f"{k} {v}" for k, v in over.items())}
    res, wall, wint = timed(scene, T)
    err = float(np.max(np.linalg.norm(_tip(res) - ref, axis=1)))
    out["default"] = {"model": _label(res), "step_s": res.run.dt, "error_m": err,
                      "wall_s": wall, "integration_s": wint}
    for key, tol in (("auto", 0.0), ("auto_equal_error", err)):
        sc = scene.with_fidelity(rung="auto", tolerance=tol)
        try:
            res, wall, wint = timed(sc, T, auto=True)
        except SceneError as exc:
            out[key] = {"tolerance_m": tol or autofidelity.DEFAULT_TOLERANCE_M,
                        "refused": " ".join(str(exc).split())}
            continue
        s = res.summary()
        e = float(np.max(np.linalg.norm(_tip(res) - ref, axis=1)))
        out[key] = {"tolerance_m": s["tolerance_m"], "model": _label(res),
                    "step_s": res.run.dt, "error_m": e,
                    "estimated_m": s["estimated_tip_error_m"],
                    "a_priori_m": s["a_priori_tip_error_m"],
                    "met": e <= s["tolerance_m"], "wall_s": wall, "integration_s": wint,
                    "analysis_s": s["auto"]["analysis_s"],
                    "check_s": s["auto"].get("check", {}).get("wall_s")}
    return out


def _label(res) -> str:
    f = res.chain.fidelity
    return f.rung if f.rung in ("rigid", "cubic") else f"{f.rung} {f.refine}"


def markdown(rows) -> str:
    out = ["| scene | s | run | TOL (m) | model | step (s) | measured (m) | estimated (m) | "
           "≤ TOL | wall (s) | integration (s) |", "|" + "---|" * 11]
    for r in rows:
        d = r["default"]
        out.append(f"| {r['scene']} | {r['duration_s']:g} | default | – | {d['model']} | "
                   f"{d['step_s']:.3g} | {d['error_m']:.2g} | – | – | {d['wall_s']:.3f} | "
                   f"{d['integration_s']:.3f} |")
        for key, what in (("auto", "auto"), ("auto_equal_error", "auto, TOL = default's")):
            a = r[key]
            if "refused" in a:
                out.append(f"| | | {what} | {a['tolerance_m']:.2g} | refused: "
                           f"{a['refused'][:120]}… |||||||")
                continue
            out.append(f"| | | {what} | {a['tolerance_m']:.2g} | {a['model']} | "
                       f"{a['step_s']:.3g} | {a['error_m']:.2g} | {a['estimated_m']:.2g} | "
                       f"{'yes' if a['met'] else 'NO'} | {a['wall_s']:.3f} | "
                       f"{a['integration_s']:.3f} |")
    refs = sorted({f"{r['scene']}: {r['reference']}" for r in rows})
    return "\n".join(out) + "\n\nReferences: " + "; ".join(refs) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", help="comma-separated subset of the scenes")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--markdown", metavar="FILE")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/flexarm_auto_refs"))
    a = ap.parse_args()
    want = set(a.scenes.split(",")) if a.scenes else None
    rows = []
    for name, T, over in SCENES:
        if want and name not in want:
            continue
        rows.append(row(name, T, over, a.cache))
        print(json.dumps(rows[-1], default=float), flush=True)
    text = markdown(rows)
    print(text)
    if a.markdown:
        Path(a.markdown).write_text(text)


if __name__ == "__main__":
    main()
