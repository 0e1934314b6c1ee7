"""``flexarm compare``: a twin run beside an experiment or another run
(:mod:`flexarm_ros.analysis.compare_cli`, docs/compare.md)."""

from __future__ import annotations

from flexarm_ros.io.arguments import number


def add_parser(sub) -> None:
    c = sub.add_parser("compare", help="a twin run beside an experiment or another run: "
                                       "frequencies, errors, pass/fail, report")
    c.add_argument("run", help="the twin's bag (flexarm run --record), or a CSV")
    c.add_argument("reference", help="MCAP bag (twin, or foreign with --map) or CSV "
                                     "('t [s]', 'name [unit]', ...)")
    c.add_argument("--report", metavar="DIR", help="write DIR/report.md and PNG figures")
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.add_argument("--map", metavar="MAP.yaml", help="channel map for the reference "
                   "(foreign bag topics/fields, or renamed/rescaled CSV columns)")
    c.add_argument("--offset", default="auto", metavar="auto|none|SECONDS",
                   help="run(t + offset) = reference(t); auto: cross-correlation (default)")
    c.add_argument("--max-shift", type=number, metavar="S",
                   help="search range of --offset auto, s (default 0.5)")
    c.add_argument("--threshold", type=number, help="pass mark on |relative error| "
                                                   "(default 0.10 = ±10 %%)")
    c.add_argument("--channels", nargs="+", metavar="NAME",
                   help="only these channels (default: every common one)")
    c.add_argument("--window", metavar="START:END",
                   help="analyse only this span of the reference clock, s (e.g. 2.1:2.5)")
    c.set_defaults(func=main)


def main(args):
    """Twin run vs reference (docs/compare.md): 0 pass, 1 fail, 2 bad input."""
    from flexarm_ros.analysis.compare_cli import run_cli
    return run_cli(args)
