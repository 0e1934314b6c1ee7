"""``flexarm new``: a commented scene of one's own to edit
(:func:`flexarm_ros.scene.template.scene_text`), checked by the scene loader before it is
written."""

from __future__ import annotations

from pathlib import Path

from flexarm_ros.io.arguments import integer


def add_parser(sub) -> None:
    from flexarm_ros.scene.template import CONTROLS, MAX_LINKS
    p = sub.add_parser("new", help="write a commented scene of one's own to edit")
    p.add_argument("path", type=Path, help="the scene file to write (.yaml)")
    p.add_argument("--links", type=integer, default=2,
                   help=f"number of links, 1-{MAX_LINKS} (default 2)")
    p.add_argument("--control", choices=CONTROLS, default="open_loop",
                   help="open_loop: a voltage step on each motor (default); position: "
                        "joint PD to a target")
    p.add_argument("--vertical", action="store_true",
                   help="the arm in a vertical plane (gravity in it, starting at rest)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=main)


def main(args):
    from flexarm_ros.errors import InputError
    from flexarm_ros.io.paths import check_output_file
    from flexarm_ros.scene.loading import load_scene_dict
    from flexarm_ros.scene.template import MAX_LINKS, scene_text
    from flexarm_ros.scene.yaml_input import load_yaml
    if not 1 <= args.links <= MAX_LINKS:
        raise InputError(f"--links: got {args.links}, expected 1 to {MAX_LINKS}")
    path = check_output_file("path", args.path, (".yaml", ".yml"))
    if path.exists() and not args.force:
        raise InputError(f"path: got {str(path)!r}, which exists; expected a new file "
                         f"(--force overwrites it)")
    name = path.stem if path.stem[:1].isalpha() else f"arm_{path.stem}"
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    text = scene_text(name, args.links, args.control, args.vertical)
    scene = load_scene_dict(load_yaml(text, str(path)))      # the template loads as it is
    path.write_text(text, encoding="utf-8")
    print(f"{path}: scene {scene.name}, {len(scene.links)} link(s), "
          f"{'position control' if args.control == 'position' else 'open loop'}; next: "
          f"flexarm explain {path}")
    return 0
