"""Seed 000: the air-bearing friction identified without Case 2, Case 3 reproduced, Case 2
predicted (issue 40 items 2 and 3).

    python tools/bearing_friction_seed000.py               # every part, Dask, one worker per core
    python tools/bearing_friction_seed000.py case3         # one of: case1 case3 case2 take
    python tools/bearing_friction_seed000.py --workers 0   # in this process, no Dask
    python tools/bearing_friction_seed000.py --scheduler tcp://127.0.0.1:8786

Prints the numbers docs/calibration_seed000.md §5 quotes, as Markdown (stdout; the
executor and each part's wall time on stderr). The studies are
:mod:`flexarm_ros.studies.bearings_seed000`: each batch of independent simulations (a
study's scenes, μ values or variants; the root finds of Case 1, one task each) is one
call of the ensemble runner on the executor opened here once — a Dask ``LocalCluster``
of one single-threaded worker process per core by default (``--workers N``: N of them;
``--workers 0``: in this process, one task after the other), or an existing Dask
cluster (``--scheduler``). The numbers are the same on every executor.

* case1 — the uniform μ that Case 1's 0.07 s delay asks for, on the shipped and the
  geometry-only arm, and the reconciled pair (resistance factor, μ).
* case3 — the backlash run without friction, with the identified μ and with a high spot
  under each bearing; its amplitudes against μ.
* case2 — Case 2 predicted with the identified friction (and the binding term).
* take — what moves Case 2's frequencies (v_s, a slower approach, RB4's inertia, the
  beams' stiffness).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.ensemble.cli import executor_args  # noqa: E402
from flexarm_ros.ensemble.runner import open_executor  # noqa: E402
from flexarm_ros.errors import InputError  # noqa: E402
from flexarm_ros.studies import bearings_seed000 as bf  # noqa: E402

PARTS = ("case1", "case3", "case2", "take")


def run(parts, executor) -> None:
    """Print the Markdown of ``parts`` (in the order of :data:`PARTS`); the μ of Case 1
    (its 0.07 s root and the reconciled pair) feeds the later parts when case1 runs,
    else the values §5 quotes."""
    mu, factor, mu_rec = 0.00446, 1.0, 0.0050
    for part in (p for p in PARTS if p in parts):
        t0 = time.perf_counter()
        if part == "case1":
            c1 = bf.case1(executor)
            print(bf.case1_table(c1), flush=True)
            mu = c1["two_link_case1"]["mu"][0.07]
            factor = c1["reconciled"]["factor"]
            mu_rec = c1["reconciled"]["mu"]
        elif part == "case3":
            print()
            print(bf.case3_table(bf.case3(mu, executor)))
            print()
            print(bf.case3_amplitudes_table(bf.case3_amplitudes(executor=executor)),
                  flush=True)
        elif part == "case2":
            print()
            print(bf.case2_table(bf.case2(mu, executor=executor)), flush=True)
            if factor != 1.0:
                print(f"\nreconciled arm (resistance × {factor:.4f}):")
                print(bf.case2_table(bf.case2(mu_rec, factor, executor)), flush=True)
        else:
            print()
            print(bf.case2_sensitivity_table(bf.case2_sensitivity(mu, executor)))
            print()
            print(bf.what_it_would_take_table(bf.what_it_would_take(executor)), flush=True)
        print(f"{part}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("parts", nargs="*", metavar="part",
                    help="case1 | case3 | case2 | take (default: all four)")
    executor_args(ap, "the simulations")
    args = ap.parse_args(argv)
    bad = [p for p in args.parts if p not in PARTS]
    if bad:        # checked here: argparse's choices refuse an empty list for nargs="*"
        print(f"error: part: got {bad[0]!r}, expected one of {', '.join(PARTS)}",
              file=sys.stderr)
        return 2
    try:
        with open_executor(args.workers, args.scheduler, timeout_s=args.timeout) as ex:
            print(f"bearing friction: {ex.description}"
                  + (f"; dashboard {ex.dashboard}" if ex.dashboard else ""),
                  file=sys.stderr, flush=True)
            run(args.parts or PARTS, ex)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
