"""``flexarm bag export`` (flexarm_ros.analysis.export): a twin bag as ``name [unit]`` CSV
tables.

Truths: the bag's own messages (read with the bag reader, field by field) against the CSV
read back with the experiment reader; resampling worked out by hand on a bag written here
(a tip at half the tick rate interpolated linearly, a contact flag held); ``flexarm
compare`` of the bag against its export finds every error exactly 0.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from flexarm_ros.bag import BagWriter, iter_messages, messages, read_bag, to_dict
from flexarm_ros.cli import main
from flexarm_ros.commands.simulate import sensor_table_path as cli_sensor_table_path
from flexarm_ros.io.experiment import read_experiment_csv
from flexarm_ros.io.tables import sensor_table_path
from flexarm_ros.scene import resolve_scene_path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "bags" / "golden_case1.mcap"
NS = "/flexarm"


def _meta(scene="two_link_case1"):
    return {"scene": scene, "namespace": NS,
            "scene_yaml": resolve_scene_path(scene).read_text()}


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory):
    """The golden bag's first 0.1 s (every topic, the project's bag writer) plus the
    controller's joint targets (a step of link1 at 50 ms)."""
    path = tmp_path_factory.mktemp("export") / "short.mcap"
    names = ["link1_joint", "link2_joint"]
    with BagWriter(path, metadata=_meta()) as w:
        for m in iter_messages(GOLDEN):
            if m.log_time_ns > 110_000_000:     # well past 0.1 s in file order
                break
            if m.log_time_ns > 100_000_000:
                continue
            w.write(m.topic, m.msgtype, to_dict(m.message), m.log_time_ns)
            if m.topic == f"{NS}/joint_states":
                q = [1.0 if m.log_time_ns >= 50_000_000 else 0.96, 0.0]
                w.write(f"{NS}/controller/joint_targets", "sensor_msgs/msg/JointState",
                        messages.joint_state(m.log_time_ns, names, q), m.log_time_ns)
    return path


def _export(capsys, *args):
    code = main(["bag", "export", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_export_equals_the_bag_messages(short_bag, tmp_path, capsys):
    out = tmp_path / "run.csv"
    code, text, _ = _export(capsys, short_bag, "--out", out, "--json")
    rep = json.loads(text)
    assert code == 0 and rep["time_base"]["topic"] == f"{NS}/ground_truth/joint_states"
    cols, _ = read_experiment_csv(out)
    bag = read_bag(short_bag)

    def msgs(topic):
        return bag.messages[f"{NS}/{topic}"]
    ticks = np.array([t for t, _ in msgs("ground_truth/joint_states")]) * 1e-9
    assert rep["rows"] == ticks.size == 101
    for name, topic, get in (
            ("tip_x", "ground_truth/tip", lambda m: m.point.x),
            ("normal_force", "tool/wrench", lambda m: m.wrench.force.x),
            ("contact", "tool/contact", lambda m: float(m.data)),
            ("enc2", "encoders/counts", lambda m: m.data[1]),
            ("link1_command", "motor_driver/commands", lambda m: m.data[0]),
            ("link2_tip_disp", "ground_truth/coordinates",
             lambda m: m.position[list(m.name).index("link2_tip_disp")]),
            ("link1_joint_measured", "joint_states", lambda m: m.position[0]),
            ("link1_joint_target", "controller/joint_targets", lambda m: m.position[0])):
        unit, t, y = cols[name]
        assert np.array_equal(t, np.array([lt for lt, _ in msgs(topic)]) * 1e-9), name
        assert np.array_equal(y, np.array([get(m) for _, m in msgs(topic)], float)), name
        assert rep["columns"][name]["resampling"] == "exact"
    assert cols["link1_joint_target"][0] == "rad" and cols["tip_x"][0] == "m"
    # the accelerometer batches: one row per sample in the 4 kHz table, as laid out
    side = sensor_table_path(out, 4000)
    assert rep["sensor_tables"]["4000"]["path"] == str(side)
    acc, _ = read_experiment_csv(side)
    rows = np.concatenate([np.reshape(m.data, (-1, 4)) for _, m in
                           msgs("accelerometers/batch")])
    assert np.array_equal(acc["acc_C"][2], rows[:, 2]) and acc["acc_C"][0] == "V"
    assert np.array_equal(acc["acc_C"][1][:4], np.array([1, 2, 3, 4]) * 250_000 * 1e-9)


def test_compare_bag_with_its_export_passes(short_bag, tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert _export(capsys, short_bag, "--out", out)[0] == 0
    code = main(["compare", str(short_bag), str(out), "--offset", "none", "--json"])
    r = json.loads(capsys.readouterr().out)
    assert code == 0 and r["pass"] and r["failed"] == []
    assert {"acc_A", "link1_joint", "tip_x", "contact", "link1_joint_target",
            "wall_gap"} <= set(r["channels"])
    for b in r["channels"].values():
        assert b["rms_error"] == 0.0 and b["peak_error"] == 0.0
    assert r["channels"]["link1_joint"]["judged_by"] == "control"   # the step at 50 ms


def test_resampling_onto_the_ticks(tmp_path, capsys):
    """Ticks every ms (ground_truth/joint_states, 0..10 ms); the tip every 2 ms from 2 ms:
    linear in between, empty before its first sample; the contact flag every 3 ms: held
    (the last sample at or before each tick), empty after its last sample (9 ms)."""
    bag = tmp_path / "rates.mcap"
    with BagWriter(bag, metadata=_meta()) as w:
        for k in range(11):
            t = k * 1_000_000
            w.write(f"{NS}/ground_truth/joint_states", "sensor_msgs/msg/JointState",
                    messages.joint_state(t, ["link1_joint"], [0.001 * k]), t)
            if k % 2 == 0 and k >= 2:
                w.write(f"{NS}/ground_truth/tip", "geometry_msgs/msg/PointStamped",
                        messages.point_stamped(t, "world", [0.1 * k, 1.0, 0.0]), t)
            if k % 3 == 0:
                w.write(f"{NS}/tool/contact", "std_msgs/msg/Bool",
                        messages.boolean(k == 3), t)
    out = tmp_path / "rates.csv"
    (tmp_path / "rates.sensors_4000hz.csv").write_text("t [s],acc_A [V]\n0,1\n")
    code, text, err = _export(capsys, bag, "--out", out, "--json", "--topics",
                              "ground_truth/tip,tool/contact")
    rep = json.loads(text)
    assert code == 0 and set(rep["columns"]) == {"tip_x", "tip_y", "contact"}
    # a sensor table of an earlier run beside --out would be read with it: said, not removed
    assert "rates.sensors_4000hz.csv" in rep["warnings"][0] and "warning" in err
    assert rep["columns"]["tip_x"]["resampling"] == "linear"
    assert rep["columns"]["contact"]["resampling"] == "previous"
    cols, _ = read_experiment_csv(out)
    ticks = np.arange(11) * 1_000_000 * 1e-9
    _, t, x = cols["tip_x"]
    assert np.array_equal(t, ticks[2:])
    assert x == pytest.approx(0.1 * np.arange(2, 11), abs=1e-15)
    _, t, c = cols["contact"]
    assert np.array_equal(t, ticks[:10])
    assert np.array_equal(c, [0, 0, 0, 1, 1, 1, 0, 0, 0, 0])


def test_bad_input_exit_status_2(short_bag, tmp_path, capsys):
    out = tmp_path / "x.csv"
    notmcap = tmp_path / "notes.mcap"
    notmcap.write_text("hello")
    for args, words in (
            ((tmp_path / "missing.mcap", "--out", out), ("missing.mcap", "no such file",
                                                         "expected an MCAP bag")),
            ((notmcap, "--out", out), ("not an MCAP file", "expected the MCAP magic")),
            ((short_bag, "--out", tmp_path / "x.txt"), ("--out", "x.txt", "expected a .csv")),
            ((short_bag, "--out", out, "--topics", "nosuch/topic"),
             ("--topics", "nosuch/topic", "expected a topic of")),
            ((short_bag, "--out", out, "--topics", "/clock"),
             ("--topics", "/clock", "gives no channel"))):
        code, _, err = _export(capsys, *args)
        assert code == 2, args
        assert err.count("\n") == 1 and all(w in err for w in words), err
    assert not out.exists()


def test_sensor_table_names_agree_with_simulate():
    assert sensor_table_path("d/run.csv", 4000.0) == cli_sensor_table_path("d/run.csv", 4000.0)
    assert sensor_table_path("run.csv", 2500).name == "run.sensors_2500hz.csv"
