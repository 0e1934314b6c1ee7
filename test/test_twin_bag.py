"""flexarm_ros.twin.recording: the one reader of the twin's bag conventions, shared by
``flexarm compare`` (analysis) and the views (viz).

Truth: sample times and values worked out by hand from a batch's layout (std_msgs rule
``value[i, j] = data[data_offset + dim[1].stride * i + j]``; sample i of n logged at t_m
taken at ``t_m - (n - 1 - i) / rate_hz``), for batches with padded rows and a non-zero
data offset — the layout the two consumers once read differently.
"""

from __future__ import annotations

import numpy as np
import pytest

from flexarm_ros.analysis.channels import load_channels
from flexarm_ros.bag import BagError, BagWriter, read_bag
from flexarm_ros.twin import recording
from flexarm_ros.io.experiment import CompareInputError
from flexarm_ros.scene import resolve_scene_path
from flexarm_ros.twin import topics as T
from flexarm_ros.viz import BagView

SCENE = "two_link_case1"          # accelerometers acc_A..acc_D at 4 kHz
NS = "/arm_ns"
PAD = -999.0                      # the values the layout skips: never a sample


def _batch(rows: np.ndarray, stride: int, offset: int) -> dict:
    """A Float64MultiArray of ``rows`` (n, c) laid out with row stride ``stride`` >= c and
    ``offset`` leading values; every skipped slot holds PAD."""
    n, c = rows.shape
    data = np.full(offset + stride * n, PAD)
    for i in range(n):
        data[offset + stride * i: offset + stride * i + c] = rows[i]
    return {"layout": {"dim": [{"label": "sample", "size": n, "stride": stride * n},
                               {"label": "channel", "size": c, "stride": stride}],
                       "data_offset": offset},
            "data": data}


def _write(path, batches, scene_yaml=None):
    meta = {"scene": SCENE, "namespace": NS}
    if scene_yaml is not None:
        meta["scene_yaml"] = scene_yaml
    with BagWriter(path, metadata=meta) as w:
        for t_ns, msg in batches:
            w.write(f"{NS}/{T.ACCEL_BATCH}", T.TYPES[T.ACCEL_BATCH], msg, t_ns)
    return path


@pytest.fixture(scope="module")
def strided(tmp_path_factory):
    """Two batches of 3 samples x 4 channels, rows padded to 6 values, data offset 2
    (first batch) and 5 (second), logged at 0.75 ms and 1.5 ms."""
    rng = np.random.default_rng(7)
    rows = [rng.normal(size=(3, 4)), rng.normal(size=(3, 4))]
    path = tmp_path_factory.mktemp("twin_bag") / "strided.mcap"
    _write(path, [(750_000, _batch(rows[0], 6, 2)), (1_500_000, _batch(rows[1], 6, 5))],
           resolve_scene_path(SCENE).read_text())
    # by hand: 4 kHz -> 250 000 ns apart, the last sample of each batch at its log time
    t_ns = np.array([250_000, 500_000, 750_000, 1_000_000, 1_250_000, 1_500_000])
    return path, t_ns, np.vstack(rows)


def test_batch_with_stride_and_offset_against_hand_layout(strided):
    path, t_ns, values = strided
    sb = recording.sensor_batches(read_bag(path), T.ACCEL_BATCH,
                                  recording.embedded_scene(read_bag(path)))
    assert sb.topic == f"{NS}/{T.ACCEL_BATCH}" and sb.rate_hz == 4000.0
    assert sb.names == ["acc_A", "acc_B", "acc_C", "acc_D"] and sb.notes == []
    assert np.array_equal(sb.t_ns, t_ns)
    assert np.array_equal(sb.values, values) and not np.any(sb.values == PAD)


def test_analysis_and_viz_read_the_same_samples(strided):
    """compare's channels and the view's traces: the hand-computed times and values."""
    path, t_ns, values = strided
    cs = load_channels(path)
    traces = {tr.name: tr for tr in BagView(path).batch_series(T.ACCEL_BATCH)}
    for j, name in enumerate(["acc_A", "acc_B", "acc_C", "acc_D"]):
        ch = cs[name]
        assert ch.unit == "V" and ch.source.startswith(f"{NS}/{T.ACCEL_BATCH}")
        assert np.array_equal(ch.t, t_ns * 1e-9)
        assert np.array_equal(ch.y, values[:, j])
        assert np.array_equal(traces[name].t_ns, t_ns)
        assert np.array_equal(traces[name].values, values[:, j])


def test_metadata_readers(strided):
    bag = read_bag(strided[0])
    assert recording.twin_info(bag)["scene"] == SCENE
    assert recording.recorded_namespace(bag) == NS and recording.namespace(bag) == NS
    assert recording.namespace(bag, "/other") == "/other"
    assert recording.embedded_scene(bag).name == SCENE
    assert len(recording.twin_messages(bag, T.ACCEL_BATCH)) == 2


def test_without_scene_names_are_generic_and_rate_from_spacing(tmp_path):
    rows = np.arange(24.0).reshape(6, 4)
    path = _write(tmp_path / "noscene.mcap", [(750_000, _batch(rows[:3], 5, 1)),
                                              (1_500_000, _batch(rows[3:], 5, 1))])
    bag = read_bag(path)
    assert recording.embedded_scene(bag) is None and recording.namespace(bag) == NS
    sb = recording.sensor_batches(bag, T.ACCEL_BATCH, None)
    assert sb.rate_hz == pytest.approx(4000.0) and "estimated" in sb.notes[0]
    assert sb.names == [f"accelerometer_{j}" for j in range(4)]
    assert np.array_equal(sb.values, rows)
    cs = load_channels(path)
    assert np.array_equal(cs["accelerometer_2"].y, rows[:, 2])
    assert any("estimated from the message spacing" in w for w in cs.warnings)


def test_layout_past_the_data_is_named(tmp_path):
    msg = _batch(np.ones((3, 4)), 6, 2)
    msg["data"] = msg["data"][:-3]                   # the last row is cut short
    path = _write(tmp_path / "short.mcap", [(750_000, msg)],
                  resolve_scene_path(SCENE).read_text())
    with pytest.raises(BagError, match=r"3 samples x 4 channels \(stride 6, data_offset 2\)"):
        BagView(path).batch_series(T.ACCEL_BATCH)
    with pytest.raises(CompareInputError, match=f"{NS}/{T.ACCEL_BATCH} at 750000 ns"):
        load_channels(path)


def test_invalid_embedded_scene_is_a_bag_error(tmp_path):
    path = _write(tmp_path / "bad.mcap", [], "links: not-a-list\n")
    with pytest.raises(BagError, match="flexarm_ros.scene_yaml is not a valid scene"):
        recording.embedded_scene(read_bag(path))
