"""The measured trade of estimating the bending from the bench's sensors (not a unit
test; the figures of docs/estimation.md come from here).

The rig is a lockstep twin bag of seed 000's two_link_case1 over its free flight (1.5 s,
before the wall at 2.1 s), its accelerometers given white noise (``NOISE`` m/s² at 1×
and 10×, in volts through each one's sensitivity; the scene's own are ideal); the
estimator runs ``flexarm estimate`` with a model offset from the rig (tip mass ±10 %,
motor resistance +10 % with torque constant −10 %: 18 % less torque per volt; the two
moved together would keep K_t/R and change nothing, beam EI −20 %), so it never sees its own
model's data. Per rig, model and sensor set: tip-deflection RMSE and largest error as a
share of each link's peak, over the whole run, and CPU per 1 kHz tick.

    python bench/bench_estimation.py            # ~2 min
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

SCENE = "two_link_case1"
DURATION_S = 1.5
#: accelerometer noise at 1×, m/s² rms (an assumption of the bench: PCB 352B68's broadband
#: resolution is 0.0005 g, the 309A's about 0.01 g; 0.01 m/s² for all four)
NOISE = 0.01
MODELS = {
    "same as the rig": {},
    "tip mass +10 %": {"links[1].tip.mass": 1.1},
    "tip mass -10 %": {"links[1].tip.mass": 0.9},
    "R +10 %, K_t -10 %": {"links[0].joint.drive.resistance": 1.1,
                           "links[1].joint.drive.resistance": 1.1,
                           "links[0].joint.drive.torque_constant": 0.9,
                           "links[1].joint.drive.torque_constant": 0.9},
    "beam EI -20 %": {"links[0].beam.EI": 0.8, "links[1].beam.EI": 0.8},
}


def _scaled(scene, factors):
    from flexarm_ros.scene.keys import get_key, set_keys
    return set_keys(scene, {k: f * get_key(scene, k) for k, f in factors.items()})


def _rig_bag(noise_x, folder):
    import yaml
    from flexarm_ros.run import run
    from flexarm_ros.scene import load_scene
    from flexarm_ros.scene.keys import scene_mapping, set_keys
    sc = load_scene(SCENE)
    sets = {}
    for k, s in enumerate(sc.sensors):
        if s.kind == "accelerometer":
            sets[f"sensors[{k}].noise_std"] = noise_x * NOISE * (s.sensitivity or 1.0)
            sets[f"sensors[{k}].seed"] = 10 + k
    rig = set_keys(sc, sets)
    path = Path(folder) / f"rig_{noise_x:g}x.yaml"
    path.write_text(yaml.safe_dump(scene_mapping(rig), sort_keys=False), encoding="utf-8")
    bag = Path(folder) / f"rig_{noise_x:g}x.mcap"
    run(str(path), DURATION_S, "lockstep", record=bag, namespace="/bench", progress=False)
    return bag, rig


def measure() -> list[dict]:
    from flexarm_ros.estimation.from_bag import estimate_bag
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for noise_x in (1.0, 10.0):
            bag, rig = _rig_bag(noise_x, folder)
            for model, factors in MODELS.items():
                est_scene = _scaled(rig, factors)
                for sensors in ("encoders", "all"):
                    e = estimate_bag(bag, est_scene, sensors)
                    rows.append({"noise": f"{noise_x:g}x", "model": model,
                                 "sensors": sensors, "cpu_us": e.cpu_per_tick_us,
                                 **{f"{k}_{m}": v[m] for k, v in e.score["links"].items()
                                    for m in ("rmse_of_peak", "max_error_of_peak")}})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = measure()
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'noise':5s} {'model':18s} {'sensors':8s} {'link1 rmse':>10s} {'max':>6s} "
          f"{'link2 rmse':>10s} {'max':>6s} {'CPU us':>7s}")
    for r in rows:
        print(f"{r['noise']:5s} {r['model']:18s} {r['sensors']:8s} "
              f"{100 * r['link1_rmse_of_peak']:9.2f}% {100 * r['link1_max_error_of_peak']:5.1f}% "
              f"{100 * r['link2_rmse_of_peak']:9.2f}% {100 * r['link2_max_error_of_peak']:5.1f}% "
              f"{r['cpu_us']:7.0f}")


if __name__ == "__main__":
    main()
