"""Regenerate docs/config_reference.md from the scene schema (the single source of truth).

    python tools/gen_config_reference.py        # writes docs/config_reference.md
"""

from pathlib import Path

from flexarm_ros.scene import Scene
from flexarm_ros.scene.schema import reference_markdown

HEADER = """# Scene file reference

Generated from `flexarm_ros/scene/sections.py` by `python tools/gen_config_reference.py`;
a test fails when this file is out of date. SI units; unknown keys are errors.

"""


def render() -> str:
    return HEADER + reference_markdown(Scene, "scene (top level)")


if __name__ == "__main__":
    out = Path(__file__).resolve().parents[1] / "docs" / "config_reference.md"
    out.write_text(render())
    print(f"wrote {out}")
