#!/usr/bin/env python3
"""Regenerate the reference data of ``flexarm compare`` in ``bags/``.

1. ``bags/golden_case1.mcap``: the twin on seed 000 Case 1 (``two_link_case1``: 1.5 V on
   both motors, the tool strikes the wall x = -0.025 m near 2.1 s), 2.5 s of simulated
   time, lockstep, every topic recorded. Made by exactly

       flexarm run two_link_case1 --duration 2.5 --record bags/golden_case1.mcap --quiet

   (about 30-60 s of wall time; loopback-only DDS and a private ROS_DOMAIN_ID). Lockstep
   runs are deterministic message for message; the file bytes may differ between runs
   (chunks are flushed on wall-clock time), the decoded messages do not.

2. ``bags/synthetic_experiment_case1.csv``: a SYNTHETIC "experiment" made from the golden
   bag, NOT a measurement: eleven channels of the golden bag (accelerometers A-D at
   4 kHz; encoder joint angles, tip position, the tool's gap to the wall, wall normal force
   and the contact flag at 1 kHz) with seeded Gaussian noise added and the clock shifted by ``SHIFT_S`` (the "DAQ"
   started before the twin's t = 0), written to the CSV convention of
   ``flexarm_ros.io.experiment`` with a comment header saying so. It exercises
   ``flexarm compare`` end to end (time offset, noise, mixed sample rates) where no
   digitized experiment is available.

Usage::

    python tools/make_golden_bags.py            # both files
    python tools/make_golden_bags.py --csv-only # only the CSV, from the existing bag
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.analysis.channels import add_wall_gap, load_channels  # noqa: E402
from flexarm_ros.io.experiment import write_experiment_csv  # noqa: E402
from flexarm_ros.nodes import environment  # noqa: E402

GOLDEN = ROOT / "bags" / "golden_case1.mcap"
SYNTHETIC = ROOT / "bags" / "synthetic_experiment_case1.csv"
SCENE, DURATION_S = "two_link_case1", 2.5

#: The synthetic experiment's clock runs ahead of the twin's by this much: a sample the
#: twin made at t is written at t + SHIFT_S (so ``flexarm compare`` finds offset -SHIFT_S).
SHIFT_S = 0.0375
#: Seed of the noise generator.
NOISE_SEED = 20260
#: channel -> (noise standard deviation, how it is stated). Relative entries ('rel') are a
#: fraction of the channel's own standard deviation over the record.
NOISE = {
    "acc_A": (0.02, "rel"), "acc_B": (0.02, "rel"),
    "acc_C": (0.02, "rel"), "acc_D": (0.02, "rel"),
    "link1_joint_measured": (1e-4, "abs"), "link2_joint_measured": (1e-4, "abs"),
    "tip_x": (5e-4, "abs"), "tip_y": (5e-4, "abs"),
    "wall_gap": (5e-4, "abs"),
    "normal_force": (0.02, "abs"),
    "contact": (0.0, "abs"),
}


def make_golden(path: Path = GOLDEN) -> Path:
    """Run the twin (the documented command) and record ``path``."""
    env = dict(os.environ)
    environment.private_graph(env)
    path.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "flexarm_ros.cli", "run", SCENE, "--duration",
           str(DURATION_S), "--record", str(path), "--quiet"]
    print("$ flexarm " + " ".join(cmd[3:]), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT, env=env)
    return path


def make_synthetic(golden: Path = GOLDEN, out: Path = SYNTHETIC) -> Path:
    """Noise + clock shift on eleven channels of the golden bag -> the CSV convention.
    ``wall_gap`` is the one derived channel: the tool point's distance to the wall (the
    tool sits beyond the recorded beam tip, so an experiment without it could not give
    the bounce)."""
    cs = load_channels(golden)
    why = add_wall_gap(cs.channels, cs.scene)
    if why is not None:
        raise SystemExit(f"wall_gap: {why}")
    rng = np.random.default_rng(NOISE_SEED)
    columns, notes = {}, []
    for name, (level, how) in NOISE.items():
        ch = cs[name]
        std = level * float(np.std(ch.y)) if how == "rel" else level
        y = ch.y + (std * rng.standard_normal(ch.y.size) if std > 0 else 0.0)
        t = np.round((ch.t + SHIFT_S) * 1e9) / 1e9
        columns[name] = (ch.unit, t, y)
        notes.append(f"  {name} [{ch.unit}]: " + (
            "no noise" if std == 0 else
            f"noise std {std:.3g} {ch.unit}" + (f" ({level:.0%} of the channel's std)"
                                                 if how == "rel" else "")))
    comments = [
        "SYNTHETIC EXPERIMENT -- not a measurement.",
        f"Made by tools/make_golden_bags.py from bags/{golden.name} (the twin, seed 000 "
        f"Case 1, {SCENE}, {DURATION_S} s):",
        f"Gaussian noise added (numpy default_rng({NOISE_SEED})) and the clock shifted by "
        f"+{SHIFT_S} s",
        f"(a twin sample at t is written at t + {SHIFT_S} s; flexarm compare should find "
        f"offset_s = -{SHIFT_S}).",
        "Columns: time 't [s]', then 'name [unit]'; empty cell = no sample at that time "
        "(4 kHz and 1 kHz channels share the file).",
        "Noise per channel:",
        *notes,
    ]
    write_experiment_csv(out, columns, comments, fmt="%.5g", time_fmt="%.10g")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--csv-only", action="store_true",
                   help="only rebuild the synthetic CSV from the existing golden bag")
    args = p.parse_args(argv)
    if not args.csv_only:
        make_golden()
        print(f"golden bag: {GOLDEN} ({GOLDEN.stat().st_size / 1e6:.2f} MB)")
    make_synthetic()
    print(f"synthetic experiment: {SYNTHETIC} ({SYNTHETIC.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
