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


@pytest.mark.parametrize("rung", ["cubic", "modal"])
def test_compiled_run_matches_numpy_run(rung):
    a = simulate(_scene(rung, output_dt=0.005), chain=Chain(_scene(rung, output_dt=0.005),
                                                            backend="numba"))
    b = simulate(_scene(rung, output_dt=0.005), chain=Chain(_scene(rung, output_dt=0.005),
                                                            backend="numpy"))
    assert a.run.dt == b.run.dt
    for key in ("tip_x", "tip_y", "energy", "l1_joint", "l2_joint_rate"):
        assert np.allclose(a.columns[key], b.columns[key], rtol=1e-9, atol=1e-11), key

