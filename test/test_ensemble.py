"""The ensemble runner (flexarm_ros.ensemble): key paths, designs, metrics, the same table
from every executor to the bit, a killed worker, diverging and refused samples as rows,
sensitivity against known answers, uncertainty statistics, and bad input (exit 2).

Dask traffic stays on 127.0.0.1 (local clusters bind there; the separately started
scheduler and worker are given --host 127.0.0.1, free ports, no dashboard)."""

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from flexarm_ros.errors import InputError
from flexarm_ros.ensemble import keys as K
from flexarm_ros.ensemble.designs import make_design, parse_param
from flexarm_ros.ensemble.metrics import evaluate, parse_metric, resolve_metrics
from flexarm_ros.ensemble.runner import SceneModel, read_table, run_ensemble
from flexarm_ros.ensemble.spec import parse_spec
from flexarm_ros.scene import load_scene, load_scene_dict

DURATION = 0.1      # simulated seconds per sample


def small_data():
    """A short link with a tip body and a torque pulse (first frequency ~4 Hz)."""
    return {"name": "ensemble_probe", "duration": 1.0,
            "links": [{"name": "arm", "beam": {"length": 0.3, "EI": 2.0,
                                               "mass_per_length": 0.3},
                       "hub": {"inertia": 0.005}, "tip": {"mass": 0.3, "inertia": 1e-4}}],
            "inputs": [{"joint": 1, "torque": {"type": "pulse", "amplitude": 0.2,
                                               "start": 0.0, "width": 0.02}}]}


@pytest.fixture(scope="module")
def scene():
    return load_scene_dict(small_data())


def bits(table) -> list:
    """Every cell as text that holds every bit (repr of a float round-trips)."""
    return [[repr(r[c]) for c in table.columns if c != "wall_s_per_sim_s"]
            for r in table.rows]


# ---------------------------------------------------------------------------- keys
def test_set_keys_equals_editing_the_file(scene):
    got = K.set_keys(scene, {"links[0].tip.mass": 0.45, "links[0].beam.EI": 2.5})
    data = small_data()                                   # the same edit made by hand
    data["links"][0]["tip"]["mass"] = 0.45
    data["links"][0]["beam"]["EI"] = 2.5
    assert got == load_scene_dict(data)
    assert K.get_key(got, "links[0].tip.mass") == 0.45
    assert K.set_keys(scene, {}) is scene


def test_set_keys_grows_a_left_out_section():
    sc = load_scene("two_link_case1")
    assert sc.links[0].joint.backlash is None
    got = K.set_keys(sc, {"links[0].joint.backlash": {"width": 0.0, "stiffness": 2e3},
                          "links[0].joint.backlash.width": 0.01})
    assert got.links[0].joint.backlash.width == 0.01
    assert got.links[0].joint.backlash.stiffness == 2e3
    with pytest.raises(InputError, match=r"links\[0\]\.joint\.backlash\.stiffness: missing"):
        K.set_keys(sc, {"links[0].joint.backlash.width": 0.01})


def test_set_keys_applies_fidelity_as_the_command_line_does():
    """A sweep over fidelity.rung on spin_up (its fixed 3.3 ms was measured for its rod 5)
    steps each rung at its own step, as `--rung` does; a dt given with it, or an
    integrator alone, keep theirs."""
    sc = load_scene("spin_up")
    assert K.set_keys(sc, {"fidelity.rung": "fem"}).fidelity.dt == 0.0
    assert K.set_keys(sc, {"fidelity.integrator": "rkn4"}).fidelity.dt == 0.0033
    got = K.set_keys(sc, {"fidelity.rung": "cubic", "fidelity.dt": 0.005}).fidelity
    assert (got.rung, got.dt) == ("cubic", 0.005)
    assert K.set_keys(sc, {"fidelity.rung": "fem"}) == sc.with_fidelity(rung="fem")
    with pytest.raises(InputError, match=r"fidelity\.refine: got -1"):
        K.set_keys(sc, {"fidelity.refine": -1})


@pytest.mark.parametrize("assignment, pattern", [
    ({"links[0].joint.drive.resistnce": 1.0},
     r"links\[0\]\.joint\.drive\.resistnce: unknown key; expected one of .*resistance"),
    ({"links[0].joint.drive.resistance": -1.0},
     r"links\[0\]\.joint\.drive\.resistance: got -1\.0, expected a finite number > 0"),
    ({"links[2].beam.EI": 1.0}, r"links\[2\].*expected 0\.\.1"),
    ({"tool.position[0]": "a"}, r"tool\.position\[0\]: got 'a'"),
    ({"links[0]..beam": 1.0}, r"expected a scene key path"),
])
def test_set_keys_refuses_with_key_value_expectation(assignment, pattern):
    with pytest.raises(InputError, match=pattern):
        K.set_keys(load_scene("two_link_case1"), assignment)


def test_key_field_bounds():
    kf = K.key_field("links[0].joint.drive.resistance")
    assert kf.type is float and kf.gt == 0.0 and kf.unit == "Ω"
    assert not kf.admits(0.0) and kf.admits(1e-9)
    assert K.key_field("tool.position[1]").type is float
    assert K.key_field("fidelity.rung").choices
    with pytest.raises(InputError, match="unknown key"):
        K.key_field("links[0].joint.drive.nope")


# ------------------------------------------------------------------------- designs
def test_grid_is_the_cartesian_product(scene):
    ps = [parse_param("links[0].tip.mass=0.1:0.5", scene),
          parse_param("fidelity.rung=rigid,cubic", scene)]
    a = make_design(ps, "grid", 3)
    assert [(x["links[0].tip.mass"], x["fidelity.rung"]) for x in a] == [
        (m, r) for m in np.linspace(0.1, 0.5, 3) for r in ("rigid", "cubic")]


def test_lhs_has_one_point_per_stratum_and_is_seeded(scene):
    ps = [parse_param("links[0].tip.mass=0.1:0.5", scene),
          parse_param("links[0].beam.EI=1:3", scene)]
    a = make_design(ps, "lhs", 20, seed=3)
    for p in ps:
        u = np.array([(x[p.key] - p.lo) / (p.hi - p.lo) for x in a])
        assert sorted(np.floor(u * 20).astype(int)) == list(range(20))
    assert make_design(ps, "lhs", 20, seed=3) == a
    assert make_design(ps, "lhs", 20, seed=4) != a
    r = make_design(ps, "random", 8, seed=1)
    assert all(0.1 <= x["links[0].tip.mass"] <= 0.5 for x in r)
    with pytest.raises(InputError, match="power of two"):
        make_design(ps, "sobol", 12)
    assert len(make_design(ps, "sobol", 16)) == 16


@pytest.mark.parametrize("text, pattern", [
    ("links[0].tip.mass=0.5:0.1", r"got LO = 0\.5 > HI = 0\.1, expected LO <= HI"),
    ("links[0].tip.mass=-1:1", r"got LO = -1, expected >= 0"),
    ("links[0].tip.mas=1:2", r"links\[0\]\.tip\.mas: unknown key"),
    ("fidelity.rung=rigid,stiff", r"got 'stiff', expected one of"),
    ("links[0].tip.mass", r"expected KEY=LO:HI"),
    ("tool.position=0:1", r"expected a list of values"),
])
def test_bad_params(scene, text, pattern):
    with pytest.raises(InputError, match=pattern):
        parse_param(text, scene)


# ------------------------------------------------------------------------- metrics
class _Fake:
    """A SimResult stand-in with chosen columns."""
    def __init__(self, t, **cols):
        self.columns = {"t": t, **cols}
        self.sensor_tables = {}
        self.contact = None


def test_settling_time_and_final_error_of_a_first_order_response():
    tau, T = 0.05, 0.5
    t = np.arange(0.0, T + 1e-12, 1e-4)
    y = 1.0 - np.exp(-t / tau)
    res = _Fake(t, y=y)
    out = evaluate(res, [parse_metric("settling_time:y"), parse_metric("final_error:y=1.2")])
    # |y - y(T)| = e^-t/tau - e^-T/tau > 0.02 (1 - e^-T/tau) until
    eT = math.exp(-T / tau)
    t_s = -tau * math.log(0.02 * (1 - eT) + eT)
    assert abs(out["settling_time_y_s"] - t_s) <= 1e-4
    assert out["final_error_y"] == pytest.approx(abs(y[-1] - 1.2), rel=0, abs=1e-15)


def test_frequency_metric_finds_a_known_tone():
    t = np.arange(0.0, 1.0, 1e-3)
    res = _Fake(t, y=np.sin(2 * np.pi * 23.4 * t) * np.exp(-t) + 0.3 * t)
    f = evaluate(res, [parse_metric("frequency:y@0.2:end")])["frequency_y_hz"]
    assert abs(f - 23.4) < 0.1 * (1 / 0.8)            # the estimator's stated bound


def test_metric_names_and_wall_scenes(scene):
    assert [m.column for m in resolve_metrics([], load_scene("two_link_case1"))][0] == \
        "impact_time_s"                                # always there with a wall
    with pytest.raises(InputError, match="no wall"):
        resolve_metrics(["bounce_height"], scene)
    with pytest.raises(InputError, match=r"--metric: got 'freq'"):
        parse_metric("freq")


# ----------------------------------------------------- determinism on every executor
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def external_cluster(tmp_path_factory):
    """`dask scheduler` and `dask worker` started as separate processes on 127.0.0.1."""
    pytest.importorskip("distributed")
    d = tmp_path_factory.mktemp("dask")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    sched = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host",
                              "127.0.0.1", "--port", str(port), "--no-dashboard"],
                             cwd=d, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
    worker = subprocess.Popen([sys.executable, "-m", "dask", "worker", addr, "--host",
                               "127.0.0.1", "--nworkers", "1", "--nthreads", "1",
                               "--no-dashboard"], cwd=d, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        yield addr
    finally:
        for p in (worker, sched):
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in (worker, sched):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def _sweep(scene):
    """Six samples: four ok, one diverging (a tiny deflection limit trips the guard),
    one refused (a negative beam stiffness)."""
    ps = [parse_param("links[0].tip.mass=0.1:0.5", scene),
          parse_param("links[0].beam.EI=2.0,3.0", scene)]
    a = make_design(ps, "grid", 2)
    a.append({"links[0].tip.mass": 0.3, "links[0].beam.EI": 2.0,
              "fidelity.max_deflection_ratio": 1e-6})
    a.append({"links[0].tip.mass": 0.3, "links[0].beam.EI": -2.0})
    return a


@pytest.mark.heavy
@pytest.mark.subprocess
def test_same_table_on_every_executor_to_the_bit(scene, external_cluster, tmp_path):
    pytest.importorskip("distributed")
    a = _sweep(scene)
    metrics = ["max_tip_deflection", "frequency:arm_tip_deflection", "settling_time:tip_y"]
    kw = dict(metrics=metrics, duration=DURATION,
              params=["links[0].tip.mass", "links[0].beam.EI"])
    serial = run_ensemble(scene, a, workers=0, **kw)
    one = run_ensemble(scene, a, workers=1, **kw)
    local = run_ensemble(scene, a, workers=None, **kw)         # default: one per core
    remote = run_ensemble(scene, a, scheduler=external_cluster, **kw)
    assert "LocalCluster, 1 " in one.meta["executor"]
    assert f"LocalCluster, {os.cpu_count()} " in local.meta["executor"]
    assert external_cluster in remote.meta["executor"]
    assert bits(one) == bits(serial)
    assert bits(local) == bits(serial)
    assert bits(remote) == bits(serial)
    # the statuses are data: the diverging and the refused sample are rows with messages
    st = [r["status"] for r in serial.rows]
    assert st == ["ok"] * 4 + ["diverged", "refused"]
    assert "simulation diverged" in serial.rows[4]["message"]
    assert "max_deflection_ratio" in serial.rows[4]["message"]
    assert serial.rows[5]["message"].startswith("links[0].beam.EI: got -2.0, expected")
    assert all(math.isnan(serial.rows[k]["max_tip_deflection_m"]) for k in (4, 5))
    # the ok rows are the plain simulations' values (the runner adds nothing)
    from flexarm_ros.sim.simulate import simulate
    direct = simulate(K.set_keys(scene, a[3]), DURATION)
    d = np.max(np.abs(direct.columns["arm_tip_deflection"]))
    assert serial.rows[3]["max_tip_deflection_m"] == d
    # the table read back from CSV holds the same bits
    serial.write(tmp_path / "t.csv")
    back = read_table(tmp_path / "t.csv")
    assert [[repr(r[c]) for c in serial.columns] for r in back] == \
        [[repr(r[c]) for c in serial.columns] for r in serial.rows]
    pytest.importorskip("pyarrow")
    serial.write(tmp_path / "t.parquet")
    back = read_table(tmp_path / "t.parquet")
    assert [[repr(r[c]) for c in serial.columns] for r in back] == \
        [[repr(r[c]) for c in serial.columns] for r in serial.rows]


@pytest.mark.subprocess
def test_a_killed_worker_leaves_a_complete_table(scene):
    """SIGKILL one of two workers while tasks run: the scheduler reruns its tasks (the
    nanny starts a fresh worker) and the table equals the serial one."""
    pytest.importorskip("distributed")
    from flexarm_ros.ensemble.runner import open_executor
    ps = [parse_param("links[0].tip.mass=0.1:0.5", scene)]
    a = make_design(ps, "grid", 10)
    kw = dict(metrics=["max_tip_deflection"], duration=0.3)
    want = run_ensemble(scene, a, workers=0, **kw)
    model = SceneModel(scene, resolve_metrics(kw["metrics"], scene), kw["duration"])
    ex = open_executor(2, warm_up=model.warm_up)
    try:
        pids_before = ex.client.run(os.getpid)
        out = {}
        th = threading.Thread(target=lambda: out.setdefault(
            "t", run_ensemble(scene, a, model=model, executor=ex)))
        th.start()
        deadline = time.monotonic() + 60
        victim = None
        while victim is None and time.monotonic() < deadline:
            busy = {w: ts for w, ts in ex.client.processing().items() if ts}
            if busy:
                victim = sorted(busy)[0]
            else:
                time.sleep(0.02)
        assert victim is not None, "no task ever ran"
        os.kill(pids_before[victim], signal.SIGKILL)
        th.join(timeout=120)
        assert not th.is_alive()
        pids_after = ex.client.run(os.getpid)
    finally:
        ex.close()
    got = out["t"]
    assert victim not in pids_after                     # that worker is gone
    assert [r["status"] for r in got.rows] == ["ok"] * len(a)
    assert bits(got) == bits(want)


# ---------------------------------------------------------------------- sensitivity
def _analytic_spec(names, low, high):
    return parse_spec({"unknowns": [{"key": n, "dist": "uniform", "low": lo, "high": hi}
                                    for n, lo, hi in zip(names, low, high)]},
                      check_keys=False)


def test_sobol_recovers_the_ishigami_indices():
    from flexarm_ros.ensemble.uq import run_sensitivity
    from flexarm_ros.testing.analytic_models import Ishigami
    model = Ishigami()
    spec = _analytic_spec(["x1", "x2", "x3"], [-math.pi] * 3, [math.pi] * 3)
    res, table = run_sensitivity(spec, "sobol", 2048, seed=1, model=model, workers=0)
    assert len(table.rows) == 2048 * 5
    truth = model.indices()
    ranked = {r["unknown"]: r for r in res["metrics"]["y"]["ranked"]}
    for i, n in enumerate(("x1", "x2", "x3")):
        r = ranked[n]
        for k in ("S1", "ST"):
            assert abs(r[k] - truth[k][i]) <= max(2 * r[f"{k}_conf"], 0.02), (n, k, r)
    assert [r["unknown"] for r in res["metrics"]["y"]["ranked"]] == ["x1", "x2", "x3"]


def test_morris_and_sobol_on_a_linear_model():
    from flexarm_ros.ensemble.uq import run_sensitivity
    from flexarm_ros.testing.analytic_models import Linear
    c = {"a": 3.0, "b": -1.0, "c": 0.0}
    low, high = [0.0, 1.0, -2.0], [1.0, 5.0, 2.0]
    spec = _analytic_spec(list(c), low, high)
    res, _ = run_sensitivity(spec, "morris", 10, seed=2, model=Linear(c), workers=0)
    r = {x["unknown"]: x for x in res["metrics"]["y"]["ranked"]}
    for n, lo, hi in zip(c, low, high):
        assert r[n]["mu_star"] == pytest.approx(abs(c[n]) * (hi - lo), rel=1e-12, abs=1e-12)
        assert r[n]["sigma"] == pytest.approx(0.0, abs=1e-9)
    w = {n: (c[n] * (hi - lo)) ** 2 for n, lo, hi in zip(c, low, high)}
    res, _ = run_sensitivity(spec, "sobol", 1024, seed=2, model=Linear(c), workers=0)
    r = {x["unknown"]: x for x in res["metrics"]["y"]["ranked"]}
    for n in c:
        assert r[n]["S1"] == pytest.approx(w[n] / sum(w.values()), abs=0.03)
        assert r[n]["ST"] == pytest.approx(w[n] / sum(w.values()), abs=0.03)


# ---------------------------------------------------------------------- uncertainty
def test_truncated_distributions_have_their_moments():
    from scipy.stats import norm
    from flexarm_ros.ensemble.uq import run_uncertainty
    from flexarm_ros.testing.analytic_models import Linear
    mu, sd, lo, hi = 1.0, 0.5, 0.6, 2.5
    spec = parse_spec({"unknowns": [
        {"key": "x", "dist": "normal", "mean": mu, "std": sd, "low": lo, "high": hi},
        {"key": "z", "dist": "lognormal", "median": 2.0, "sigma": 0.3}]}, check_keys=False)
    table, stats, _ = run_uncertainty(spec, 20000, seed=5, model=Linear({"x": 1.0}),
                                      workers=0)
    a, b = (lo - mu) / sd, (hi - mu) / sd
    Z = norm.cdf(b) - norm.cdf(a)
    mean = mu + sd * (norm.pdf(a) - norm.pdf(b)) / Z              # truncated-normal mean
    var = sd ** 2 * (1 + (a * norm.pdf(a) - b * norm.pdf(b)) / Z
                     - ((norm.pdf(a) - norm.pdf(b)) / Z) ** 2)
    s = stats["y"]
    assert abs(s["mean"] - mean) < 4 * math.sqrt(var / 20000)
    assert s["std"] == pytest.approx(math.sqrt(var), rel=0.03)
    x = table.column("x")
    assert x.min() >= lo and x.max() <= hi
    zz = np.log(table.column("z"))
    assert np.median(zz) == pytest.approx(math.log(2.0), abs=0.02)
    assert np.std(zz) == pytest.approx(0.3, rel=0.03)


def test_uncertainty_on_a_scene_gives_an_envelope(scene, tmp_path):
    from flexarm_ros.ensemble.plots import plot_envelope, plot_histograms
    from flexarm_ros.ensemble.spec import Spec, Unknown
    from flexarm_ros.ensemble.uq import run_uncertainty
    spec = Spec(scene="x", unknowns=[Unknown("m", ("links[0].tip.mass",), "uniform",
                                             {"low": 0.2, "high": 0.4})],
                metrics=["max_tip_deflection"], duration=DURATION)
    model = SceneModel(scene, resolve_metrics(spec.metrics, scene), DURATION, ("tip_y",))
    table, stats, env = run_uncertainty(spec, 6, seed=0, model=model, workers=0,
                                        channel="tip_y")
    t, med, p5, p95 = env
    ys = np.vstack([s["tip_y"] for s in table.series])
    assert np.all(p5 <= med) and np.all(med <= p95)
    assert np.all(p5 >= ys.min(axis=0) - 1e-15) and np.all(p95 <= ys.max(axis=0) + 1e-15)
    assert stats["max_tip_deflection_m"]["n"] == 6
    assert plot_envelope(t, med, p5, p95, "tip_y", tmp_path).stat().st_size > 0
    assert plot_histograms(table, stats, tmp_path).stat().st_size > 0


# -------------------------------------------------------------------------- the CLI
def _cli(argv, capsys):
    from flexarm_ros.cli import main
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_sweep_command_writes_table_series_and_figures(tmp_path, capsys):
    p = tmp_path / "scene.yaml"
    import yaml
    p.write_text(yaml.safe_dump(small_data()))
    out = tmp_path / "t.csv"
    code, stdout, err = _cli(["sweep", str(p), "--param", "links[0].tip.mass=0.2:0.4",
                              "--param", "links[0].beam.EI=2,3", "--samples", "2",
                              "--duration", str(DURATION), "--workers", "0", "--quiet",
                              "--out", str(out), "--series", "tip_x,tip_y", "--png",
                              str(tmp_path / "png"), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(stdout)
    assert doc["counts"]["ok"] == 4 and len(doc["rows"]) == 4
    rows = read_table(out)
    assert [r["max_tip_deflection_m"] for r in rows] == \
        [r["max_tip_deflection_m"] for r in doc["rows"]]
    assert sorted(x.name for x in (tmp_path / "t.samples").iterdir()) == [
        f"sample_{k:05d}.csv" for k in range(4)]
    assert (tmp_path / "png" / "max_tip_deflection_m_map.png").stat().st_size > 0
    meta = json.loads((tmp_path / "t.csv.meta.json").read_text())
    assert meta["design"] == "grid" and meta["scene"] == "ensemble_probe"


@pytest.mark.parametrize("argv, pattern", [
    (["sweep", "--param", "links[0].joint.drive.resistnce=1:2"],
     r"links\[0\]\.joint\.drive\.resistnce: unknown key"),
    (["sweep", "--param", "links[0].joint.drive.resistance=2:1"],
     r"got LO = 2 > HI = 1, expected LO <= HI"),
    (["sweep", "--param", "links[0].joint.drive.resistance=1:2", "--metric",
      "frequency:acc_Z"], r"channel 'acc_Z' not in the run"),
    (["sweep", "--param", "links[0].joint.drive.resistance=1:2", "--design", "sobol",
      "--samples", "10"], r"expected a power of two"),
])
def test_sweep_bad_input_exits_2(argv, pattern, capsys):
    code, _, err = _cli(argv + ["--workers", "0", "--quiet"], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert __import__("re").search(pattern, err), err


@pytest.mark.heavy
def test_unreachable_scheduler_exits_2(capsys):
    pytest.importorskip("distributed")
    addr = f"tcp://127.0.0.1:{_free_port()}"           # nothing listens there
    code, _, err = _cli(["sweep", "link", "--param", "links[0].beam.EI=1:2",
                         "--duration", "0.01", "--scheduler", addr, "--timeout", "1",
                         "--quiet"], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert f"--scheduler: got '{addr}', no Dask scheduler answered within 1 s" in err
    assert "dask scheduler" in err


def test_distribution_leaving_the_schema_bounds_exits_2(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text("scene: two_link_case1\nunknowns:\n"
                    "  - key: links[0].joint.drive.resistance\n"
                    "    dist: normal\n    mean: 1.085\n    std: 0.2\n")
    code, _, err = _cli(["uncertainty", str(spec), "--workers", "0", "--quiet"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "links[0].joint.drive.resistance" in err
    assert "expected a distribution inside the schema's bounds > 0 (Ω)" in err
    spec.write_text("scene: two_link_case1\nunknowns:\n"
                    "  - key: links[0].joint.drive.resistance\n"
                    "    dist: uniform\n    low: 1.2\n    high: 1.0\n")
    code, _, err = _cli(["sensitivity", str(spec), "--workers", "0", "--quiet"], capsys)
    assert code == 2 and "low = 1.2 >= high = 1, expected low < high" in err


# ------------------------------------------------------------- the study on the runner
@pytest.mark.heavy
@pytest.mark.subprocess
def test_study_rows_are_runner_tasks_with_the_same_results_on_dask():
    """flexarm study's ladder rows as tasks: on a Dask worker they give the serial rows'
    errors, frequencies and step counts to the bit (only the timing columns differ)."""
    pytest.importorskip("distributed")
    from flexarm_ros.ensemble.runner import open_executor
    from flexarm_ros.studies import ladder as study
    sc = load_scene_dict(small_data())
    ladder = [study.spec("rigid", 1, "rk4"), study.spec("fem", 2, "rk4")]
    kw = dict(duration=0.02, ladder=ladder, reference=study.spec("fem", 4, "rk4"))
    lines = []
    serial = study.run_study(sc, progress=lines.append, **kw)
    with open_executor(1) as ex:
        dask_rows = study.run_study(sc, executor=ex, **kw)
    timing = {"wall_s_per_sim_s", "real_time_factor", "timing_runs", "pareto"}
    for a, b in zip(serial, dask_rows):
        assert a["status"] == b["status"] == "ok"
        assert {k: repr(v) for k, v in a.items() if k not in timing} == \
            {k: repr(v) for k, v in b.items() if k not in timing}
    assert sum(line.startswith("[") for line in lines) == len(ladder)   # one per row


@pytest.mark.subprocess
def test_contact_study_rows_are_runner_tasks_with_the_same_results_on_dask():
    """The contact trade's rows (flexarm study on a scene with a wall) as tasks: on a Dask
    worker the same rows as in this process (timing columns aside) — to round-off: after
    the rest of the suite this process's rows have differed from a fresh worker's in the
    12th digit (7e-12 relative on a tip error; the reference stepper's numpy/LAPACK
    solves), never otherwise."""
    pytest.importorskip("distributed")
    from flexarm_ros.ensemble.runner import open_executor
    from flexarm_ros.scene import load_scene
    from flexarm_ros.studies.contact import run_contact_study
    sc = load_scene("two_link_case1")
    lines = []
    serial = run_contact_study(sc, 0.05, quick=True, progress=lines.append)
    with open_executor(1) as ex:
        dask_rows = run_contact_study(sc, 0.05, quick=True, executor=ex)
    assert [r["contact"] for r in serial] == ["impulse", "compliant", "compliant"]
    for a, b in zip(serial, dask_rows, strict=True):
        assert a["status"] == b["status"] == "ok"
        assert a.keys() == b.keys()
        for k in a:
            if k == "wall_s_per_sim_s":
                continue
            if isinstance(a[k], float) and isinstance(b[k], float):
                assert a[k] == pytest.approx(b[k], rel=1e-9, abs=1e-300, nan_ok=True), \
                    (k, a[k], b[k])
            else:
                assert repr(a[k]) == repr(b[k]), k
    assert len(lines) == 1 + len(serial)        # the reference, then one line per row


@pytest.mark.heavy
def test_uncertainty_and_sensitivity_commands_on_a_scene_file(tmp_path, capsys):
    import yaml
    (tmp_path / "probe.yaml").write_text(yaml.safe_dump(small_data()))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({
        "scene": "probe.yaml", "duration": DURATION, "channel": "tip_y",
        "metrics": ["max_tip_deflection"],
        "unknowns": [{"name": "tip_mass", "key": "links[0].tip.mass", "dist": "uniform",
                      "low": 0.2, "high": 0.4},
                     {"name": "EI", "key": "links[0].beam.EI", "dist": "lognormal",
                      "median": 2.0, "sigma": 0.1, "low": 1.5, "high": 2.5}]}))
    code, out, err = _cli(["uncertainty", str(spec), "--samples", "4", "--workers", "0",
                           "--quiet", "--json", "--png", str(tmp_path / "u"), "--out",
                           str(tmp_path / "u.csv")], capsys)
    assert code == 0, err
    s = json.loads(out)["statistics"]["max_tip_deflection_m"]
    vals = [r["max_tip_deflection_m"] for r in read_table(tmp_path / "u.csv")]
    assert s["n"] == 4 and s["p50"] == pytest.approx(np.median(vals), rel=1e-15)
    assert (tmp_path / "u" / "envelope_tip_y.png").is_file()
    env = (tmp_path / "u.envelope_tip_y.csv").read_text().splitlines()
    assert env[0] == "t [s],tip_y_p5 [m],tip_y_p50 [m],tip_y_p95 [m]"
    assert not (tmp_path / "u.samples").exists()        # no per-sample files unasked
    rows = read_table(tmp_path / "u.csv")               # columns named by the unknowns
    assert all(0.2 <= r["tip_mass"] <= 0.4 and 1.5 <= r["EI"] <= 2.5 for r in rows)
    code, out, err = _cli(["sensitivity", str(spec), "--method", "morris", "--samples", "2",
                           "--workers", "0", "--quiet", "--markdown",
                           str(tmp_path / "s.md"), "--png", str(tmp_path / "s")], capsys)
    assert code == 0, err
    assert "max_tip_deflection_m: morris over 6 samples" in out
    assert (tmp_path / "s" / "sensitivity_morris.png").is_file()
    assert "| rank | unknown | mu*" in (tmp_path / "s.md").read_text()


def test_the_case1_spec_example_loads_and_maps_quantiles_to_its_bounds():
    from pathlib import Path
    from flexarm_ros.ensemble.spec import load_spec
    spec = load_spec(Path(__file__).resolve().parents[1] / "examples" /
                     "sensitivity_case1.yaml")
    base = spec.base_scene()
    assert base.links[0].joint.backlash.width == 0.0                 # `set:` applied
    lo, hi = spec.assignments(np.array([[0.0] * len(spec.unknowns),
                                        [1.0] * len(spec.unknowns)]))
    for u in spec.unknowns:
        for k in u.keys:                                             # tied keys, one value
            assert lo[k] == pytest.approx(u.low) and hi[k] == pytest.approx(u.high)
    K.set_keys(base, lo)                                             # both ends valid
    K.set_keys(base, hi)
