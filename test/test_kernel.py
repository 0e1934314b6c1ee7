"""The compiled kernel and the numpy reference evaluate the same equations (to round-off)."""

import numpy as np
import pytest


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.chain import Chain
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

pytestmark = pytest.mark.skipif(not kchain.HAVE_NUMBA, reason="numba not installed")

# a scene that touches every term: gravity off-axis, hub radius, CG and joint offsets,
# joint flexibility, beam damping, a torque program and a prescribed motion
SCENE = {
    "name": "everything", "gravity": [0.3, -9.8], "duration": 0.05,
    "links": [
        {"name": "l1", "beam": {"length": 0.65, "EI": 60.0, "mass_per_length": 0.32,
                                "hub_radius": 0.05,
                                "damping": {"viscous_per_length": 0.1,
                                            "stiffness_proportional": 1e-4}},
         "hub": {"mass": 0.1, "inertia": 8e-5, "cg": [0.01, 0.02]},
         "tip": {"mass": 2.34, "inertia": 2.15e-3, "joint_offset": [0.03, -0.01],
                 "cg": [0.01, 0.0]},
         "joint": {"initial_rate": 1.0, "drive_inertia": 0.05, "drive_damping": 0.1,
                   "flexibility": {"stiffness": 100.0, "damping": 0.1,
                                   "motor_inertia": 0.01}}},
        {"name": "l2", "beam": {"length": 0.6575, "EI": 60.0, "mass_per_length": 0.32},
         "hub": {"mass": 0.087, "inertia": 3.3e-5},
         "tip": {"mass": 1.94, "inertia": 2.35e-3, "cg": [0.02, 0.01]},
         "joint": {"initial_rate": -2.0}}],
    "inputs": [{"joint": 1, "torque": {"type": "square", "amplitude": 0.3,
                                       "frequency_hz": 2.0}},
               {"joint": 2, "motion": {"type": "spin_up", "omega": 2.0, "ramp_time": 1.0}}],
}


def _scene(rung, **fid):
    d = dict(SCENE)
    d["fidelity"] = {"rung": rung, **fid}
    return load_scene_dict(d)


@pytest.mark.parametrize("rung", ["rigid", "cubic", "modal", "fem", "fd"])
@pytest.mark.parametrize("foreshortening", [True, False])
def test_rhs_matches_numpy_reference(rung, foreshortening):
    chain = Chain(_scene(rung, foreshortening=foreshortening), backend="numba")
    rng = np.random.default_rng(1)
    for t in (0.0, 0.37, 1.4):
        x = rng.normal(size=2 * len(chain.free)) * 0.05
        ref = chain.rhs_numpy(t, x)
        got = chain.rhs(t, x)
        assert np.allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_a_strided_state_costs_no_second_compile_of_the_kernel():
    """``Chain.rhs`` of a column of a history (a strided view) gives the contiguous copy's
    numbers through the kernel's one compiled signature: each other array layout would
    compile the whole kernel again (a cold suite compiled ``rhs`` and ``rhs_into`` twice,
    ~25 s of CPU)."""
    chain = Chain(_scene("modal"), backend="numba")
    rng = np.random.default_rng(2)
    history = rng.normal(size=(2 * len(chain.free), 3)) * 0.05
    want = chain.rhs(0.2, history[:, 1].copy())
    signatures = list(kchain.rhs.signatures)
    got = chain.rhs(0.2, history[:, 1])
    assert not history[:, 1].flags.c_contiguous
    assert np.array_equal(got, want)
    assert list(kchain.rhs.signatures) == signatures


@pytest.mark.parametrize("rung", ["rigid", "cubic", "modal", "fem", "fd"])
@pytest.mark.parametrize("foreshortening", [True, False])
@pytest.mark.parametrize("sums", ["points", "invariants"])
def test_beam_sums_by_points_and_by_invariants_match_numpy(rung, foreshortening, sums,
                                                          monkeypatch):
    """Either way of summing a beam's inertia in the compiled kernel (forced here on every
    rung, also where the cost rule would not choose it) against the numpy reference, which
    sums over the points."""
    import flexarm_ros.model.rung_chain as chain_mod
    monkeypatch.setattr(chain_mod, "by_invariants", lambda ne, points, fs: sums == "invariants")
    chain = Chain(_scene(rung, foreshortening=foreshortening), backend="numba")
    assert chain.model.invariant.all() == (sums == "invariants")
    rng = np.random.default_rng(7)
    # large deflections, where the quartic terms count (the meshes' 16-20 coordinates at
    # that size make M ill-conditioned: there as in the test above)
    scale = 0.05 if rung in ("fem", "fd") else 0.2
    for t in (0.0, 0.37, 1.4):
        x = rng.normal(size=2 * len(chain.free)) * scale
        ref = chain.rhs_numpy(t, x)
        got = chain.rhs(t, x)
        assert np.allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_the_cost_rule_takes_invariants_for_modal_and_cubic_not_fine_meshes(monkeypatch):
    import flexarm_ros.model.rung_chain as chain_mod
    monkeypatch.setattr(chain_mod, "BEAM_SUMS", "invariants")   # the default, whatever the env says
    chain_of = {r: Chain(_scene(r, **({"refine": 8} if r == "fem" else {})), backend="numba")
                for r in ("cubic", "modal", "fem")}
    assert chain_of["cubic"].model.invariant.all()
    assert chain_of["modal"].model.invariant.all()
    assert not chain_of["fem"].model.invariant.any()


@pytest.mark.parametrize("rung", ["cubic", "modal"])
def test_compiled_run_matches_numpy_run(rung):
    # the numba run's automatic step for both (each backend's stability estimate differs at
    # round-off, and the dense output keeps a step as it is)
    h = simulate(_scene(rung, output_dt=0.005), 0.005).run.dt
    sc = _scene(rung, output_dt=0.005, dt=h)
    a = simulate(sc, chain=Chain(sc, backend="numba"))
    b = simulate(sc, chain=Chain(sc, backend="numpy"))
    assert a.run.dt == b.run.dt == h
    assert a.run.rhs_evaluations == b.run.rhs_evaluations
    for key in ("tip_x", "tip_y", "energy", "l1_joint", "l2_joint_rate"):
        assert np.allclose(a.columns[key], b.columns[key], rtol=1e-9, atol=1e-11), key



_BITS = """
from flexarm_ros.scene import load_scene
from flexarm_ros.sim.simulate import simulate
r = simulate(load_scene("two_link_free"), 0.3)
print(repr(r.run.dt), r.run.rhs_evaluations, r.columns["tip_x"].tobytes().hex())
"""


@pytest.mark.slow
@pytest.mark.subprocess
def test_a_fresh_compile_and_a_cache_load_give_the_same_bits(tmp_path):
    """A process that compiles the kernel and one that loads it from numba's cache run the
    same bits (with fast-math's 'reassoc' they did not: docs/decisions/0016-the-compiled-kernel.md,
    "Why not 'reassoc'"); the ensembles' Dask workers depend on it. Two subprocesses, one empty
    cache directory; the first compiles (about a minute)."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    env.pop("FLEXARM_BEAM_SUMS", None)
    runs = [subprocess.run([sys.executable, "-c", _BITS], env=env, capture_output=True,
                           text=True, timeout=900) for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    assert any((tmp_path / "numba").rglob("*.nbi")), "the first run wrote no cache"
    assert runs[0].stdout == runs[1].stdout


def test_the_cache_digest_covers_every_module_numba_compiles():
    """numba's cache keys a function on its own file only, so the digest naming the cache
    directory must cover every file whose functions are compiled: any module using the
    compiler (``jit``, ``jit_inline``, ``jit_raw`` or ``numba``) is among them."""
    import re
    from pathlib import Path
    from flexarm_ros.model.compiled import cache_dir, compiled_sources, source_key
    pkg = Path(__file__).resolve().parents[1] / "flexarm_ros"
    covered = {p.resolve() for p in compiled_sources()}
    uses = re.compile(r"^\s*@(_?jit\w*)|^\s*\w+ = _?jit\w*\(|^import numba|^\s*@numba\.",
                      re.M)
    users = {p.resolve() for p in pkg.rglob("*.py") if uses.search(p.read_text())}
    assert users and users <= covered, sorted(str(p) for p in users - covered)
    assert cache_dir("/x").name == f"flexarm-{source_key()}"


def test_a_cold_cache_is_told_from_a_warm_one(tmp_path, monkeypatch):
    """``cache_is_cold``: no compiled function in numba's cache directory (what
    ``flexarm run`` compiles once in the parent for)."""
    numba = pytest.importorskip("numba")
    from flexarm_ros.model.compiled import HAVE_NUMBA, cache_is_cold
    if not HAVE_NUMBA:
        pytest.skip("numba disabled")
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    assert cache_is_cold()
    (tmp_path / "chain.span-1.py311.nbi").write_bytes(b"")
    assert not cache_is_cold()


_TWO_COMPILERS = """
import os, sys, time
from pathlib import Path
from flexarm_ros.model.compiled import jit

@jit
def work(x):
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] ** 1.5 - i * 0.5
    return s

go = Path(sys.argv[1])
Path(sys.argv[2]).touch()                   # imported, ready
while not go.exists():                      # both processes start compiling at once
    time.sleep(0.005)
import numpy as np
print(work(np.arange(4.0)), sum(work.stats.cache_misses.values()),
      sum(work.stats.cache_hits.values()))
"""


@pytest.mark.subprocess
def test_two_processes_on_a_cold_cache_compile_a_function_once(tmp_path):
    """Two processes that need one function at the same moment on an empty cache: one
    compiles it, the other waits on its lock and loads it (``compiled._CompileLock``);
    without the lock both compile (the suite's workers each compiled every kernel)."""
    import os
    import subprocess
    import sys
    import time
    from flexarm_ros.model.compiled import HAVE_NUMBA, fcntl
    if not HAVE_NUMBA or fcntl is None:
        pytest.skip("numba disabled or no flock here")
    module = tmp_path / "two_compilers.py"
    module.write_text(_TWO_COMPILERS)
    go = tmp_path / "go"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    ready = [tmp_path / f"ready{i}" for i in range(2)]
    procs = [subprocess.Popen([sys.executable, str(module), str(go), str(r)], env=env,
                              cwd=tmp_path, stdout=subprocess.PIPE, text=True)
             for r in ready]
    deadline = time.monotonic() + 120
    while not all(r.exists() for r in ready) and time.monotonic() < deadline:
        time.sleep(0.01)
    go.touch()                                  # both imported and waiting: go
    outs = [p.communicate(timeout=300)[0].split() for p in procs]
    assert [p.returncode for p in procs] == [0, 0]
    assert outs[0][0] == outs[1][0]             # the same result
    # (compiled, loaded from the cache) per process: one compiled, the other loaded
    assert sorted((int(o[1]), int(o[2])) for o in outs) == [(0, 1), (1, 0)], outs


def test_a_compile_lock_held_too_long_is_waited_for_then_passed(tmp_path, monkeypatch):
    """A process whose compile lock another holder keeps (stopped, hung) waits its
    ``patience`` and then compiles anyway, with the same result: a stopped process never
    stalls the others for good."""
    import fcntl as _fcntl
    import os
    import time
    numba = pytest.importorskip("numba")
    from flexarm_ros.model import compiled
    if not compiled.HAVE_NUMBA or compiled.fcntl is None:
        pytest.skip("numba disabled or no flock here")
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(compiled._CompileLock, "patience", 0.4)

    def cube(x):
        return x * x * x
    f = compiled.jit(cube)
    path = tmp_path / f"{cube.__module__}.{cube.__qualname__}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        _fcntl.flock(fd, _fcntl.LOCK_EX)            # another holder
        t0 = time.monotonic()
        assert f(3.0) == 27.0
        assert time.monotonic() - t0 >= 0.4         # it waited its patience first
    finally:
        os.close(fd)
    assert not compiled._CompileLock.held           # nothing left held in this process


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.subprocess
def test_a_first_run_in_processes_compiles_once_and_says_so(tmp_path):
    """``flexarm run --processes`` on an empty numba cache: the parent compiles the
    kernels once, saying so, and the run's wall time with start-up covers it (a
    new-user trial saw 80 s of silence and a summary of half that)."""
    import json
    import os
    import subprocess
    import sys
    import time
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "run", "link",
                        "--processes", "--duration", "0.05", "--no-record", "--json"],
                       env=env, capture_output=True, text=True, timeout=900, cwd=tmp_path)
    wall = time.monotonic() - t0
    assert r.returncode == 0, r.stderr[-2000:]
    assert "compiling the numba kernels" in r.stderr
    s = json.loads(r.stdout)
    assert s["wall_time_s"] > 0.6 * wall
