"""Loading scenes: a YAML file or a parsed mapping validated into a :class:`Scene`; the
shipped scenes in ``config/`` found by name from a source tree, a pip install or an ament
prefix."""

from __future__ import annotations

from pathlib import Path

from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.scene.schema import from_mapping
from flexarm_ros.scene.sections import Scene
from flexarm_ros.scene.yaml_input import load_yaml, read_yaml_text

#: the scene every command uses when none is named: seed 000 Case 1 (the wall strike)
DEFAULT_SCENE = "two_link_case1"


def load_scene_dict(data) -> Scene:
    """Validate a parsed mapping into a :class:`Scene`."""
    return from_mapping(Scene, data, "")


def load_scene(path) -> Scene:
    """Load and validate a scene YAML file (a path, or a name of a shipped scene)."""
    p = resolve_scene_path(path)
    try:
        # UTF-8 text, bounded: depth, alias expansion, duplicates
        data = load_yaml(read_yaml_text(p, "scene"), str(p))
    except InputError as exc:
        raise SceneError(str(exc)) from None
    try:
        return load_scene_dict(data)
    except InputError as exc:
        raise SceneError(f"{p.name}: {exc}") from None


def config_dir() -> Path:
    """The shipped ``config/`` folder (source tree, or ``share/flexarm_ros/config``)."""
    import os
    import sys
    here = Path(__file__).resolve()
    share = Path("share") / "flexarm_ros" / "config"
    candidates = [here.parents[2] / "config",              # source tree / editable install
                  Path(sys.prefix) / share]                 # pip install (data_files)
    # colcon / ament: <prefix>/share/flexarm_ros/config, prefixes from AMENT_PREFIX_PATH,
    # and the install prefix above lib/pythonX.Y/site-packages/flexarm_ros/model/
    candidates += [Path(p) / share for p in os.environ.get("AMENT_PREFIX_PATH", "").split(
        os.pathsep) if p]
    if len(here.parents) > 5:
        candidates.append(here.parents[5] / share)
    for c in candidates:
        if c.is_dir():
            return c
    raise SceneError("cannot find the shipped config/ folder (looked in "
                     + ", ".join(str(c) for c in candidates) + ")")


def resolve_scene_path(path) -> Path:
    """A scene path as given, or the shipped scene of that name (``link`` → config/link.yaml)."""
    p = Path(path)
    if p.is_file():
        return p
    for cand in (config_dir() / p.name, config_dir() / f"{p.name}.yaml"):
        if cand.is_file():
            return cand
    raise SceneError(f"scene: got {str(path)!r}, expected an existing YAML file or the name of "
                     f"a shipped scene ({', '.join(shipped_scenes())})")


def shipped_scenes() -> list[str]:
    return sorted(p.stem for p in config_dir().glob("*.yaml"))
