"""Start-up of a ``flexarm simulate`` process (docs/performance.md, "Start-up"): what it
imports, how it
writes its CSV tables and its collector settings. Timings live in bench/bench_startup.py,
never here."""

from __future__ import annotations

import gc
import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flexarm_ros import cli
from flexarm_ros.errors import InputError
from flexarm_ros.io.tables import read_table, write_table

#: modules a plain rk4 simulate never needs (scipy.linalg comes with numba's BLAS check)
NOT_FOR_SIMULATE = ("scipy.integrate", "scipy.optimize", "scipy.signal", "matplotlib",
                    "rclpy", "mcap", "mcap_ros2", "rerun")


def _child(code: str, tmp_path) -> dict:
    """Run ``code`` in a fresh interpreter (cwd tmp_path); its last stdout line is JSON."""
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _loaded(names) -> str:
    return (f"[m for m in {tuple(names)!r} if m in sys.modules]")


@pytest.mark.subprocess
def test_cli_import_loads_no_scipy_numba_or_ros(tmp_path):
    got = _child("import json, sys\nimport flexarm_ros.cli\n"
                 f"print(json.dumps({_loaded(NOT_FOR_SIMULATE + ('scipy', 'numba'))}))",
                 tmp_path)
    assert got == []


@pytest.mark.subprocess
def test_rk4_simulate_process_imports_and_gc(tmp_path):
    """``flexarm simulate`` of an rk4 scene, as the console script runs it (``main()``
    reading sys.argv): no solve_ivp, optimizer, plotting or ROS module is loaded; the
    batch collector settings are on and the heap is frozen at the end."""
    code = ("import gc, json, sys\n"
            "sys.argv = ['flexarm', 'simulate', 'two_link_free', '--duration', '0.05',\n"
            "            '--out', 'run.csv', '--quiet']\n"
            "from flexarm_ros import cli\n"
            "rc = cli.main()\n"
            f"print(json.dumps({{'rc': rc, 'loaded': {_loaded(NOT_FOR_SIMULATE)},\n"
            "                  'threshold': gc.get_threshold(),\n"
            "                  'frozen': gc.get_freeze_count()}))")
    got = _child(code, tmp_path)
    assert got["rc"] == 0
    assert got["loaded"] == []
    assert tuple(got["threshold"]) == cli.BATCH_GC_THRESHOLD
    assert got["frozen"] > 0
    cols = read_table(tmp_path / "run.csv")
    assert len(cols["t"]) == 51 and np.all(np.isfinite(cols["energy"]))


def test_main_with_argv_leaves_the_collector_alone(tmp_path, capsys):
    """In-process callers (tests, tools: ``main([...])``) keep their collector settings."""
    before, frozen = gc.get_threshold(), gc.get_freeze_count()
    assert cli.main(["modes", "two_link_free", "--json"]) == 0
    capsys.readouterr()
    assert gc.get_threshold() == before and gc.get_freeze_count() == frozen


def test_solve_ivp_methods_load_on_use():
    import scipy.integrate

    from flexarm_ros.sim.integrate import SOLVE_IVP, solve_ivp_method
    assert {k: solve_ivp_method(k) for k in SOLVE_IVP} == {
        "rk45": scipy.integrate.RK45, "dop853": scipy.integrate.DOP853,
        "radau": scipy.integrate.Radau, "bdf": scipy.integrate.BDF,
        "lsoda": scipy.integrate.LSODA}


# ------------------------------------------------------------------------------- CSV
def _reference_csv(path, columns, units) -> None:
    """The CSV writer before the start-up work (np.char.mod per column, a join per row):
    the text write_table must keep."""
    names = list(columns)
    text = {k for k in names if np.asarray(columns[k]).dtype.kind in "OUS"}
    cols = [(np.asarray(columns[k]).astype(str) if k in text else
             np.char.mod("%.10g", np.asarray(columns[k], float))) for k in names]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(f"{k} [{units[k]}]" if k in units else k for k in names) + "\n")
        for row in zip(*cols):
            fh.write(",".join(row) + "\n")


AWKWARD = np.array([0.0, -0.0, 1.0, -1.0, 1 / 3, -2 / 3, 1e-300, 5e-324,
                    -2.2250738585072014e-308, 1.7976931348623157e308, 123456789012345678.0,
                    0.1 + 0.2, 1e16, 9.999999999e9, 99999.999995, 1.5e-5, np.pi * 1e-7,
                    2.0 ** 53 + 1, 0.5, 1e21])


def test_csv_bytes_equal_the_reference_writer(tmp_path):
    n = len(AWKWARD)
    cols = {"t": np.arange(n) * 1e-3, "a": AWKWARD, "b": AWKWARD[::-1].copy(),
            "ints": np.arange(n, dtype=int) - 7, "phase": np.array(
                ["free", "impact", "sliding", "sticking"] * (n // 4), dtype=object),
            "from_list": list(AWKWARD * 0.5)}
    units = {"t": "s", "a": "m", "phase": "text"}
    write_table(tmp_path / "new.csv", cols, units)
    _reference_csv(tmp_path / "ref.csv", cols, units)
    assert (tmp_path / "new.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=0, max_size=40))
def test_csv_bytes_and_round_trip_any_floats(tmp_path_factory, values):
    """Same bytes as the reference for any finite float64; reading back gives each value
    at its ten significant digits exactly (float('%.10g' % v)), and .npz gives the float64
    itself."""
    d = tmp_path_factory.mktemp("csv")
    x = np.array(values, float)
    cols = {"t": np.arange(len(x), dtype=float), "x": x, "neg": -x}
    write_table(d / "new.csv", cols, {"t": "s"})
    _reference_csv(d / "ref.csv", cols, {"t": "s"})
    assert (d / "new.csv").read_bytes() == (d / "ref.csv").read_bytes()
    back = read_table(d / "new.csv")
    if len(x):
        assert np.array_equal(back["x"], [float("%.10g" % v) for v in values])
    write_table(d / "x.npz", cols)
    z = read_table(d / "x.npz")
    assert np.array_equal(z["x"], x) and np.array_equal(np.signbit(z["x"]), np.signbit(x))


def test_csv_of_a_simulation_equals_the_reference(tmp_path):
    """A scene with a wall and sensors: text column (contact_phase), units, sensor tables."""
    from flexarm_ros.io.units import table_units
    from flexarm_ros.scene import load_scene
    from flexarm_ros.sim.simulate import simulate
    scene = load_scene("two_link_case1")
    res = simulate(scene, 0.05)
    tables = {"main": res.columns, **{f"s{r:g}": t for r, t in res.sensor_tables.items()}}
    assert "contact_phase" in res.columns and len(tables) > 1
    for name, cols in tables.items():
        units = table_units(cols, scene)
        write_table(tmp_path / f"{name}.csv", cols, units)
        _reference_csv(tmp_path / f"{name}.ref.csv", cols, units)
        assert ((tmp_path / f"{name}.csv").read_bytes()
                == (tmp_path / f"{name}.ref.csv").read_bytes()), name


def test_csv_long_table_in_chunks(tmp_path, monkeypatch):
    from flexarm_ros.io import tables
    monkeypatch.setattr(tables, "CSV_CHUNK_ROWS", 7)
    cols = {"t": np.linspace(0.0, 1.0, 50), "y": np.sin(np.arange(50.0))}
    write_table(tmp_path / "new.csv", cols)
    _reference_csv(tmp_path / "ref.csv", cols, {})
    assert (tmp_path / "new.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()


def test_write_table_refusals(tmp_path):
    with pytest.raises(InputError, match="column 'y' has non-finite"):
        write_table(tmp_path / "a.csv", {"t": [0.0, 1.0], "y": [1.0, np.inf]})
    with pytest.raises(ValueError, match="different lengths"):
        write_table(tmp_path / "a.csv", {"t": [0.0, 1.0], "y": [1.0]})
    assert not (tmp_path / "a.csv").exists()


# ---------------------------------------------------------------------- output columns
@pytest.mark.parametrize("name", ["two_link_free", "two_link_case3_backlash", "spin_up",
                                  "link_motor", "hydraulic_2kg"])
def test_energies_equal_the_numpy_energy(name):
    """Chain.energies (the energy and tip columns; compiled kinematics with numba and no
    gravity) equals Chain.energy per sample to round-off; exactly on the numpy path."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.sim.simulate import simulate
    res = simulate(load_scene(name), 0.2)
    ch, run = res.chain, res.run
    E, tip = ch.energies(run.t, run.q, run.qd, run.z)
    ref = [ch.energy(q, qd) for q, qd in zip(run.q, run.qd)]
    E_ref = np.array([e["total"] for e in ref])
    tip_ref = np.array([e["tip"] for e in ref])
    assert np.array_equal(res.columns["energy"], E)
    scale = max(np.abs(E_ref).max(), 1e-300)
    if ch.backend == "numba" and not ch.has_gravity:
        assert np.abs(E - E_ref).max() <= 1e-13 * scale
        assert np.abs(tip - tip_ref).max() <= 1e-14
    else:
        assert np.array_equal(E, E_ref) and np.array_equal(tip, tip_ref)
