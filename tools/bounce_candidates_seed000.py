"""Seed 000 Case 1: what sets the first bounce (issue 40 item 1, docs/calibration_seed000.md §6).

    python tools/bounce_candidates_seed000.py              # the table of §6
    python tools/bounce_candidates_seed000.py --workers 0  # in this process, no Dask
    python tools/bounce_candidates_seed000.py --only damping

The candidates and how each row is read: :mod:`flexarm_ros.studies.bounce_seed000`. The
rows run as one batch on the ensemble runner: a local Dask cluster of one worker process
per core by default (``--workers N``, ``--workers 0`` in this process), or an existing
cluster (``--scheduler ADDRESS``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.ensemble.cli import executor_args  # noqa: E402
from flexarm_ros.ensemble.runner import open_executor  # noqa: E402
from flexarm_ros.errors import InputError  # noqa: E402
from flexarm_ros.studies import bounce_seed000 as bs  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="rows whose group contains this text")
    executor_args(ap, "the simulations")
    args = ap.parse_args(argv)
    groups = sorted({c[0] for c in bs.CANDIDATES})
    if args.only and not any(args.only in g for g in groups):
        print(f"error: --only: got {args.only!r}, which no group contains; expected part of "
              f"one of: {', '.join(groups)}", file=sys.stderr)
        return 2
    try:
        with open_executor(args.workers, args.scheduler, timeout_s=args.timeout) as ex:
            print(f"bounce candidates: {ex.description}", file=sys.stderr, flush=True)
            rows = bs.candidates(ex, args.only, on_result=lambda k, r: print(
                f"{r['label']}: {r['wall_s']:.1f} s", file=sys.stderr, flush=True))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(bs.table(rows)))
    print("\n(in target: first bounce 0.5-20 mm, impact 2.1 ± 0.02 s, f_A within 5 % of "
          "10.96 Hz)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
