"""The progress line (flexarm_ros/io/progress.py): redrawn in place on a terminal, one
plain line per update (throttled) in a log file."""

import pytest
import io

from flexarm_ros.io import progress as P


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_on_a_terminal_the_line_is_redrawn_and_blanked():
    out = _Tty()
    line = P.ProgressLine(10, out)
    line.show("a")
    line.show("bb")
    line.clear()
    assert out.getvalue() == "\ra         \rbb        \r          \r"


def test_in_a_log_file_each_update_is_a_line_of_its_own_at_most_once_per_period(
        monkeypatch):
    now = [100.0]
    monkeypatch.setattr(P.time, "monotonic", lambda: now[0])
    out = io.StringIO()                        # not a terminal
    line = P.ProgressLine(10, out)
    line.show("  t = 1")
    now[0] += 1.0
    line.show("  t = 2")                      # within LOG_PERIOD_S: not written
    now[0] += P.LOG_PERIOD_S
    line.show("  t = 3")
    line.show("  t = 4", final=True)          # the final one always
    line.clear()
    assert out.getvalue() == "t = 1\nt = 3\nt = 4\n"
    assert "\r" not in out.getvalue()


@pytest.mark.heavy
def test_a_compile_notice_comes_once_and_only_from_inside_numbas_compiler(tmp_path):
    """The notice looks at the entering thread's stack: a frame of numba's compiler.py
    (here a stand-in compiled with that file name) makes it speak once; the same wait
    elsewhere keeps it silent."""
    import io
    import os
    import time
    from flexarm_ros.io.progress import NUMBA_COMPILER, CompileNotice
    ns = {"time": time}
    fake = os.path.join(str(tmp_path), *NUMBA_COMPILER)
    exec(compile("def compile_extra():\n    time.sleep(0.4)\n", fake, "exec"), ns)
    out = io.StringIO()
    with CompileNotice(after=0.05, period=0.02, stream=out) as n:
        ns["compile_extra"]()
    assert n.said and out.getvalue().count("compiling the numba kernels") == 1
    quiet = io.StringIO()
    with CompileNotice(after=0.05, period=0.02, stream=quiet) as n:
        time.sleep(0.4)
    assert not n.said and quiet.getvalue() == ""
    off = io.StringIO()
    with CompileNotice(after=0.05, period=0.02, stream=off, enabled=False) as n:
        ns["compile_extra"]()
    assert not n.said and off.getvalue() == ""
    # a cache load passes through compiler.py (CompileResult._rebuild): not a compile
    from flexarm_ros.io.progress import NUMBA_CACHE_LOAD
    loader = os.path.join(str(tmp_path), *NUMBA_CACHE_LOAD[0])
    exec(compile(f"def {NUMBA_CACHE_LOAD[1]}():\n    compile_extra()\n", loader, "exec"), ns)
    load = io.StringIO()
    with CompileNotice(after=0.05, period=0.02, stream=load) as n:
        ns[NUMBA_CACHE_LOAD[1]]()
    assert not n.said and load.getvalue() == ""
