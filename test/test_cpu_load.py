"""The run's CPU budget (twin/cpu_load.py): the sampler's CPU time of a child process over
a window against the child's own ``time.process_time`` (an independent clock of the same
kernel accounting, read inside the process), the interpolation, and the per-tick sums."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from flexarm_ros.twin.cpu_load import CpuSampler, _at, cpu_budget, role

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="no /proc")

# sleeps, burns BURN s of CPU between two monotonic stamps, sleeps: prints the stamps and
# the CPU the child measured itself
CHILD = """
import json, sys, time
time.sleep(0.4)
t0, c0 = time.monotonic(), time.process_time()
while time.process_time() - c0 < float(sys.argv[1]):
    pass
t1, c1 = time.monotonic(), time.process_time()
time.sleep(0.4)
print(json.dumps([t0, t1, c1 - c0]))
"""


@pytest.mark.subprocess
def test_the_sampler_measures_a_childs_cpu_over_its_window():
    sampler = CpuSampler(root_role="test", period=0.02).start()
    try:
        out = subprocess.run([sys.executable, "-c", CHILD, "0.5"], capture_output=True,
                             text=True, check=True).stdout
    finally:
        sampler.stop()
    t0, t1, own = json.loads(out)
    got = sampler.between(t0, t1)
    name = os.path.basename(sys.executable)
    # /proc's clock tick (10 ms) and a period's interpolation at each end
    assert got[name] == pytest.approx(own, abs=0.05)
    # outside the window the child slept: almost nothing
    assert sampler.between(t1 + 0.1, t1 + 0.3).get(name, 0.0) < 0.03
    # this process only waited for the child: what it used is the sampler's own reading
    # of /proc every 20 ms, which grows with the host's process count (0.27 s of the
    # child's 0.5 once, a suite and a hog beside it): less than the child's busy loop
    assert got["test"] < own


@pytest.mark.subprocess
def test_a_process_is_named_by_the_node_it_runs():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(5)",
                          "flexarm_ros.nodes.controller"])
    try:
        for _ in range(100):                  # until exec has replaced the command line
            if role(p.pid) == "controller":
                break
            time.sleep(0.01)
        assert role(p.pid) == "controller"
    finally:
        p.kill()
        p.wait()


def test_cpu_time_at_an_instant_is_linear_between_samples():
    s = [(1.0, 0.10), (2.0, 0.30), (3.0, 0.30)]
    assert _at(s, 1.5) == pytest.approx(0.20)
    assert _at(s, 2.5) == pytest.approx(0.30)
    assert _at(s, 0.5) == 0.10 and _at(s, 9.0) == 0.30      # the nearest outside


def test_the_budget_per_tick_and_the_share_of_the_cpus():
    b = cpu_budget({"simulator": 0.8, "recorder": 0.3}, ticks=1000, wall_s=1.0, cpus=2)
    assert b["cpu_ms_per_tick"] == pytest.approx({"simulator": 0.8, "recorder": 0.3})
    assert b["cpu_ms_per_tick_total"] == pytest.approx(1.1)
    assert b["cpu_share"] == pytest.approx(0.55) and b["cpus_available"] == 2
