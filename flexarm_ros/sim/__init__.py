"""Integration of the model in time: ``integrate`` (fixed-step RK4 and the trapezoidal rule
compiled, scipy's ``solve_ivp`` methods; step choice and the divergence guard),
``contact_stepper`` (RK4 through the contact modes with located events), ``plant`` (the
plant stepped tick by tick with held inputs, as the ROS simulator drives it) and
``simulate`` (a whole batch run of a scene into named columns).

    from flexarm_ros.sim import simulate
    result = simulate(load_scene("two_link_free"), duration=1.0)
"""

from importlib import import_module

_PUBLIC = {"simulate": "simulate", "SimResult": "simulate", "Plant": "plant",
           "integrate": "integrate", "Integration": "integrate", "choose_step": "integrate",
           "ContactStepper": "contact_stepper"}
__all__ = sorted(_PUBLIC)


def __getattr__(name):
    if name in _PUBLIC:
        return getattr(import_module(f"flexarm_ros.sim.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module 'flexarm_ros.sim' has no attribute {name!r}")
