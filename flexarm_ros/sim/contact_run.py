"""A run of a scene with a wall: the contact stepper (:mod:`contact_stepper`) set up
and run over a whole run, as batch simulation and the accuracy pilots take it."""

from __future__ import annotations

import time

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model.contact import check_integrator
from flexarm_ros.sim.budget import check_work
from flexarm_ros.sim.contact_stepper import integrate_contact, warm_up
from flexarm_ros.sim.guard import DivergenceGuard
from flexarm_ros.sim.integrate import Integration, input_breakpoints, smooth
from flexarm_ros.sim.step import choose_step


def integrate_with_contact(chain, contact, x0, T, out_dt, progress=None, accelerometers=None,
                           dt=None):
    """Run a scene with a wall (fixed-step RK4 through the contact modes); the readings of
    ``accelerometers`` (:func:`ksensors.pack`'s arrays) at every sample in ContactRun.acc.
    The step: ``dt`` when given (the tolerance's), else fidelity.dt (0: automatic)."""
    fid = chain.fidelity
    check_integrator(chain)
    tm = contact.terms(0.0, x0)
    g0 = contact.gap(tm)
    if g0 < 0:
        sc = chain.scene
        w = sc.walls[0]
        lengths = ", ".join(f"links[{k}].beam.length = {lk.beam.length:g} m"
                            for k, lk in enumerate(sc.links))
        raise SceneError(f"walls[0]: the tool starts {-g0:.6g} m inside the wall (tool at "
                         f"{[round(float(v), 6) for v in tm.r]} m; walls[0].point = "
                         f"{list(w.point)} m, walls[0].normal = {list(w.normal)}; "
                         f"{lengths}), expected "
                         f"a start on the free side (gap >= 0)")
    chain.check_mass_matrix(chain.full_state(0.0, x0)[0])
    dense = smooth(chain)
    h = choose_step(chain, x0, "rk4", fid.dt if dt is None else dt, out_dt, contact=contact,
                    dense=dense)
    check_work(chain, x0, h, T, "rk4", contact)
    guard = DivergenceGuard(chain, fid.max_deflection_ratio, "rk4", h)
    import scipy.optimize  # noqa: F401  the stepper's root finder: its import outside the timing
    warm_up(chain, contact, x0, accelerometers)        # compiled code: outside the timing too
    wall0 = time.perf_counter()
    xs, crun, steps, calls = integrate_contact(
        chain, contact, x0, T, h, out_dt, guard, progress,
        input_breakpoints(chain, T) if dense else (), accelerometers)
    wall = time.perf_counter() - wall0
    t = np.arange(len(xs)) * out_dt
    return Integration.completed(chain, t, xs, calls, steps, wall, h), crun
