"""Options that a run used to accept without a word and now refuses in one line, exit 2:
a lawson4 step above the output period (it stepped at the period), ``--refine`` on a rung
with one shape per beam (ignored), a negative ``--shape-rate`` (read as "every message"),
a ``compare --window`` outside the reference's records (a table of dashes)."""

from __future__ import annotations

import pytest

from flexarm_ros.cli import main


@pytest.mark.parametrize("argv, says", [
    (["simulate", "link", "--dt", "1", "--duration", "0.1"],
     "fidelity.dt: got 1 s with the lawson4 integrator, expected at most the output period "
     "0.001 s"),
    (["simulate", "link", "--rung", "rigid", "--refine", "5", "--duration", "0.1"],
     "--refine: got 5 with the rigid rung, expected 0 or 1"),
    (["simulate", "two_link_free", "--rung", "cubic", "--refine", "3", "--duration", "0.1"],
     "--refine: got 3 with the cubic rung, expected 0 or 1"),
    (["compare", "bags/golden_case1.mcap", "bags/golden_case1.mcap", "--window", "10:20"],
     "--window: got 10:20 s, expected a span that overlaps the reference's records "
     "[0, 2.5] s"),
])
def test_a_quiet_accept_is_now_refused_in_one_line(argv, says, tmp_path, capsys,
                                                  monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    if argv[0] == "simulate":
        argv = argv + ["--quiet", "--out", str(tmp_path / "x.csv")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err, err
    assert not (tmp_path / "x.csv").exists()


def test_a_negative_shape_rate_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    assert main(["replay", "bags/golden_case1.mcap", "--rerun", str(tmp_path / "x.rrd"),
                 "--shape-rate", "-1"]) == 2
    assert "shape_rate: got -1.0, expected a number >= 0" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()


def test_a_lawson4_step_that_divides_the_output_period_still_runs(tmp_path):
    assert main(["simulate", "link", "--dt", "0.0005", "--duration", "0.05", "--quiet",
                 "--out", str(tmp_path / "x.csv")]) == 0


def test_calibrate_refuses_a_billion_starts(capsys, monkeypatch):
    """It allocated the Sobol sample of 1e9 starts (8 GiB) before saying anything."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    assert main(["calibrate", "link", "bags/golden_case1.mcap", "--param",
                 "links[0].beam.EI=1000:4000", "--starts", "1000000000"]) == 2
    assert "--starts: got 1000000000, expected an integer from 1 to 10000" in \
        capsys.readouterr().err


def test_a_bag_with_nothing_to_draw_is_refused_and_the_old_recording_kept(tmp_path, capsys):
    from mcap.writer import Writer
    bag = tmp_path / "foreign.mcap"
    with open(bag, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema(name="x", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/foo", message_encoding="json", schema_id=sid)
        w.add_message(channel_id=cid, log_time=1, data=b"{}", publish_time=1)
        w.finish()
    rrd = tmp_path / "old.rrd"
    rrd.write_bytes(b"an earlier recording")
    assert main(["replay", str(bag), "--rerun", str(rrd)]) == 2
    err = capsys.readouterr().err
    assert "with nothing the rerun view draws (its topics: /foo)" in err
    assert rrd.read_bytes() == b"an earlier recording"
    assert [p.name for p in tmp_path.iterdir()] and not list(tmp_path.glob(".*partial*"))
