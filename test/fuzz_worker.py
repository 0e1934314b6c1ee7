"""The fuzz suite's worker (test/test_fuzz.py): runs ``flexarm`` commands in-process, one
per JSON line on stdin, and answers one JSON line per case on stdout, so the parent can put
every case under a wall-clock limit (a hang kills this process, not the test run) while
the cases themselves cost an in-process call, not a Python start-up each.

Case: {"argv": [...], "scan": directory or null}. Answer: {"code": exit status,
"out": stdout, "err": stderr, "traceback": text of an exception that escaped main() or
null, "nonfinite": [CSV files under "scan" holding a non-finite number], "wall_s": s}.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import sys
import time
import traceback
from pathlib import Path


def nonfinite_csv(directory) -> list[str]:
    """CSV files under ``directory`` with a non-finite numeric cell."""
    bad = []
    for path in sorted(Path(directory).rglob("*.csv")):
        with open(path, encoding="utf-8") as fh:
            fh.readline()
            for line in fh:
                for cell in line.rstrip("\n").split(","):
                    try:
                        v = float(cell)
                    except ValueError:
                        continue            # a text column (contact_phase)
                    if not math.isfinite(v):
                        bad.append(str(path))
                        break
                else:
                    continue
                break
    return bad


def run_case(case: dict) -> dict:
    from flexarm_ros.cli import main
    out, err = io.StringIO(), io.StringIO()
    tb = None
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(case["argv"])
        except SystemExit as exc:                # argparse
            code = exc.code if isinstance(exc.code, int) else 2
        except BaseException:                    # noqa: BLE001 - what the fuzz looks for
            code = None
            tb = traceback.format_exc()
    scan = case.get("scan")
    return {"code": code, "out": out.getvalue()[-4000:], "err": err.getvalue()[-4000:],
            "traceback": tb, "nonfinite": nonfinite_csv(scan) if scan else [],
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    import os
    answers = os.fdopen(os.dup(1), "w")      # the protocol keeps the real stdout;
    os.dup2(2, 1)                            # anything written to fd 1 below goes to stderr
    sys.stdout = sys.__stdout__ = io.TextIOWrapper(os.fdopen(1, "wb", 0), write_through=True)
    for line in sys.stdin:
        if not line.strip():
            continue
        answer = run_case(json.loads(line))
        answers.write(json.dumps(answer) + "\n")
        answers.flush()


if __name__ == "__main__":
    main()
