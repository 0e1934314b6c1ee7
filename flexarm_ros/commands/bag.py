"""``flexarm bag repair`` and ``flexarm bag export``: the bag tools
(:mod:`flexarm_ros.bag.repair`, :mod:`flexarm_ros.analysis.export`)."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub) -> None:
    b = sub.add_parser("bag", help="bag tools (repair, export)")
    bsub = b.add_subparsers(dest="bag_command", required=True, metavar="{repair,export}")
    br = bsub.add_parser("repair", help="rewrite what is readable of a damaged or unfinished "
                                        "MCAP bag (killed recorder, corrupt chunks) into a "
                                        "complete file")
    br.add_argument("bag", type=Path, metavar="IN.mcap", help="the damaged bag (kept as is)")
    br.add_argument("--out", type=Path, metavar="OUT.mcap",
                    help="the complete bag to write (default: IN.repaired.mcap)")
    br.add_argument("--json", action="store_true", help="print the report as JSON")
    br.set_defaults(func=repair)
    be = bsub.add_parser("export", help="write a twin bag's channels as 'name [unit]' CSV "
                                        "tables (what flexarm compare and calibrate read)")
    be.add_argument("bag", type=Path, metavar="BAG.mcap", help="a bag of flexarm run --record")
    be.add_argument("--out", type=Path, metavar="run.csv", required=True,
                    help="the main table (control ticks); batch sensors go to "
                         "run.sensors_<rate>hz.csv beside it")
    be.add_argument("--topics", nargs="+", metavar="TOPIC",
                    help="only the channels of these topics (absolute, or relative to the "
                         "bag's namespace; spaces or commas)")
    be.add_argument("--json", action="store_true", help="print what was written as JSON")
    be.set_defaults(func=export)


def repair(args):
    """A damaged or unfinished bag rewritten complete; see flexarm_ros.bag.repair."""
    from flexarm_ros.bag.repair import cli
    return cli(args)


def export(args):
    """A twin bag's channels as name [unit] CSV tables; see flexarm_ros.analysis.export."""
    from flexarm_ros.analysis.export import cli
    return cli(args)
