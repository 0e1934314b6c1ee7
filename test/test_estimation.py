"""The twin follows the rig: the Kalman filter's exact sampling against a numerical
integral, and ``flexarm estimate`` on a twin bag whose scene is offset from the
estimator's (tip mass +10 %), scored against the bag's ground truth (which the filter
never reads), from the CLI and from Python; the refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from flexarm_ros.cli import main
from flexarm_ros.estimation.kalman import ModelFilter
from flexarm_ros.scene import load_scene


def test_the_sampled_noise_is_van_loans_integral():
    """Q_Δ = ∫₀^Δ e^{As} W e^{Aᵀs} ds by the filter's matrix exponential against Simpson's
    rule on 2001 points, and Φ = e^{AΔ} against the series' semigroup Φ(Δ/2)²."""
    f = ModelFilter(load_scene("two_link_case1"))
    from scipy.integrate import simpson
    from scipy.linalg import expm
    Phi, Gam, Q = f._discrete(250_000)
    s = np.linspace(0, 250e-6, 2001)
    vals = np.array([expm(f.A * si) @ f.W @ expm(f.A.T * si) for si in s])
    Qn = simpson(vals, x=s, axis=0)
    assert np.allclose(Q, Qn, rtol=1e-6, atol=1e-9 * np.max(np.abs(Qn)))
    half = f._discrete(125_000)[0]
    assert np.allclose(Phi, half @ half, rtol=1e-10, atol=1e-12)


@pytest.fixture(scope="module")
def case1_bag(tmp_path_factory):
    """A 1.2 s lockstep twin bag of two_link_case1 (before the wall), ground truth in."""
    from flexarm_ros.run import run
    path = tmp_path_factory.mktemp("est") / "case1.mcap"
    run("two_link_case1", 1.2, "lockstep", record=path, namespace="/est", progress=False)
    return path


@pytest.mark.ros
@pytest.mark.subprocess
def test_encoders_and_accelerometers_follow_a_rig_whose_tip_is_heavier(case1_bag, tmp_path,
                                                                       capsys):
    """The estimator's tip mass 10 % above the rig's: tip-deflection RMSE ≤ 3 % and the
    largest error ≤ 10 % of each link's peak over the run (the targets measured here:
    1.4 % / 2.3 % and 2.4 % / 9.4 % on 1.5 s); encoders alone are reported, finite."""
    out = tmp_path / "est.csv"
    assert main(["estimate", str(case1_bag), "--scene", "two_link_case1", "--set",
                 "links[1].tip.mass=2.574", "--out", str(out), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    for name, s in rep["score"]["links"].items():
        assert s["peak_m"] > 5e-3, name
        assert s["rmse_of_peak"] <= 0.03 and s["max_error_of_peak"] <= 0.10, (name, s)
    head = out.read_text().splitlines()[0]
    assert head == ("t [s],link1_tip_deflection [m],link2_tip_deflection [m],tip_x [m],"
                    "tip_y [m],nis [1],event")
    assert main(["estimate", str(case1_bag), "--sensors", "encoders", "--out",
                 str(tmp_path / "enc.csv"), "--json"]) == 0
    enc = json.loads(capsys.readouterr().out)["score"]
    assert all(np.isfinite(s["rmse_m"]) for s in enc["links"].values())


@pytest.mark.ros
@pytest.mark.subprocess
def test_the_python_api_gives_the_clis_estimate(case1_bag, tmp_path):
    import flexarm_ros as fx
    est = fx.estimate(case1_bag)
    assert main(["estimate", str(case1_bag), "--out", str(tmp_path / "e.csv")]) == 0
    from flexarm_ros.io.tables import read_table
    cli = read_table(tmp_path / "e.csv")
    assert np.allclose(cli["link2_tip_deflection"], est.columns["link2_tip_deflection"],
                       rtol=1e-9, atol=1e-15)
    assert est.score["links"]["link2"]["rmse_of_peak"] < 0.03


@pytest.mark.parametrize("argv,says", [
    (["missing.mcap", "--out", "x.csv"], "BAG: got 'missing.mcap', expected an existing"),
    (["bags/golden_case1.mcap", "--out", "x.txt"], "--out"),
    (["bags/golden_case1.mcap", "--process-noise", "-1", "--out", "x.csv"],
     "--process-noise: got -1"),
    (["bags/golden_case1.mcap", "--set", "duration=1", "--out", "x.csv"],
     "--set: got values without --scene"),
])
def test_estimate_refusals_are_one_line_exit_2(tmp_path, monkeypatch, capsys, argv, says):
    import os
    root = os.getcwd()
    argv = [a if not a.startswith("bags/") else os.path.join(root, a) for a in argv]
    monkeypatch.chdir(tmp_path)
    rc = main(["estimate", *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and says in err and len(err.splitlines()) == 1, err


@pytest.mark.ros
@pytest.mark.subprocess
def test_settled_gains_are_the_time_varying_filters(case1_bag, monkeypatch):
    """Encoders alone: the filter that reuses its gains once P has settled gives the
    estimate of the filter that propagates P at every measurement, to round-off."""
    from flexarm_ros.estimation import kalman
    from flexarm_ros.estimation.from_bag import estimate_bag
    fast = estimate_bag(case1_bag, sensors="encoders")
    monkeypatch.setattr(kalman, "SETTLED", -1.0)           # never settles
    full = estimate_bag(case1_bag, sensors="encoders")
    for k in ("link1_tip_deflection", "link2_tip_deflection", "tip_x"):
        assert np.allclose(fast.columns[k], full.columns[k], rtol=0, atol=1e-9), k


@pytest.mark.ros
@pytest.mark.subprocess
def test_the_estimator_node_beside_a_lockstep_run_is_the_bag_estimate(tmp_path):
    """The estimator node started beside a lockstep twin of two_link_case1 (0.6 s) reads
    only the bench topics; from the first tick it received, its published tip deflections
    are those of the same filter fed the run's bag from that tick, to 1e-12 m."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.estimation.from_bag import Follower, _events
    from flexarm_ros.nodes.common import QOS
    from flexarm_ros.nodes.estimator import EstimatorNode
    from flexarm_ros.run import InProcessGraph
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.recording import embedded_scene
    path = tmp_path / "live.mcap"
    g = InProcessGraph(namespace="/es", scene="two_link_case1", mode="lockstep",
                       duration=0.6, record=path)
    got = []
    try:
        est = EstimatorNode(context=g.context, namespace="/es", parameter_overrides=[
            Parameter("scene", value="two_link_case1"), Parameter("mode", value="lockstep"),
            Parameter("duration", value=0.6)])
        g.executor.add_node(est)
        g.nodes["estimator"] = est
        user = Node("listener", namespace="/es", context=g.context)
        g.executor.add_node(user)
        g.nodes["listener"] = user
        user.create_subscription(Float64MultiArray, T.EST_DEFLECTIONS,
                                 lambda m: got.append(list(m.data)), QOS)
        sim = g["simulator"]
        assert g.spin_until(lambda: sim.finished, 300)
        sim.halt()
        assert g.spin_until(g.recorded_all, 60)
        assert g.spin_until(lambda: len(got) >= est.ticks_published, 30)
    finally:
        g.close()
    assert est.ticks_published >= 500
    bag = read_bag(path)
    scene = embedded_scene(bag)
    events, _ = _events(bag, scene, "/es")
    start = est.first_ns                  # the node's first tick
    fol = Follower(scene)
    rows = []
    for t, _, kind, payload in events:
        if t >= start:
            r = fol.feed(t, kind, payload)
            if r is not None:
                rows.append(fol.filter.chain.tip_deflections(r[1]))
    assert len(got) == est.ticks_published and len(rows) >= len(got)
    assert np.allclose(np.array(got), np.array(rows[:len(got)]), rtol=0, atol=1e-12)


def test_a_bag_through_the_wall_strike_says_where_the_estimate_leaves_its_ground():
    """The shipped golden bag (two_link_case1, 2.5 s, the strike at 2.1 s): the estimate
    runs, and a note names the first contact, after which the filter (no contact in its
    model) is off by far more than before it."""
    from pathlib import Path
    from flexarm_ros.estimation.from_bag import estimate_bag
    bag = Path(__file__).resolve().parents[1] / "bags" / "golden_case1.mcap"
    est = estimate_bag(bag)
    note = [n for n in est.notes if "touches the wall from 2.099 s" in n]
    assert note and "does not model contact" in note[0]
    assert est.score["links"]["link2"]["max_error_of_peak"] > 1.0


def test_a_measurement_set_the_filter_does_not_read_is_refused_before_the_bag_is_read():
    import flexarm_ros as fx
    from flexarm_ros.errors import InputError
    with pytest.raises(InputError, match="--sensors: got 'strain', expected all or encoders"):
        fx.estimate("no-such.mcap", sensors="strain")
