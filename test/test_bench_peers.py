"""bench/bench_peers.py (issue 36 item 5): it imports and its flexarm_ros part runs without
the peer codes; setup.py declares the ``peers`` extra; the peer parts run a short case
where the extra is installed (skipped otherwise)."""

import ast
import importlib.util
import pathlib

import numpy as np
import pytest

from flexarm_ros.sim.truth import measures

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_peers_under_test",
                                                  ROOT / "bench" / "bench_peers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_setup_declares_the_peers_extra_and_the_package_does_not_need_it():
    tree = ast.parse((ROOT / "setup.py").read_text())
    extras = None
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "extras_require":
            extras = ast.literal_eval(node.value)
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            required = " ".join(ast.literal_eval(node.value))
    assert extras is not None
    peers = " ".join(extras["peers"])
    assert "exudyn" in peers and "mujoco" in peers
    assert "exudyn" not in required and "mujoco" not in required
    # the package itself never imports them
    for path in (ROOT / "flexarm_ros").rglob("*.py"):
        text = path.read_text()
        assert "import exudyn" not in text and "import mujoco" not in text, path


def test_the_flexarm_part_runs_and_is_measured_on_the_grid(bench):
    d = bench.scene_data("spin_up")
    assert d["kind"] == "motion" and d["L"] == 10.0 and d["EA"] == 2.8e7
    link = bench.scene_data("link_tipmass")
    assert link["kind"] == "torque" and link["tip_m"] == 0.5
    assert link["EA"] == bench.LINK_EA                    # the rod is inextensible there
    grid = bench.GRID["spin_up"]
    cols, cpu = bench.flexarm_run(d, {"output_dt": grid}, 0.2, grid)
    assert cpu > 0 and len(cols["t"]) == 21
    np.testing.assert_allclose(cols["t"], np.arange(21) * grid, atol=1e-12)
    # the hub-frame deflection of a run from its world tip and the prescribed angle
    phi = np.array([bench.motion(d, t)[0] for t in cols["t"]])
    again = bench._columns(d, cols["t"], np.c_[cols["tip_x"], cols["tip_y"]], phi)
    np.testing.assert_allclose(again["beam_tip_deflection"], cols["beam_tip_deflection"],
                               atol=1e-9)
    m = measures(again, cols, ["beam"])
    assert m.position_m == 0.0


def test_the_table_and_the_front_ratio(bench):
    rows = [{"tool": "Exudyn ANCF", "setting": "a", "cpu_per_s": 1.0, "position_m": 1e-6,
             "deflection_m": 1e-6, "deflection_share": 1e-5},
            {"tool": "Exudyn ANCF", "setting": "b", "cpu_per_s": 0.1, "position_m": 1e-4,
             "deflection_m": 1e-4, "deflection_share": 1e-3},
            {"tool": "flexarm_ros", "setting": "rod", "cpu_per_s": 0.01, "position_m": 1e-5,
             "deflection_m": 1e-5, "deflection_share": 1e-4},
            {"tool": "MuJoCo rod", "setting": "x", "failed": "not expressed"}]
    res = {"scene": "spin_up", "duration_s": 1.0, "grid_s": 0.01, "reference": "ref",
           "agreement": [], "peak_deflection_m": 0.5, "rows": rows, "repeats": 1}
    (setting, err, ratio), = bench.front_ratio(res)
    assert setting == "rod" and err == 1e-5
    assert ratio == pytest.approx(np.sqrt(10.0) * 0.1 / 0.01 * 1.0, rel=1e-9)   # 0.316/0.01
    text = bench.markdown([res])
    assert "| flexarm_ros | rod | 0.01 |" in text and "failed: not expressed" in text


@pytest.mark.subprocess          # importing exudyn starts a child process
def test_the_peers_run_a_short_case_where_installed(bench):
    pytest.importorskip("exudyn")
    d = bench.scene_data("spin_up")
    grid = bench.GRID["spin_up"]
    cols, cpu = bench.ancf_run(d, 4, 0.01, 0.2, grid)
    ref, _ = bench.flexarm_run(d, {"output_dt": grid}, 0.2, grid)
    assert measures(cols, ref, ["beam"]).position_m < 1e-4
    pytest.importorskip("mujoco")
    cols, cpu = bench.mujoco_run(d, 10, 0.00025, 0.2, grid)
    assert measures(cols, ref, ["beam"]).position_m < 1e-3
