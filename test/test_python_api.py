"""The Python API runs what the CLI runs: tables byte for byte, the linear model equal to
the export, the same refusals; docs/python.md's examples as doctests."""

from __future__ import annotations

import doctest
import json
from pathlib import Path

import numpy as np
import pytest

import flexarm_ros as fx
from flexarm_ros.cli import main

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("name,duration", [("two_link_position", 0.3),   # a controller
                                           ("two_link_case1", 0.2),      # a wall
                                           ("hydraulic_2kg", 0.2)])      # a servovalve
def test_simulate_writes_the_clis_table_byte_for_byte(tmp_path, name, duration):
    assert main(["simulate", name, "--duration", str(duration), "--quiet",
                 "--out", str(tmp_path / "cli.csv")]) == 0
    run = fx.simulate(name, duration=duration)
    run.to_csv(tmp_path / "api.csv")
    assert (tmp_path / "api.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
    for cli in tmp_path.glob("cli.sensors_*.csv"):
        api = tmp_path / cli.name.replace("cli.", "api.")
        assert api.read_bytes() == cli.read_bytes()
    assert run.t[-1] <= duration + 1e-12 and run.t[-1] > duration - 0.01   # the output grid


def test_the_result_reads_as_the_table(tmp_path):
    run = fx.simulate("two_link_free", duration=0.1, rung="cubic")
    assert run.summary["rung"] == "cubic" and run.t[0] == 0.0
    assert run["tip_x"].shape == run.t.shape and run.units["tip_x"] == "m"
    with pytest.raises(KeyError, match="no such column; the columns are t, "):
        run["nope"]
    with pytest.raises(fx.InputError, match="path: "):
        run.to_csv(tmp_path / "x.txt")


def test_linearize_is_the_export(tmp_path):
    control = pytest.importorskip("control")
    assert main(["linearize", "two_link_position", "--out", str(tmp_path / "ss.npz")]) == 0
    ref = np.load(tmp_path / "ss.npz")
    sys = fx.linearize("two_link_position")
    assert isinstance(sys, control.StateSpace)
    for key in "ABCD":
        assert np.array_equal(getattr(sys, key), ref[key])
    assert sys.state_labels == list(ref["states"]) and sys.output_labels == list(ref["outputs"])
    assert np.array_equal(sys.x0, ref["x0"]) and sys.units["inputs"] == ["V", "V"]
    raw = fx.linearize("two_link_position", python_control=False)
    assert np.array_equal(raw.A, ref["A"])
    assert main(["linearize", "two_link_position", "--closed-loop", "--json"]) == 0


def test_modes_and_design_are_the_commands(tmp_path, capsys):
    assert main(["modes", "link_tipmass", "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    api = fx.modes("link_tipmass")
    assert np.array_equal(api["frequencies_hz"], cli["frequencies_hz"])
    assert api["joints"] == cli["joints"] == "locked"
    assert main(["design", "two_link_position", "--shaper", "zvd",
                 "--out", str(tmp_path / "s.yaml")]) == 0
    written = fx.load_scene(tmp_path / "s.yaml").control.shaper
    shaped = fx.design("two_link_position", shaper="zvd").control.shaper
    assert shaped.times == written.times and shaped.amplitudes == written.amplitudes


@pytest.mark.parametrize("call,says", [
    (lambda: fx.load_scene("two_link_free", set={"links[0].beam.EI": -1.0}),
     "links[0].beam.EI: got -1.0, expected a finite number > 0.0 (N·m²)"),
    (lambda: fx.load_scene("two_link_free", set={"links[0].beam.GA": 1.0}),
     "links[0].beam.GA: unknown key"),
    (lambda: fx.load_scene("two_link_free", rungg="rod"), "rungg: unknown keyword"),
    (lambda: fx.simulate("two_link_free", duration=-1.0), "--duration: got -1.0"),
    (lambda: fx.modes("link_tipmass", joints="loose"), "joints: got 'loose'"),
    (lambda: fx.design("two_link_case1"), "control.mode: got None, expected 'position'"),
])
def test_bad_input_raises_the_clis_one_line_error(call, says):
    with pytest.raises(fx.InputError) as exc:
        call()
    assert says in str(exc.value) and "\n" not in str(exc.value)


def test_the_cli_says_the_same_line(capsys):
    assert main(["simulate", "two_link_free", "--set", "links[0].beam.EI=-1"]) == 2
    line = capsys.readouterr().err.strip()
    with pytest.raises(fx.InputError) as exc:
        fx.load_scene("two_link_free", set={"links[0].beam.EI": -1})
    assert line == f"flexarm: error: {exc.value}"


def test_docs_python_md_runs(tmp_path, monkeypatch):
    pytest.importorskip("control")
    monkeypatch.chdir(ROOT)
    res = doctest.testfile(str(ROOT / "docs" / "python.md"), module_relative=False,
                           globs={"tmp": tmp_path}, optionflags=doctest.ELLIPSIS)
    assert res.attempted >= 15 and res.failed == 0
