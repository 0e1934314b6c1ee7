"""Every YAML a user hands the project is read with limits (issue 39, item 3).

An alias bomb, a document nested thousands of levels deep and a key given twice are each
refused in one line, exit 2, before anything is built; every shipped scene, spec and map
loads exactly as ``yaml.safe_load`` reads it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from flexarm_ros.cli import main
from flexarm_ros.errors import InputError
from flexarm_ros.scene.yaml_input import MAX_DEPTH, MAX_NODES, load_yaml

ROOT = Path(__file__).resolve().parents[1]

#: nine levels of anchors, each aliasing the one below ten times: 10⁹ leaves when walked
BOMB = ('a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x", "x"]\n'
        + "".join(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]\n"
                  for i in range(1, 10))
        + "links: *a9\n")
DEEP = "links: " + "[" * 5000 + "]" * 5000 + "\n"
TWICE = "duration: 1.0\nlinks: []\nduration: 2.0\n"


def _one_line(capsys, code) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("text, says", [
    (BOMB, f"expands to more than {MAX_NODES:,} nodes"),
    (DEEP, f"nested deeper than {MAX_DEPTH} levels at line 1"),
    (TWICE, "key 'duration' given twice (line 1 and line 3)"),
])
def test_each_limit_is_one_error_naming_the_source(text, says):
    with pytest.raises(InputError) as info:
        load_yaml(text, "x.yaml")
    assert str(info.value).startswith("x.yaml: ") and says in str(info.value)
    assert "\n" not in str(info.value)


def _yaml12(value):
    r"""safe_load's value with its strings that YAML 1.2's core schema reads as floats
    (spec 1.2.2, 10.3.2: [-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?) as floats."""
    import re
    if isinstance(value, dict):
        return {k: _yaml12(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_yaml12(v) for v in value]
    # where 1.1 and 1.2 differ: an exponent without a dot or a sign (a quoted "0.001"
    # stays a string in both)
    if isinstance(value, str) and re.fullmatch(
            r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)[eE][-+]?[0-9]+", value) and not re.fullmatch(
            r"[-+]?[0-9]*\.[0-9]*[eE][-+][0-9]+", value):
        return float(value)
    return value


def test_within_the_limits_it_is_yaml_safe_load():
    """Every YAML file of the repository (scenes, specs, maps) loads as safe_load reads
    it, numbers as YAML 1.2 reads them (``69.0e9`` a float, which YAML 1.1 leaves a
    string); so do anchors within the bound, merge keys and an empty file."""
    files = sorted([*ROOT.glob("config/*.yaml"), *ROOT.glob("examples/*.yaml"),
                    *ROOT.glob("bags/*.yaml")])
    assert len(files) >= 10
    for f in files:
        text = f.read_text(encoding="utf-8")
        assert load_yaml(text, f.name) == _yaml12(yaml.safe_load(text)), f
    small = 'base: &b {x: 1, y: [1, 2]}\nother:\n  <<: *b\n  z: *b\n'
    assert load_yaml(small, "s") == yaml.safe_load(small)
    assert load_yaml("", "e") is None
    nested = "a: " + "[" * (MAX_DEPTH - 2) + "1" + "]" * (MAX_DEPTH - 2) + "\n"
    assert load_yaml(nested, "n") == yaml.safe_load(nested)


@pytest.mark.heavy
@pytest.mark.parametrize("text, says", [(BOMB, "nodes"), (DEEP, "nested deeper"),
                                        (TWICE, "given twice")])
def test_every_command_reading_yaml_refuses_in_one_line(tmp_path, capsys, text, says):
    """A scene (simulate), an ensemble spec (uncertainty), a calibration spec and a
    channel map (compare): exit 2, one line naming the file."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    csv = ROOT / "bags" / "synthetic_experiment_case1.csv"
    for argv in (["simulate", str(bad), "--duration", "0.01", "--out", str(tmp_path / "o.csv")],
                 ["uncertainty", str(bad), "--workers", "0", "--out", str(tmp_path / "u.csv")],
                 ["calibrate", "--spec", str(bad)],
                 ["compare", str(ROOT / "bags" / "golden_case1.mcap"), str(csv), "--map",
                  str(bad)]):
        line = _one_line(capsys, main(argv))
        assert "bad.yaml" in line and says in line, (argv[0], line)
    assert not (tmp_path / "o.csv").exists() and not (tmp_path / "u.csv").exists()
