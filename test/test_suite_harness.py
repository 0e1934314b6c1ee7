"""The suite's own harness (test/conftest.py): a pytest-xdist worker that dies of a fatal
signal has its stack printed in the run's summary, the crashing thread first
(decision 0034: CI keeps only the tail of the output, where xdist says no more than
"worker crashed")."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent

CRASHING = '''
def test_segfaults():
    import ctypes
    ctypes.string_at(0)                 # reads address 0: SIGSEGV
'''


@pytest.mark.subprocess
def test_a_crashed_workers_stack_is_in_the_summary(tmp_path):
    shutil.copy2(HERE / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "extended.txt").write_text("")
    (tmp_path / "pytest.ini").write_text("[pytest]\naddopts = -p no:cacheprovider\n")
    (tmp_path / "test_crash.py").write_text(CRASHING)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PYTEST_", "FLEXARM_TEST_"))}
    r = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--max-worker-restart",
                        "0", "-q", str(tmp_path)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stdout + r.stderr
    out = r.stdout
    section = out[out.index("fatal error in worker gw"):out.index("short test summary")]
    lines = section.splitlines()
    assert "Fatal Python error: Segmentation fault" in lines[1], section
    crashing = section[section.index("Current thread"):]
    crashing = crashing[:crashing.index("\n\n")]
    assert "in test_segfaults" in crashing, section
    assert "test_crash.py::test_segfaults" in out, out
