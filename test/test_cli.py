"""The flexarm command: simulate / modes / explain, outputs and errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from flexarm_ros.cli import main
from flexarm_ros.io.tables import read_table


def test_simulate_csv_has_header_and_named_columns(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "link_tipmass", "--duration", "0.05", "--out", str(out),
                 "--rung", "cubic", "--quiet"]) == 0
    cols = read_table(out)
    for key in ("t", "link1_joint", "link1_tip_disp", "link1_tip_rot", "link1_joint_rate",
                "link1_tip_disp_rate", "tip_x", "tip_y", "energy"):
        assert key in cols
    assert cols["t"][0] == 0.0 and np.isclose(cols["t"][-1], 0.05)
    # the hub radius 0.075 m + beam 1 m: the undeformed tip is at x = 1.075
    assert np.isclose(cols["tip_x"][0], 1.075)


def test_simulate_npz_equals_csv(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.npz"
    for f in (a, b):
        assert main(["simulate", "link", "--duration", "0.02", "--out", str(f), "--quiet",
                     "--rung", "modal", "--refine", "2"]) == 0
    ca, cb = read_table(a), read_table(b)
    assert list(ca) == list(cb)
    for k in ca:
        assert np.allclose(ca[k], cb[k], rtol=1e-9, atol=1e-12)


def test_simulate_json_summary(capsys):
    assert main(["simulate", "two_link_free", "--duration", "0.05", "--json"]) == 0
    summ = json.loads(capsys.readouterr().out)
    for key in ("status", "message", "sim_time_s", "wall_time_s", "real_time_factor",
                "rhs_evaluations", "steps"):
        assert key in summ
    assert summ["status"] == 0 and np.isclose(summ["sim_time_s"], 0.05)
    # RK4: four stages per step; the ẋ at the end of a step with an output sample inside
    # it (the dense output's cubic Hermite; the 9.94 ms automatic step > 1 ms) is the
    # next step's first stage, so at most the last one is extra (one compiled call)
    assert summ["step_s"] > 1e-3
    assert 4 * summ["steps"] <= summ["rhs_evaluations"] <= 4 * summ["steps"] + 1


def test_fidelity_overrides_reach_the_model(capsys):
    assert main(["simulate", "link", "--duration", "0.01", "--json", "--rung", "fem",
                 "--refine", "3", "--integrator", "dop853", "--rtol", "1e-6",
                 "--atol", "1e-9"]) == 0
    summ = json.loads(capsys.readouterr().out)
    assert summ["rung"] == "fem" and summ["integrator"] == "dop853"
    assert len(summ["coordinates"]) == 1 + 6


def test_modes_json_matches_closed_form(capsys):
    from flexarm_ros.testing import beam_theory
    assert main(["modes", "link_tipmass", "--joints", "locked", "--json", "--rung", "fem",
                 "--refine", "12"]) == 0
    out = json.loads(capsys.readouterr().out)
    ref = beam_theory.tip_loaded_frequencies_hz(2000.0, 1.0, 1.0, 0.5, 0.002, 3)
    assert np.allclose(out["frequencies_hz"][:3], ref, rtol=1e-4)
    assert out["frequencies_hz"] == sorted(out["frequencies_hz"])


def test_modes_free_joints_include_the_rigid_mode(capsys):
    assert main(["modes", "link_tipmass", "--joints", "free", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frequencies_hz"][0] == 0.0 and out["frequencies_hz"][1] > 1.0


def test_explain_names_coordinates_and_omissions(capsys):
    assert main(["explain", "link_tipmass", "--no-check"]) == 0
    text = capsys.readouterr().out
    assert "link1_joint" in text and "left out" in text and "gravity" in text
    assert "contact (no wall in this scene)" in text
    assert main(["explain", "two_link_case1"]) == 0      # a scene with a wall
    modelled, left_out = capsys.readouterr().out.split("left out:")[:2]
    assert "wall walls[0] (point [-0.025, 0.0] m" in modelled and "friction 0.5" in modelled
    assert "no wall" not in left_out.splitlines()[0]


@pytest.mark.parametrize("argv, fragment", [
    (["simulate", "no_such_scene"], "expected an existing YAML file"),
    (["simulate", "link", "--refine", "2", "--rung", "fd"], "expected >= 4 segments"),
    (["simulate", "link", "--rtol", "-1"], "fidelity.rtol: got -1.0"),
    (["simulate", "link", "--duration", "0.01", "--out", "x.txt"], "expected a .csv or .npz"),
    (["simulate", "link", "--rung", "cubic", "--integrator", "rk4", "--dt", "0.5",
      "--duration", "0.01"], "RK4 stability limit"),
])
def test_bad_input_exits_with_a_clear_message(argv, fragment, capsys, tmp_path,
                                              monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(argv)
    assert code in (2, 3)
    assert fragment in capsys.readouterr().err
    assert not (tmp_path / "x.txt").exists()


@pytest.mark.subprocess
def test_console_entry_point_runs_default_scene(tmp_path):
    from flexarm_ros.scene import DEFAULT_SCENE
    out = tmp_path / "run.csv"
    r = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "simulate", "--duration",
                        "0.02", "--out", str(out), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert DEFAULT_SCENE == "two_link_case1"
    assert r.stdout.startswith(f"{DEFAULT_SCENE}: ") and out.exists()


@pytest.mark.subprocess
def test_core_imports_without_rclpy():
    code = ("import sys; sys.modules['rclpy'] = None; "
            "import flexarm_ros.model.chain, flexarm_ros.sim.simulate, flexarm_ros.cli, "
            "flexarm_ros.nodes.environment, flexarm_ros.run; "
            "print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr


def test_config_reference_is_up_to_date():
    import pathlib
    import runpy
    root = pathlib.Path(__file__).resolve().parents[1]
    mod = runpy.run_path(str(root / "tools" / "gen_config_reference.py"))
    assert (root / "docs" / "config_reference.md").read_text() == mod["render"](), \
        "run: python tools/gen_config_reference.py"


def test_study_refuses_the_options_its_ladder_varies(capsys):
    """--rung etc. would be silently replaced by the ladder: they are not study options."""
    with pytest.raises(SystemExit) as info:
        main(["study", "link", "--rung", "fem"])
    assert info.value.code == 2
    assert "unrecognized arguments: --rung fem" in capsys.readouterr().err


def test_the_progress_line_is_cleared_only_when_drawn(capsys):
    """An error right after start must not be preceded by a blanked line (a log read
    '\\r' + 48 spaces + '\\r' before every one-line error)."""
    import io
    import sys

    from flexarm_ros.commands.common import Progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    real, sys.stderr = sys.stderr, Tty()
    try:                                          # on a terminal: redrawn, then blanked
        p = Progress(2.0, quiet=False)
        p.clear()
        assert sys.stderr.getvalue() == ""
        p(0.5)
        p.clear()
        err = sys.stderr.getvalue()
    finally:
        sys.stderr = real
    assert err.startswith("\r  t = 1 / 2 s") and err.endswith(" " * Progress.WIDTH + "\r")
    p = Progress(2.0, quiet=False)                # in a log (capsys): plain lines only
    p(0.5)
    p.clear()
    assert capsys.readouterr().err == "t = 1 / 2 s ( 50.0 %)\n"
    q = Progress(2.0, quiet=True)
    assert q.callback is None
    q.clear()
    assert capsys.readouterr().err == ""


def test_quiet_hides_progress_not_the_summary(capsys):
    argv = ["simulate", "link", "--duration", "0.05", "--rung", "cubic"]
    assert main(argv) == 0
    loud = capsys.readouterr()
    # a run this short may end before the first progress report (at most one per wall
    # second): then nothing was drawn and nothing is cleared
    assert loud.err == "" or loud.err.startswith("t = ")
    assert main(argv + ["--quiet"]) == 0
    quiet = capsys.readouterr()
    assert quiet.err == ""
    assert quiet.out.startswith("link: ") and "simulated in" in quiet.out
    assert quiet.out.count("\n") == loud.out.count("\n") == 1


@pytest.mark.parametrize("argv,expect", [
    (["--late-bound", "-1"], "--late-bound: got -1.0 s, expected a finite bound of at "
                             "least one control period (0.001 s)"),
    (["--ground-truth-rate", "-5"], "--ground-truth-rate: got -5.0, expected 0 (every "
                                    "tick)"),
    (["--layout", "triple"], "argument --layout: invalid choice: 'triple' (expected one "
                             "of 'one', 'split', 'processes')"),
])
def test_bad_run_flags_are_named_as_flags_before_anything_starts(capsys, argv, expect):
    try:
        code = main(["run", "--duration", "0.01", "--no-record", *argv])
    except SystemExit as exc:                     # argparse's own usage errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert expect in err and "Traceback" not in err and err.count("\n") == 1, err


# ------------------------------------------------------------------- --set KEY=VALUE
def _json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_set_reaches_modes_and_linearize_closed_form(capsys):
    """Every frequency of a beam on a locked (modes) or free ideal-torque (linearize, no
    damping) joint scales as √EI: the mass matrix does not see EI, the stiffness matrix
    is linear in it. link's EI is 2000 N·m²; --set doubles it."""
    ei = "links[0].beam.EI=4000"
    base = _json(capsys, ["modes", "link", "--joints", "locked", "--json"])
    set_ = _json(capsys, ["modes", "link", "--joints", "locked", "--json", "--set", ei])
    assert base["set"] == {} and set_["set"] == {"links[0].beam.EI": 4000}
    np.testing.assert_allclose(set_["frequencies_hz"], np.sqrt(2) * np.array(
        base["frequencies_hz"]), rtol=1e-9)

    def oscillations(out):
        e = np.linalg.eigvals(np.array(out["A"]))
        return np.sort(e.imag[e.imag > 0])
    lin = _json(capsys, ["linearize", "link", "--json"])
    lin2 = _json(capsys, ["linearize", "link", "--json", "--set", ei])
    assert lin2["set"] == {"links[0].beam.EI": 4000}
    np.testing.assert_allclose(oscillations(lin2), np.sqrt(2) * oscillations(lin), rtol=1e-9)
    assert main(["modes", "link", "--set", ei]) == 0
    assert "\n  set: links[0].beam.EI=4000\n" in capsys.readouterr().out


def test_set_reaches_simulate_and_an_explicit_flag_wins(tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    argv = ["simulate", "link", "--duration", "0.02", "--quiet"]
    assert main(argv + ["--out", str(a)]) == 0
    assert "set:" not in capsys.readouterr().out
    assert main(argv + ["--out", str(b), "--set", "fidelity.output_dt=2e-3"]) == 0
    assert capsys.readouterr().out.splitlines()[1] == "  set: fidelity.output_dt=0.002"
    ta, tb = read_table(a)["t"], read_table(b)["t"]       # 1 ms output → 2 ms
    assert len(ta) == 21 and len(tb) == 11 and np.allclose(tb, ta[::2])
    summ = _json(capsys, argv + ["--json", "--set", "fidelity.rung=fem", "--rung", "cubic"])
    assert summ["rung"] == "cubic" and summ["set"] == {"fidelity.rung": "fem"}
    assert _json(capsys, argv + ["--json"])["set"] == {}


def test_a_fidelity_set_survives_a_flag_that_changes_the_model(capsys):
    """--refine sends the scene's rod_modes, rod_points and dt back to their defaults (they
    were chosen for its rod); a --set of one of them alongside it is kept, not dropped."""
    argv = ["simulate", "two_link_free", "--duration", "0.05", "--quiet", "--json",
            "--refine", "8", "--set", "fidelity.rod_modes=4", "--set",
            "fidelity.rod_points=5", "--set", "fidelity.dt=0.0035"]
    assert main(argv) == 0
    summ = json.loads(capsys.readouterr().out)
    assert summ["step_s"] == 0.0035 and len(summ["coordinates"]) == 2 + 2 * 4
    assert main(["explain", "two_link_free", "--no-check", "--refine", "8", "--set",
                 "fidelity.rod_modes=4", "--set", "fidelity.rod_points=5"]) == 0
    text = capsys.readouterr().out
    assert "rung rod (refine 8; its lowest 4 bending modes; 5 Gauss points)" in text
    assert "4 elastic coordinate(s)" in text and ", 5 mass points" in text
    # without the sets, --refine alone: all 8 modes on the default 11 points
    assert main(["explain", "two_link_free", "--no-check", "--refine", "8"]) == 0
    text = capsys.readouterr().out
    assert "8 elastic coordinate(s)" in text and ", 11 mass points" in text
    # the modes alone: on the 8-term rod's 11 points, named in simulate's summary line
    assert main(["explain", "two_link_free", "--no-check", "--refine", "8", "--set",
                 "fidelity.rod_modes=4"]) == 0
    text = capsys.readouterr().out
    assert "4 elastic coordinate(s)" in text and ", 11 mass points" in text
    assert main(["simulate", "two_link_free", "--duration", "0.05", "--refine", "8",
                 "--set", "fidelity.rod_modes=4", "--dt", "0.0035"]) == 0
    assert "rung rod (lowest 4 modes of 8 terms), rkn4" in capsys.readouterr().out


def test_set_reaches_explain_and_creates_a_section_the_scene_leaves_out(capsys):
    assert main(["explain", "link", "--set", "fidelity.rung=fem", "--no-check"]) == 0
    text = capsys.readouterr().out
    assert "rung fem (refine" in text and text.endswith("set: fidelity.rung=fem\n")
    # two_link_free declares no control: section; the set creates one (twin_control)
    assert main(["explain", "two_link_free", "--set", "control.rate_hz=500",
                 "--no-check"]) == 0
    assert "control every 2 ms (500 Hz)" in capsys.readouterr().out


@pytest.mark.parametrize("sets,expect", [
    (["links[0].beam.EII=3"], "flexarm: error: links[0].beam.EII: unknown key; expected "
                              "one of E, EA, EI, damping, density, hub_radius, length, "
                              "mass_per_length, section, thickness"),
    (["links[0].beam.EI=-1"], "flexarm: error: links[0].beam.EI: got -1.0, expected a "
                              "finite number > 0"),
    (["links[0].beam.EI=stiff"], "links[0].beam.EI: got 'stiff' (str), expected a finite "
                                 "number > 0"),
    (["links[0].beam.EI"], "flexarm: error: --set: got 'links[0].beam.EI', expected "
                           "KEY=VALUE with a scene key path such as links[0].beam.EI"),
    (["links[0].beam.EI="], "--set: got 'links[0].beam.EI=', expected a VALUE after '='"),
    (["links[0]..EI=3"], "--set: got 'links[0]..EI=3', expected KEY=VALUE with KEY a "
                         "scene key path"),
    (["links[0].beam.EI=[1, 2"], "--set links[0].beam.EI: got '[1, 2', expected VALUE as "
                                 "one YAML scalar or flow value"),
    (["links[3].beam.EI=3"], "links[3].beam.EI: got index 3 of links, expected 0..0"),
    # values the schema admits one by one, which the scene refuses together
    (["fidelity.rung=fd", "fidelity.refine=2"], "fidelity.refine: got 2, expected >= 4 "
                                                "segments for the fd rung"),
    (["links[0].joint.backlash.width=0.01"], "links[0].joint.backlash.stiffness: missing "
                                             "required field"),
    (["fidelity.rung=fem", "fidelity.rung=fd"], "--set fidelity.rung: got it twice (fem and "
                                                "fd), expected each key once"),
])
@pytest.mark.parametrize("command", ["modes", "simulate"])
def test_bad_set_exits_2_with_one_line(capsys, command, sets, expect):
    argv = [command, "link", *[a for s in sets for a in ("--set", s)]]
    assert main(argv + (["--duration", "0.01", "--quiet"] if command == "simulate"
                        else [])) == 2
    cap = capsys.readouterr()
    assert expect in cap.err and cap.err.count("\n") == 1 and cap.out == "", cap.err


def test_set_values_are_yaml_with_numbers_in_exponent_form():
    from flexarm_ros.scene.overrides import format_sets, format_value, parse_set, parse_sets
    assert parse_set("links[0].beam.EI=6.0") == ("links[0].beam.EI", 6.0)
    assert parse_set("tool.position=[6.0, 8.0]") == ("tool.position", [6.0, 8.0])
    assert parse_set("fidelity.foreshortening=false") == ("fidelity.foreshortening", False)
    assert parse_set(" fidelity.rung = modal") == ("fidelity.rung", "modal")
    # YAML 1.1 reads 1e-3 as text; a user means the number (quoted it stays text)
    assert parse_set("fidelity.dt=1e-3") == ("fidelity.dt", 1e-3)
    assert parse_set("control.kp=[2e2, 1E+2]")[1] == [200.0, 100.0]
    assert parse_set("name='1e3'")[1] == "1e3"
    sets = parse_sets(["a=6.0", "b=[6.0, 8.0]", "c=true", "d=modal", "e='1e3'"])
    assert format_sets(sets) == "a=6.0, b=[6.0, 8.0], c=true, d=modal, e='1e3'"
    assert parse_sets([f"{k}={format_value(v)}" for k, v in sets.items()]) == sets
