"""Control metrics in ``flexarm compare`` (flexarm_ros.analysis.control, the control block of
flexarm_ros.analysis.compare).

Truths: the closed forms of textbook step responses — a first-order lag y = 1 - exp(-t/τ)
rises (10-90 %) in τ ln 9, settles (2 %) in τ ln 50 and does not overshoot; a second-order
response with damping ζ overshoots by exp(-πζ/sqrt(1-ζ²)), its 10/90 % instants are the
roots of the analytic response (scipy brentq) and its last exit from the 2 % band lies
within half a damped period before the envelope exp(-ζω_n t)/sqrt(1-ζ²) enters it; a
first-order lag behind a ramp of length R settles at τ ln(50 (τ/R)(e^(R/τ) - 1)).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from flexarm_ros.analysis import compare as C
from flexarm_ros.analysis.channels import load_channels
from flexarm_ros.analysis.comparison import (CONTROL_CRITERIA, CONTROL_KEYS,
                                             CONTROL_SIDE_KEYS, TOP_KEYS)
from flexarm_ros.analysis.control import METRIC_KEYS, tracking_metrics
from flexarm_ros.bag import BagWriter, messages
from flexarm_ros.cli import main
from flexarm_ros.io.experiment import write_experiment_csv
from flexarm_ros.scene import load_scene, resolve_scene_path

DT = 1e-4
T0 = 0.1                                   # the step is applied here
T = np.round(np.arange(0.0, 1.5 + DT / 2, DT), 12)
S = np.maximum(T - T0, 0.0)                # time since the step


def first_order(tau):
    return np.where(T >= T0, 1.0 - np.exp(-S / tau), 0.0)


def second_order(zeta, wn, t=None):
    s = S if t is None else t
    wd = wn * math.sqrt(1 - zeta ** 2)
    y = 1 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(1 - zeta ** 2)
                                       * np.sin(wd * s))
    return y if t is not None else np.where(T >= T0, y, 0.0)


STEP = np.where(T >= T0, 1.0, 0.0)


# ------------------------------------------------------------------ metrics, closed forms

@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_first_order_step(sign):
    tau = 0.05
    r = tracking_metrics(T, sign * first_order(tau), T, sign * STEP)
    m, cmd = r["metrics"], r["command"]
    assert (cmd.kind, cmd.onset_s, cmd.step) == ("step", pytest.approx(T0), sign * 1.0)
    assert m["rise_time_s"] == pytest.approx(tau * math.log(9), abs=1e-6)
    assert m["settling_time_s"] == pytest.approx(tau * math.log(50), abs=1e-6)
    assert m["overshoot"] == 0.0
    assert m["final_error"] == pytest.approx(math.exp(-(T[-1] - T0) / tau), rel=1e-9)
    # RMS of e = -exp(-s/τ) after the step over the record: sqrt(τ/2 / T) to O(dt/τ)
    assert m["rms_tracking_error"] == pytest.approx(math.sqrt(tau / 2 / T[-1]), rel=5e-3)


def test_second_order_step():
    zeta, wn = 0.3, 20.0
    wd = wn * math.sqrt(1 - zeta ** 2)
    m = tracking_metrics(T, second_order(zeta, wn), T, STEP)["metrics"]
    assert m["overshoot"] == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)),
                                           abs=1e-6)
    def f(level):
        return brentq(lambda s: second_order(zeta, wn, np.array([s]))[0] - level, 0.0,
                      math.pi / wd)
    assert m["rise_time_s"] == pytest.approx(f(0.9) - f(0.1), abs=1e-6)
    t_env = math.log(1 / (0.02 * math.sqrt(1 - zeta ** 2))) / (zeta * wn)
    assert t_env - math.pi / wd <= m["settling_time_s"] <= t_env


def test_ramp_target():
    """A first-order lag behind a ramp from 0 to 1 over R = 0.2 s, then held."""
    tau, R = 0.03, 0.2
    target = np.clip(S / R, 0.0, 1.0)
    y = np.where(S <= R, (S - tau * (1 - np.exp(-S / tau))) / R,
                 1 - tau / R * (math.exp(R / tau) - 1) * np.exp(-S / tau))
    r = tracking_metrics(T, y, T, target)
    cmd, m = r["command"], r["metrics"]
    assert cmd.kind == "ramp" and cmd.onset_s == pytest.approx(T0)
    assert cmd.hold_s == pytest.approx(T0 + R)
    assert m["overshoot"] == 0.0
    assert m["settling_time_s"] == pytest.approx(
        tau * math.log(50 * tau / R * (math.exp(R / tau) - 1)), abs=1e-6)
    # a ramp still moving at the end: final and RMS errors only, the reason stated
    r = tracking_metrics(T, S, T, S)
    assert r["command"].hold_s is None and r["metrics"]["final_error"] == 0.0
    assert r["metrics"]["settling_time_s"] is None and "still moves" in r["why"]["overshoot"]


def test_no_step_and_setpoint_from_the_start():
    """A constant target equal to the output's first value: no step (only the final and
    RMS errors); a constant target away from it: a step at the record's start (the
    twin's position controller commands its setpoint from t = 0)."""
    wobble = 1e-3 * np.sin(2 * np.pi * 3 * T)
    r = tracking_metrics(T, wobble, T, np.zeros_like(T))
    assert r["command"].kind == "none"
    assert r["metrics"]["rms_tracking_error"] == pytest.approx(1e-3 / math.sqrt(2), rel=1e-3)
    for k in ("overshoot", "rise_time_s", "settling_time_s"):
        assert r["metrics"][k] is None and "constant" in r["why"][k]
    tau = 0.05
    r = tracking_metrics(T, 1 - np.exp(-T / tau), T, np.ones_like(T))
    assert (r["command"].kind, r["command"].onset_s) == ("step", 0.0)
    assert r["metrics"]["settling_time_s"] == pytest.approx(tau * math.log(50), abs=1e-6)
    # a span (--window) that starts after the setpoint was given holds only the tail
    late = T >= 0.5
    r = tracking_metrics(T[late], 1 - np.exp(-T[late] / tau), T, np.ones_like(T))
    assert r["command"].kind == "none" and "before the analysed span" in r["why"]["overshoot"]


# ------------------------------------------------------------------ compare on control runs

def _table(path, y1, y2, tip=None):
    """A control run's table: link1 steps (target column), link2 holds (target = its start)."""
    cols = {"link1_joint": ("rad", T, y1), "link1_joint_target": ("rad", T, STEP),
            "link2_joint": ("rad", T, y2), "link2_joint_target": ("rad", T, np.zeros_like(T))}
    if tip is not None:
        cols["tip_x"] = ("m", T, tip)
        cols["tip_target_x"] = ("m", T, 0.5 * STEP)
    write_experiment_csv(path, cols)
    return path


def _cmp(capsys, run, ref, *extra):
    code = main(["compare", str(run), str(ref), "--offset", "none", "--json", *extra])
    return code, json.loads(capsys.readouterr().out)


def test_control_run_passes_within_the_tolerances(tmp_path, capsys):
    """τ 4 % slower, the held joint wobbling alike: rise and settling times 4 % apart,
    inside ±10 %; link2 has no step, so it keeps the oscillation criteria."""
    wob = 1e-3 * np.sin(2 * np.pi * 7 * T)
    ref = _table(tmp_path / "ref.csv", first_order(0.050), wob, 0.5 * first_order(0.05))
    run = _table(tmp_path / "run.csv", first_order(0.052), wob, 0.5 * first_order(0.052))
    code, r = _cmp(capsys, run, ref)
    assert code == 0 and r["pass"] and r["failed"] == []
    b = r["channels"]["link1_joint"]
    assert b["judged_by"] == "control" and sorted(b["criteria"]) == sorted(CONTROL_CRITERIA)
    c = b["control"]
    assert c["difference"]["rise_time_s"] == pytest.approx(0.002 * math.log(9), abs=1e-5)
    assert c["tolerance"]["rise_time_s"] == pytest.approx(0.1 * 0.05 * math.log(9), abs=1e-5)
    assert c["tolerance"]["final_error"] == pytest.approx(0.02)       # 2 % of a 1 rad step
    h = r["channels"]["link2_joint"]
    assert h["judged_by"] == "oscillation" and "amplitude_error" in h["criteria"]
    assert h["control"]["reference"]["command"]["kind"] == "none"
    assert h["control"]["reference"]["overshoot"] is None
    assert "constant" in h["control"]["null_reasons"]["reference.overshoot"]
    # the tip tracks tip_target_x: control criteria, its FFT frequency reported, not judged
    tip = r["channels"]["tip_x"]
    assert tip["judged_by"] == "control" and "frequency_error" not in tip["criteria"]
    assert tip["control"]["target_channel"]["reference"] == "tip_target_x"


@pytest.mark.heavy
def test_control_run_fails_a_slow_overshooting_or_reversed_response(tmp_path, capsys):
    hold = np.zeros_like(T)
    ref = _table(tmp_path / "ref.csv", first_order(0.05), hold)
    slow = _table(tmp_path / "slow.csv", first_order(0.06), hold)
    code, r = _cmp(capsys, slow, ref)
    assert code == 1
    # 20 % slower: rise and settling times fail; the RMS tracking errors, sqrt(τ/2T),
    # differ by sqrt(1.2) - 1 = 9.5 %, inside ±10 %
    assert r["failed"] == ["link1_joint:rise_time", "link1_joint:settling_time"]
    assert r["channels"]["link1_joint"]["criteria"]["rms_tracking_error"] is True
    osc_ref = _table(tmp_path / "osc_ref.csv", second_order(0.4, 20.0), hold)
    osc_run = _table(tmp_path / "osc_run.csv", second_order(0.3, 20.0), hold)
    code, r = _cmp(capsys, osc_run, osc_ref)
    c = r["channels"]["link1_joint"]["control"]
    assert code == 1 and "link1_joint:overshoot" in r["failed"]
    assert c["difference"]["overshoot"] == pytest.approx(
        math.exp(-0.3 * math.pi / math.sqrt(0.91)) - math.exp(-0.4 * math.pi / math.sqrt(0.84)),
        abs=1e-5)
    # the case: the run goes the opposite way; the amplitudes (peak-to-peak) agree
    code, r = _cmp(capsys, _table(tmp_path / "rev.csv", -first_order(0.05), hold), ref)
    assert code == 1 and r["channels"]["link1_joint"]["amplitude_error"] == pytest.approx(0)
    assert {"link1_joint:final_error", "link1_joint:rise_time"} <= set(r["failed"])


@pytest.mark.heavy
def test_json_keys_of_the_control_block(tmp_path, capsys):
    ref = _table(tmp_path / "ref.csv", first_order(0.05), np.zeros_like(T))
    code, r = _cmp(capsys, ref, ref)
    assert code == 0 and r["schema"] == "flexarm-compare/2" and sorted(r) == sorted(TOP_KEYS)
    assert r["control_method"]["settling_band"] == 0.02
    assert r["control_method"]["rise"] == [0.1, 0.9]
    for name in ("link1_joint", "link2_joint"):
        c = r["channels"][name]["control"]
        assert sorted(c) == sorted(CONTROL_KEYS)
        for side in ("run", "reference"):
            assert sorted(c[side]) == sorted(CONTROL_SIDE_KEYS)
            assert sorted(c[side]["command"]) == ["final_target", "hold_s", "initial", "kind",
                                                   "onset_s", "step"]
        assert sorted(c["difference"]) == sorted(c["tolerance"]) == sorted(METRIC_KEYS)
        for block in ("run", "reference", "difference"):
            for k in METRIC_KEYS:
                if c[block][k] is None:
                    assert isinstance(c["null_reasons"][f"{block}.{k}"], str)
    assert r["channels"]["link1_joint_target"]["control"] is None     # a target has none
    c = r["channels"]["link1_joint"]["control"]
    assert all(v == 0.0 for v in c["difference"].values())
    rep = tmp_path / "rep"
    assert main(["compare", str(ref), str(ref), "--offset", "none", "--report",
                 str(rep)]) == 0
    text = (rep / "report.md").read_text()
    assert "## Control (channels that track a command)" in text and "settling time" in text


# ------------------------------------------------------------------ targets from a twin bag

def test_joint_targets_topic_gives_target_channels(tmp_path):
    """controller/joint_targets (JointState, names <link>_joint) -> <link>_joint_target,
    the target of <link>_joint and <link>_joint_measured; one encoder count of the scene
    (500 lines × 4 × 156 on the motor shaft) is the final-error floor."""
    scene = "two_link_position"
    path = tmp_path / "ctl.mcap"
    names = ["link1_joint", "link2_joint"]
    goal = np.array([0.7, 0.4])
    ticks = np.arange(301)
    with BagWriter(path, metadata={"scene": scene, "namespace": "/flexarm",
                                   "scene_yaml": resolve_scene_path(scene).read_text()}) as w:
        for k in ticks:
            t_ns = int(k) * 1_000_000
            q = goal * (1 - math.exp(-k / 40.0))
            w.write("/flexarm/joint_states", "sensor_msgs/msg/JointState",
                    messages.joint_state(t_ns, names, q), t_ns)
            w.write("/flexarm/controller/joint_targets", "sensor_msgs/msg/JointState",
                    messages.joint_state(t_ns, names, goal), t_ns)
    cs = load_channels(path)
    tgt = cs["link1_joint_target"]
    assert tgt.unit == "rad" and np.array_equal(tgt.y, np.full(301, 0.7))
    assert np.array_equal(tgt.t, ticks * 1_000_000 * 1e-9)       # the log times
    r = C.compare(cs, cs, offset="none").result
    b = r["channels"]["link1_joint_measured"]
    assert b["judged_by"] == "control" and b["pass"] is True
    assert b["control"]["target_channel"] == {"run": "link1_joint_target",
                                              "reference": "link1_joint_target"}
    assert b["control"]["reference"]["command"]["kind"] == "step"      # setpoint from t = 0
    sc = load_scene(scene)
    q = 2 * math.pi / (500 * 4 * sc.links[0].joint.drive.gear_ratio)
    assert b["control"]["quantum"] == pytest.approx(q, rel=1e-12)
    assert b["control"]["tolerance"]["final_error"] == pytest.approx(max(0.02 * 0.7, q))
