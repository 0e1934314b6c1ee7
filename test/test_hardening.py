"""Issue 12: nothing hangs, every bad path ends in one clear line.

* the work budget (``fidelity.max_steps``): a run whose step collapsed is refused before
  integrating, fast, naming the step's eigenvalue, the coordinate that takes part in it
  and its scene keys — checked against closed forms (an armature's rate R/L, steps =
  duration / dt) and against the scene key that was made absurd;
* the model size and the modal rung's memory;
* scene rules (names, hub radius, encoder range, reach, output period);
* the command line: durations, output paths checked before the work, namespaces, the
  modes count, non-UTF-8 scenes, replay of a bag whose twin topics carry other types;
* the plant: an encoder count beyond int32 stops the run at the time the closed form says;
* progress on stderr (simulated time / total) and ``--quiet``.
"""

from __future__ import annotations

import copy
import math
import os
import subprocess
import sys
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from flexarm_ros.cli import main
from flexarm_ros.errors import InputError, SceneError, SimulationDiverged, WorkTooLarge
from flexarm_ros.nodes import environment
from flexarm_ros.scene import load_scene, load_scene_dict
from flexarm_ros.scene.loading import config_dir

ROOT = Path(__file__).resolve().parents[1]


def shipped(name) -> dict:
    return yaml.safe_load((config_dir() / f"{name}.yaml").read_text(encoding="utf-8"))


def _set(data, path, value):
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return data


def simulate_argv(tmp_path, data, *extra):
    p = tmp_path / f"{data['name']}.yaml"
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return ["simulate", str(p), "--quiet", *extra]


def one_error_line(capsys, code, expect=2) -> str:
    err = capsys.readouterr().err
    lines = [ln.split("\r")[-1] for ln in err.split("\n") if ln.split("\r")[-1].strip()]
    assert code == expect, err
    assert len(lines) == 1, lines
    assert "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------------------ work budget
def test_armature_rate_sets_the_step_and_is_named_with_its_closed_form(tmp_path, capsys,
                                                                     monkeypatch):
    """inductance 1e-9 H: the current's eigenvalue is −R/L (the mechanical rates are 1e6
    times slower); the refusal names it, the current, L and R, and the quasi-static fix —
    up front: the integrator is never entered (the run itself: ~1e10 steps)."""
    import flexarm_ros.sim.integrate as integ

    def never(*args, **kwargs):
        raise AssertionError("a step was taken: the refusal must come first")
    for name in ("warm_up", "rk4_dense", "rk4_loop", "trapezoid_loop"):
        monkeypatch.setattr(integ.kloops, name, never)
    for name in ("_run_rk4_dense", "_run_trapezoid", "rk4_step"):
        monkeypatch.setattr(integ, name, never)
    data = _set(shipped("link_motor"), ("links", 0, "joint", "drive", "inductance"), 1e-9)
    data["fidelity"]["integrator"] = "rk4"       # lawson4, the scene's, has no such limit
    R = data["links"][0]["joint"]["drive"]["resistance"]
    code = main(simulate_argv(tmp_path, data))
    msg = one_error_line(capsys, code)
    assert msg.startswith("flexarm: error: fidelity.max_steps: the run needs")
    lam = float(msg.split("λ = ")[1].split(" ")[0])
    assert lam == pytest.approx(-R / 1e-9, rel=1e-3)
    for frag in ("link1_current", "links[0].joint.drive.inductance = 1e-09 H",
                 f"links[0].joint.drive.resistance = {R:g}", "quasi_static",
                 "expected at most 1e+08"):
        assert frag in msg, frag


def test_fixed_step_count_is_duration_over_dt(capsys):
    code = main(["simulate", "link", "--dt", "1e-12", "--duration", "2", "--quiet",
                 "--integrator", "rk4"])
    msg = one_error_line(capsys, code)
    assert "the run needs 2e+12 rk4 steps (duration 2 s / step 1e-12 s)" in msg
    assert "fixed fidelity.dt = 1e-12 s" in msg and "--dt 0" in msg


def test_budget_is_a_parameter(capsys):
    """The same run passes under a budget of its own step count and is refused one below
    (the count: duration / automatic step)."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.linear import smooth_rhs
    from flexarm_ros.model.statics import initial_x
    from flexarm_ros.sim.integrate import choose_step
    sc = load_scene("link").with_fidelity(rung="cubic", integrator="rk4")
    ch = Chain(sc)
    h = choose_step(ch, initial_x(ch), "rk4", 0.0, sc.fidelity.output_dt,
                    dense=smooth_rhs(ch))
    need = 0.05 / h                 # the dense output's step need not divide the run
    steps = math.ceil(need - 1e-9)
    base = ["simulate", "link", "--rung", "cubic", "--integrator", "rk4", "--duration",
            "0.05", "--quiet"]
    assert main(base + ["--max-steps", str(steps)]) == 0
    capsys.readouterr()
    code = main(base + ["--max-steps", str(steps - 1)])
    msg = one_error_line(capsys, code)
    assert f"needs {need:.3g} rk4 steps" in msg and f"at most {steps - 1:.3g}" in msg


@pytest.mark.parametrize("path, value, coordinate, key", [
    (("links", 0, "beam", "mass_per_length"), 1e-12, "link1_y",
     "links[0].beam.mass_per_length = 1e-12 kg/m"),
    (("links", 0, "beam", "damping"), {"stiffness_proportional": 1e12}, "link1_y",
     "links[0].beam.damping.stiffness_proportional = 1e+12 s"),
    (("links", 0, "beam", "damping"), {"viscous_per_length": 1e12}, "link1_y",
     "links[0].beam.damping.viscous_per_length = 1e+12 N·s/m²"),
], ids=["mass_per_length", "stiffness_damping", "viscous_damping"])
def test_collapsed_beam_step_names_the_beam_key(tmp_path, capsys, path, value, coordinate,
                                                key):
    data = _set(shipped("link"), path, value)
    # the seed's own model (nodes link1_y…) by RK4, whose step the collapse sets (lawson4,
    # the scene's integrator since session 21, steps the linearization exactly)
    data["fidelity"].update(rung="fd", refine=10, integrator="rk4")
    code = main(simulate_argv(tmp_path, data))
    msg = one_error_line(capsys, code)
    assert f"in which {coordinate}" in msg and key in msg
    assert "--integrator trapezoid" in msg and "--refine" in msg


def test_joint_damper_on_the_second_link_is_named_by_participation(tmp_path, capsys):
    """A damper of 1e12 N·m·s/rad on joint 2 (a relative angle): its mode's right
    eigenvector spreads over link 1 (M⁻¹e₂), its participation sits on link2_joint."""
    data = _set(shipped("two_link_case2"), ("links", 1, "joint", "drive_damping"), 1e12)
    data["duration"] = 0.01
    code = main(simulate_argv(tmp_path, data))
    msg = one_error_line(capsys, code)
    assert "in which link2_joint takes the largest part" in msg
    assert "links[1].joint.drive_damping = 1e+12" in msg


@pytest.mark.timeout(300)      # a hang guard, not a speed test: unstopped, it runs for hours
def test_adaptive_run_is_stopped_by_its_pace(tmp_path, capsys):
    """dop853 has no step to check up front: the pace of its first steps projects the
    total, and the run stops within a window of steps, not after hours."""
    data = _set(shipped("link"), ("links", 0, "beam", "mass_per_length"), 1e-12)
    # the seed's own model (nodes link1_y…) by RK4, whose step the collapse sets (lawson4,
    # the scene's integrator since session 21, steps the linearization exactly)
    data["fidelity"].update(rung="fd", refine=10, integrator="rk4")
    code = main(simulate_argv(tmp_path, data, "--integrator", "dop853", "--max-steps",
                              "1e5"))
    msg = one_error_line(capsys, code)
    assert "the dop853 run has taken" in msg and "link1_y" in msg
    assert "mass_per_length = 1e-12" in msg


def test_twin_run_is_refused_before_any_node_starts():
    from flexarm_ros.run import run
    data = _set(shipped("link_motor"), ("links", 0, "joint", "drive", "inductance"), 1e-9)
    sc = load_scene_dict(data)
    from flexarm_ros.sim.plant import check_plant_work
    # the plant has no drive states (the driver integrates the current exactly): fine
    check_plant_work(sc, 1.0)
    with pytest.raises(WorkTooLarge) as info:
        run("link", duration=1.0, record=None, fidelity={"dt": 1e-12}, progress=False)
    assert "fidelity.max_steps" in str(info.value) and "fixed fidelity.dt" in str(info.value)



@pytest.mark.subprocess
def test_simulator_node_started_on_its_own_checks_the_budget():
    """``ros2 run flexarm_ros simulator`` (no ``flexarm run`` before it): the node's own
    process refuses the run in one line, exit 2, before it publishes anything."""
    r = subprocess.run([sys.executable, "-m", "flexarm_ros.nodes.simulator", "--ros-args",
                        "-p", "scene:=link", "-p", "duration:=1.0", "-p", "dt:=1e-12"],
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, **environment.child_environment()})
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("simulator: error: fidelity.max_steps") and "fidelity.dt" in line


# ------------------------------------------------------------------------- model size
@pytest.mark.timeout(300)      # a hang guard, not a speed test (fem 200 took 27 s to build)
def test_a_model_too_large_to_build_is_refused_before_building(capsys):
    for rung, refine in (("fem", 200), ("fd", 400)):
        code = main(["modes", "link", "--rung", rung, "--refine", str(refine)])
        msg = one_error_line(capsys, code)
        assert f"fidelity.refine: got {refine}" in msg and "expected at most 200" in msg


def test_fine_eigen_mesh_matrices_equal_the_full_build():
    """The modal rung's eigen-solve mesh is built without S: its K and M are the full
    build's, bit for bit."""
    from flexarm_ros.model.beams import hermite_fem
    beam = load_scene("link").links[0].beam
    full, light = hermite_fem(beam, 12), hermite_fem(beam, 12, with_S=False)
    assert light.S is None
    for a in ("K", "M_e", "D", "phi_tip", "slope_tip"):
        assert np.array_equal(getattr(full, a), getattr(light, a)), a


@pytest.mark.subprocess
def test_forty_modes_build_within_a_memory_limit():
    """modal 40 used to build a 480-element S tensor (14 GB, killed by the kernel)."""
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30)); "
            "from flexarm_ros.scene import load_scene; from flexarm_ros.model.chain import "
            "Chain; c = Chain(load_scene('link').with_fidelity(rung='modal', refine=40), "
            "backend='numpy'); print(c.n)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300, env={"FLEXARM_NO_NUMBA": "1", "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "41"


# ------------------------------------------------------------------------ scene rules
BASE = {"name": "base",
        "links": [{"name": "l1", "beam": {"length": 1.0, "EI": 2.0, "mass_per_length": 0.5},
                   "hub": {"inertia": 0.01}}],
        "inputs": [{"joint": 1, "torque": {"type": "constant", "value": 0.1}}]}


def _scene(**patch):
    data = copy.deepcopy(BASE)
    for path, v in patch.items():
        _set(data, tuple(int(p) if p.isdigit() else p for p in path.split("__")), v)
    return data


@pytest.mark.parametrize("name", ["enc,1", "", "a b", "1abc", "ä", "x-y", "a.b"])
def test_names_that_would_break_a_table_are_refused(name):
    with pytest.raises(SceneError) as info:
        load_scene_dict(_scene(links__0__name=name))
    assert str(info.value).startswith(f"links[0].name: got {name!r}, expected")
    data = _scene()
    data["sensors"] = [{"name": name, "kind": "potentiometer", "joint": 1, "rate_hz": 100.0}]
    with pytest.raises(SceneError) as info:
        load_scene_dict(data)
    assert str(info.value).startswith(f"sensors[0].name: got {name!r}, expected")


def test_sensor_columns_must_be_unique():
    data = _scene()
    data["sensors"] = [{"name": "a", "kind": "potentiometer", "joint": 1, "rate_hz": 100.0},
                       {"name": "a_true", "kind": "potentiometer", "joint": 1,
                        "rate_hz": 100.0}]
    with pytest.raises(SceneError, match=r"sensors\[1\]\.name: got 'a_true', whose column "
                                         r"'a_true' is also a column of sensors\[0\]"):
        load_scene_dict(data)
    data["sensors"] = [{"name": "t", "kind": "potentiometer", "joint": 1, "rate_hz": 100.0}]
    with pytest.raises(SceneError, match="the time column"):
        load_scene_dict(data)


def test_hub_radius_names_itself_and_the_reason():
    load_scene_dict(_scene(links__0__beam__hub_radius=100.0))          # 100 lengths: ok
    with pytest.raises(SceneError) as info:
        load_scene_dict(_scene(links__0__beam__hub_radius=1e6))
    msg = str(info.value)
    assert msg.startswith("links[0].beam.hub_radius: got 1000000.0 m, expected at most 100")
    assert "round-off" in msg and "inertia" in msg


def test_encoder_counts_must_keep_a_thousand_revolutions_within_int32():
    """counts per output revolution = gear ratio × lines × quadrature; the boundary is
    exact: 1000 revolutions of counts = 2³¹ − 1 passes, one count more fails."""
    def scene(ratio, lines):
        data = _scene()
        data["links"][0]["joint"] = {"drive_inertia": 0.01, "drive": {
            "type": "dc_motor", "gear_ratio": ratio, "torque_constant": 0.05,
            "back_emf_constant": 0.05, "resistance": 1.0}}
        data["inputs"] = [{"joint": 1, "voltage": {"type": "constant", "value": 1.0}}]
        data["sensors"] = [{"name": "enc", "kind": "encoder", "joint": 1, "rate_hz": 1000.0,
                            "lines_per_rev": lines, "quadrature": 1}]
        return data
    limit = (2**31 - 1) / 1000                  # counts per revolution
    load_scene_dict(scene(limit / 2, 2))        # exactly at the limit
    with pytest.raises(SceneError) as info:
        load_scene_dict(scene(limit / 2 * (1 + 1e-9), 2))
    assert str(info.value).startswith("links[0].joint.drive.gear_ratio: got")
    assert "±1000 revolutions fit the int32 counts" in str(info.value)
    with pytest.raises(SceneError, match=r"^sensors\[0\]\.lines_per_rev: got 3000000"):
        load_scene_dict(scene(1.0, 3_000_000))


def test_tool_and_wall_within_reach():
    reach = 1.0 + 0.2
    data = _scene(links__0__beam__hub_radius=0.2)
    data["tool"] = {"position": [reach, 0.0]}
    load_scene_dict(data)                                 # exactly the reach
    data["tool"] = {"position": [0.0, 1.21]}
    with pytest.raises(SceneError, match=r"^tool\.position: got \[0\.0, 1\.21\] m \(1\.21 m "
                                         r"from the last tip frame\), expected at most the "
                                         r"arm's reach 1\.2 m"):
        load_scene_dict(data)
    data["tool"] = {"position": [0.1, 0.0]}
    far = 2 * (reach + 0.1)
    data["walls"] = [{"point": [far, 5.0], "normal": [-1.0, 0.0]}]
    load_scene_dict(data)
    data["walls"] = [{"point": [far * 1.001, 5.0], "normal": [-2.0, 0.0]}]
    with pytest.raises(SceneError, match=r"^walls\[0\]\.point: got .* a wall line 2\.6026 m "
                                         r"from the base, expected at most twice the reach"):
        load_scene_dict(data)


def test_output_period_longer_than_the_run_is_refused(capsys):
    with pytest.raises(SceneError, match=r"^fidelity\.output_dt: got 10\.0 s, expected at "
                                         r"most the duration 1\.0 s"):
        load_scene_dict(_scene(fidelity={"output_dt": 10.0}))
    code = main(["simulate", "link", "--duration", "0.0005", "--quiet"])
    msg = one_error_line(capsys, code)
    assert "fidelity.output_dt: got 0.001 s, expected at most the run's duration 0.0005 s" in msg


# ----------------------------------------------------------------------- command line
@pytest.mark.parametrize("value", ["inf", "nan", "-1", "0", "-inf"])
@pytest.mark.parametrize("command", ["simulate", "study", "run"])
def test_durations(command, value, capsys):
    if command == "run" and value == "inf":
        pytest.skip("run --duration inf: until Ctrl-C (documented)")
    code = main([command, "link", f"--duration={value}"])
    msg = one_error_line(capsys, code)
    assert f"--duration: got {float(value)}" in msg and "> 0 s" in msg


@pytest.mark.timeout(300)      # a hang guard: every case is refused before any work
def test_output_paths_are_checked_before_the_work(tmp_path, capsys):
    """Each refusal comes before any simulation (two_link_case1's 6 s would take longer
    than the refusal) and leaves nothing behind."""
    (tmp_path / "d.csv").mkdir()
    (tmp_path / "d.mcap").mkdir()
    (tmp_path / "f").write_text("x")
    bag = ROOT / "bags" / "golden_case1.mcap"
    csv = ROOT / "bags" / "synthetic_experiment_case1.csv"
    cases = [
        (["simulate", "two_link_case1", "--out", tmp_path / "d.csv"], "--out",
         "an existing directory"),
        (["simulate", "two_link_case1", "--out", tmp_path / "no" / "x.csv"], "--out",
         "does not exist"),
        (["simulate", "two_link_case1", "--out", tmp_path / "f" / "x.csv"], "--out",
         "is not a directory"),
        (["simulate", "two_link_case1", "--out", "/proc/x.csv"], "--out", "writable"),
        (["linearize", "link", "--out", tmp_path / "no" / "ss.npz"], "--out",
         "does not exist"),
        (["study", "link", "--png", tmp_path / "no" / "p.png"], "--png", "does not exist"),
        (["run", "two_link_case1", "--record", tmp_path / "d.mcap"], "--record",
         "an existing directory"),
        (["run", "two_link_case1", "--record", tmp_path / "run.txt"], "--record",
         "expected a .mcap file name"),
        (["run", "two_link_case1", "--record", "/proc/run.mcap"], "--record", "writable"),
        (["run", "two_link_case1", "--rerun", tmp_path / "no" / "v.rrd"], "--rerun",
         "does not exist"),
        (["compare", bag, csv, "--report", tmp_path / "f"], "--report", "an existing file"),
        (["compare", bag, csv, "--report", tmp_path / "f" / "sub"], "--report",
         "is a file"),
    ]
    for argv, flag, why in cases:
        code = main([str(a) for a in argv])
        msg = one_error_line(capsys, code)
        assert msg.startswith(f"flexarm: error: {flag}: got '"), msg
        assert why in msg, msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.csv", "d.mcap", "f"]
    code = main(["replay", str(bag), "--rerun", str(tmp_path / "no" / "v.rrd")])
    assert code == 2 and "--rerun" in capsys.readouterr().err


@pytest.mark.parametrize("ns, ok", [
    ("/flexarm", "/flexarm"), ("flexarm", "/flexarm"), ("/", "/"), ("/lab/arm_2", "/lab/arm_2"),
    ("/_private", "/_private"),
    ("1abc", None), ("/a//b", None), ("/a/", None), ("a b", None), ("/a-b", None),
    ("/ä", None), ("~/x", None), ("", None), ("/lab/2arm", None), ("/" + "n" * 200, None)])
def test_namespace_follows_the_ros2_rules(ns, ok):
    from flexarm_ros.nodes.names import check_namespace
    if ok is None:
        with pytest.raises(InputError, match=r"^--namespace: got .*expected a ROS 2 namespace"):
            check_namespace("--namespace", ns)
    else:
        assert check_namespace("--namespace", ns) == ok


def test_valid_namespaces_are_valid_for_rclpy():
    """The rule above against rclpy's own validator (rmw_validate_namespace)."""
    validate = pytest.importorskip("rclpy.validate_namespace").validate_namespace
    from rclpy.exceptions import InvalidNamespaceException
    from flexarm_ros.nodes.names import check_namespace
    for ns in ["/flexarm", "/", "/lab/arm_2", "/_private", "/A9"]:
        assert validate(check_namespace("--namespace", ns))
    for ns in ["/a//b", "/a/", "/a-b", "/lab/2arm", "/ä"]:
        with pytest.raises(InvalidNamespaceException):
            validate(ns)


def test_bad_namespace_stops_run_and_replay_before_ros(capsys):
    code = main(["run", "link", "--namespace", "1abc", "--duration", "0.01"])
    assert "--namespace: got '1abc'" in one_error_line(capsys, code)
    code = main(["replay", str(ROOT / "bags" / "golden_case1.mcap"), "--namespace", "/a//b"])
    assert "--namespace: got '/a//b'" in one_error_line(capsys, code)


def test_modes_count_must_be_positive(capsys):
    code = main(["modes", "link", "--count", "-1"])
    assert "--count: got -1, expected an integer >= 1" in one_error_line(capsys, code)
    code = main(["modes", "link", "--count", "0"])
    assert "--count: got 0" in one_error_line(capsys, code)


def test_non_utf8_and_unreadable_scenes(tmp_path, capsys):
    p = tmp_path / "latin1.yaml"
    p.write_bytes("name: caf\xe9\n".encode("latin-1"))
    code = main(["simulate", str(p)])
    msg = one_error_line(capsys, code)
    assert "latin1.yaml: got byte 0xe9 at offset 9, expected a UTF-8 text file" in msg
    q = tmp_path / "broken.yaml"
    q.write_text("name: [x\nlinks: {\n")
    code = main(["modes", str(q)])
    assert "broken.yaml: not valid YAML at line" in one_error_line(capsys, code)


def test_replay_names_a_twin_topic_with_another_type(tmp_path, capsys):
    from flexarm_ros.bag.writer import BagWriter
    bag = tmp_path / "foreign.mcap"
    with BagWriter(bag) as w:
        for k in range(3):
            w.write("/flexarm/ground_truth/tip", "std_msgs/msg/Float64MultiArray",
                    {"layout": {"dim": [], "data_offset": 0}, "data": [1.0, 2.0]}, k * 1000)
    pytest.importorskip("rerun")
    code = main(["replay", str(bag), "--rerun", str(tmp_path / "v.rrd")])
    msg = one_error_line(capsys, code)
    assert ("/flexarm/ground_truth/tip: got message type std_msgs/msg/Float64MultiArray, "
            "expected geometry_msgs/msg/PointStamped") in msg


@pytest.mark.heavy
@pytest.mark.subprocess
def test_console_script_prints_one_line_and_no_traceback(tmp_path):
    """The real entry point, in a process: bad input is one line on stderr, exit 2."""
    latin = tmp_path / "latin1.yaml"
    latin.write_bytes("name: caf\xe9\n".encode("latin-1"))
    (tmp_path / "dir.mcap").mkdir()
    for argv in (["simulate", str(latin)], ["simulate", "link", "--duration", "nan"],
                 ["run", "link", "--record", str(tmp_path / "dir.mcap")],
                 ["run", "link", "--namespace", "bad ns"],
                 ["modes", "link", "--count", "-1"], ["simulate", "link", "--dt", "abc"]):
        r = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", *argv],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert r.returncode == 2, (argv, r.stderr)
        assert "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, (argv, r.stderr)


# ---------------------------------------------------------------------------- plant
def test_encoder_beyond_int32_stops_the_plant_when_the_closed_form_says():
    """A free rigid link spinning at ω: counts = ⌊gain·ω·t⌋ leave int32 at
    t* = (2³¹ − 1)/(gain·ω); the plant stops at the first encoder sample past t* with
    SimulationDiverged naming the encoder (it crashed the message encoding before)."""
    from flexarm_ros.sim.plant import Plant
    omega, lines = 1000.0, 500_000                  # 2e6 counts per revolution
    data = _scene(links__0__joint={"initial_rate": omega})
    data["inputs"] = []
    data["links"][0]["joint"]["drive_inertia"] = 0.01
    data["fidelity"] = {"rung": "rigid"}
    data["sensors"] = [{"name": "enc", "kind": "encoder", "joint": 1, "rate_hz": 1000.0,
                        "lines_per_rev": lines, "quadrature": 4, "on_motor_shaft": False}]
    plant = Plant(load_scene_dict(data))
    gain = lines * 4 / (2 * math.pi)
    t_star = (2**31 - 1) / (gain * omega)           # ≈ 6.75 s (1074 revolutions)
    with pytest.raises(SimulationDiverged) as info:
        for _ in range(10_000):
            plant.step(0.01)
    err = info.value
    assert err.quantity == "encoder enc counts" and "int32" in str(err)
    # the rate stays ω (free rigid link, no torque): the stop is within one sample of t*
    assert t_star < err.time <= t_star + 1e-3 + 1e-9


# -------------------------------------------------------------------------- progress
class _Clock:
    """perf_counter that advances 0.7 s per call: every report is due."""

    def __init__(self):
        self.t = 0.0

    def perf_counter(self):
        self.t += 0.7
        return self.t


@pytest.mark.parametrize("scene", ["link", "two_link_case1"])
def test_progress_shows_simulated_time_over_total(scene, monkeypatch, capsys):
    import flexarm_ros.sim.contact_stepper as cs
    import flexarm_ros.sim.integrate as integ
    monkeypatch.setattr(integ, "time", _Clock())
    monkeypatch.setattr(cs, "time", _Clock())
    # 0.5 s: enough steps for more than one compiled call (integrate.MIN_CALL_STEPS each)
    assert main(["simulate", scene, "--duration", "0.5", "--rung", "cubic"]) == 0
    err = capsys.readouterr().err
    shown = [s for s in re.split(r"[\r\n]", err) if s.strip()]     # a first run's
    assert any(s.strip().startswith("t = ") and "/ 0.5 s (" in s for s in shown), err  # compile notice too
    assert main(["simulate", scene, "--duration", "0.5", "--rung", "cubic",
                 "--quiet"]) == 0
    assert capsys.readouterr().err == ""
