"""Regenerate docs/study/: the speed–accuracy ladder of the seed scenes.

    python tools/run_study_docs.py [scene ...]     # ~4 min per scene on 2 cores

Writes, per scene, <scene>.json (the rows of `flexarm study --json`), <scene>.txt (the
table) and <scene>.png (the Pareto plot).
"""

import json
import sys
from pathlib import Path

from flexarm_ros.scene import load_scene
from flexarm_ros.studies.ladder import format_table, plot_pareto, run_study

SCENES = ["two_link_free", "link_tipmass", "hydraulic_2kg", "spin_up"]


def main(names):
    out = Path(__file__).resolve().parents[1] / "docs" / "study"
    out.mkdir(parents=True, exist_ok=True)
    for name in names or SCENES:
        rows = run_study(load_scene(name), progress=lambda m: print(m, flush=True))
        (out / f"{name}.json").write_text(json.dumps(rows, indent=2) + "\n")
        (out / f"{name}.txt").write_text(format_table(rows) + "\n")
        plot_pareto(rows, out / f"{name}.png", title=name)
        print(f"wrote docs/study/{name}.*", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
