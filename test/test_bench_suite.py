"""bench/bench_suite.py's command line (its timings are the bench's, not a test's)."""

import importlib.util
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "bench_suite.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_suite", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("argv, says", [(["--runs", "0"], "--runs: got 0"),
                                        (["--cache", "tepid"], "invalid choice: 'tepid'")])
def test_a_bad_option_stops_before_any_run(argv, says, capsys):
    with pytest.raises(SystemExit) as exc:
        _bench().main(argv)
    assert exc.value.code == 2
    assert says in capsys.readouterr().err


def test_the_bench_times_the_readmes_test_command():
    readme = (BENCH.parents[1] / "README.md").read_text()
    command = " ".join(_bench().COMMAND[1:5])          # -m pytest -m <marker expression>
    assert command.replace("-m not slow and not extended",
                           '-m "not slow and not extended"') in readme
