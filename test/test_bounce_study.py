"""The seed 000 bounce study (flexarm_ros/studies/bounce_seed000.py, docs/calibration_seed000.md
§6): its reading of impact, flights and f_A against a gap series built with known values,
and the shipped Case 1 read through it on the runner as the twin's own contact log says."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from flexarm_ros.studies import bounce_seed000 as bs


def synthetic_run():
    """A gap that closes at 0.2 s, flies 4 mm (0.3-0.5 s, a half sine), rests, flies
    9 mm (0.7-0.8 s); an 11.0 Hz decaying ring at point A after the impact (4 kHz)."""
    t = np.arange(0, 1.0 + 5e-4, 1e-3)
    gap = np.where(t < 0.2, 0.01 * (0.2 - t), 0.0)
    for a, b, hgt in ((0.3, 0.5, 4e-3), (0.7, 0.8, 9e-3)):
        on = (t > a) & (t < b)
        gap[on] = hgt * np.sin(np.pi * (t[on] - a) / (b - a))
    ts = np.arange(0, 1.0, 2.5e-4)
    acc = np.where(ts > 0.2, np.exp(-2.0 * (ts - 0.2)) * np.sin(2 * np.pi * 11.0 * ts), 0.0)
    return SimpleNamespace(columns={"t": t, "gap": gap},
                           sensor_tables={4000.0: {"t": ts, "acc_A_true": acc}})


def test_the_reading_finds_the_impact_the_flights_and_the_ring_it_was_given():
    f = bs.features(synthetic_run())
    assert f["impact_s"] == pytest.approx(0.2, abs=1e-9)
    assert f["bounces_m"] == pytest.approx([4e-3, 9e-3], rel=1e-3)
    assert f["main_m"] == pytest.approx(4e-3, rel=1e-3)
    assert f["f_A"] == pytest.approx(11.0, abs=0.05)


def test_the_shipped_case1_through_the_runner_agrees_with_its_contact_log():
    """The shipped row on the runner: impact and first flight as the contact stepper's
    own impact log and gap give them (a second reading), and the §6 figures."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.sim.simulate import simulate
    row = bs.candidates(only="shipped")[0]
    res = simulate(load_scene("two_link_case1"), bs.DURATION)
    assert row["impact_s"] == pytest.approx(res.contact.impacts[0].time, abs=1e-3)
    assert row["impact_s"] == pytest.approx(2.099, abs=2e-3)
    assert 25e-3 < row["bounces_m"][0] < 35e-3          # §6: 30.0 mm, the target missed
    assert row["f_A"] == pytest.approx(10.85, abs=0.1)


def _tool(name):
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "tools" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("tool,argv,words", [
    ("bounce_candidates_seed000", ["--only", "nosuch"],
     ["--only", "'nosuch'", "no group contains", "beam damping"]),
    ("bearing_friction_seed000", ["case9"],
     ["part", "'case9'", "expected one of case1, case3, case2, take"]),
    ("bounce_candidates_seed000", ["--workers", "0", "--timeout", "-1"],
     ["--timeout", "-1.0", "expected a finite number > 0 s"]),
])
def test_the_seed000_tools_refuse_bad_input_in_one_line(tool, argv, words, capsys):
    """Before any run: exit 2 and one line naming the option, the value and what is
    expected."""
    assert _tool(tool).main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(w in err[0] for w in words), err
