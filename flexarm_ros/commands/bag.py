"""``flexarm bag repair``, ``flexarm bag export`` and ``flexarm bag scene``: the bag tools
(:mod:`flexarm_ros.bag.repair`, :mod:`flexarm_ros.analysis.export`,
:func:`flexarm_ros.twin.recording.rerun_scene_text`)."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub) -> None:
    b = sub.add_parser("bag", help="bag tools (repair, export, scene)")
    bsub = b.add_subparsers(dest="bag_command", required=True,
                            metavar="{repair,export,scene}")
    br = bsub.add_parser("repair", help="rewrite what is readable of a damaged or unfinished "
                                        "MCAP bag (killed recorder, corrupt chunks) into a "
                                        "complete file")
    br.add_argument("bag", type=Path, metavar="IN.mcap", help="the damaged bag (kept as is)")
    br.add_argument("--out", metavar="OUT.mcap",
                    help="the complete bag to write (default: IN.repaired.mcap); an "
                         "existing directory (or a path ending in /): IN.repaired.mcap in "
                         "it")
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
    bs = bsub.add_parser("scene", help="write the scene a twin bag ran, with the live "
                                       "parameter sets it recorded as control.changes "
                                       "(flexarm simulate of it reruns the run)")
    bs.add_argument("bag", type=Path, metavar="BAG.mcap", help="a bag of flexarm run --record")
    bs.add_argument("--out", type=Path, metavar="SCENE.yaml", required=True,
                    help="the scene file to write")
    bs.set_defaults(func=scene)


def repair_output(bag, out) -> Path | None:
    """The file ``--out`` names: ``None`` (the default beside the input); a directory
    (existing, or written with a trailing separator) → ``IN.repaired.mcap`` in it, which
    must exist; else the path as given. Checked before the bag is read (InputError, exit
    2): a writable file in an existing directory."""
    import os
    from flexarm_ros.bag.repair import default_output
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    if out is None:
        return None
    text = str(out)
    as_dir = text.endswith(("/", os.sep)) or Path(text).is_dir()
    if as_dir:
        d = Path(text)
        if not d.is_dir():
            what = "is a file" if d.exists() else "does not exist"
            raise InputError(f"--out: got {text!r}, a directory that {what}, expected an "
                             f"existing directory (the repaired bag is written into it) or "
                             f"a file name OUT.mcap")
        path = d / default_output(bag).name
    else:
        path = Path(text)
    check_output_file("--out", path)      # the input itself: repair() refuses it
    return path


def repair(args):
    """A damaged or unfinished bag rewritten complete; see flexarm_ros.bag.repair."""
    from flexarm_ros.bag.repair import cli
    args.out = repair_output(args.bag, args.out)
    return cli(args)


def export(args):
    """A twin bag's channels as name [unit] CSV tables; see flexarm_ros.analysis.export."""
    from flexarm_ros.analysis.export import cli
    return cli(args)


def scene(args):
    """The scene a bag ran, with its recorded live parameter changes (control.changes)."""
    import sys
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.twin.recording import recorded_changes, rerun_scene_text
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    if not args.bag.is_file():
        raise InputError(f"BAG.mcap: got {str(args.bag)!r}, expected an existing bag file")
    args.out = check_output_file("--out", args.out, (".yaml", ".yml"))
    bag = read_bag(str(args.bag))
    text = rerun_scene_text(bag)
    args.out.write_text(text, encoding="utf-8")
    print(f"{args.bag}: the scene it ran, {len(recorded_changes(bag))} live parameter "
          f"changes as control.changes → {args.out}", file=sys.stdout)
    return 0

