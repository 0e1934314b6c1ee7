"""The ROS parameters every node of the twin takes, and how the ``flexarm`` fidelity options
travel as parameters (no rclpy here: ``flexarm run`` builds the values, the nodes declare
them through :mod:`flexarm_ros.nodes.common`).

Each entry is ``name: (default, description)``; the default's type is the parameter's type.
The fidelity parameters mirror ``flexarm simulate``'s options ``--rung``, ``--refine``,
``--integrator``, ``--rtol``, ``--atol``, ``--dt``, ``--no-foreshortening`` and
``--max-steps``; at its default a parameter keeps the scene's value. ``set`` carries
``--set KEY=VALUE`` (:func:`flexarm_ros.scene.overrides.encode_sets`), applied to the
loaded scene before them.
"""

from __future__ import annotations

from flexarm_ros.scene import DEFAULT_SCENE

MODES = ("lockstep", "realtime", "fast")

COMMON = {
    "scene": (DEFAULT_SCENE, "scene YAML path or shipped scene name"),
    "mode": ("lockstep", "time mode: lockstep (message-driven, deterministic), realtime "
                         "(wall-clock paced) or fast (free-running, /clock)"),
    "duration": (0.0, "simulated seconds until the run ends (0: the scene's duration, inf: "
                      "no end); the controller and driver do not answer states at or past it"),
    "recorders": (0, "recorders expected on every topic before publishing starts (lockstep "
                     "loses nothing only if every subscriber is matched first)"),
    "set": ("", "scene values to set before the fidelity parameters, a JSON object "
                "{\"key path\": value} (flexarm run --set KEY=VALUE; empty: none)"),
    "run_enclave": ("", "set by flexarm run: the ROS enclave it put this run's nodes in "
                        "(--ros-args --enclave), which tells its nodes from another run's "
                        "in the same namespace and domain (empty: started by hand)"),
    "stop_file": ("", "set by flexarm run for the nodes it starts as processes: a file it "
                      "creates before it stops them; a SIGINT/SIGTERM while the file does "
                      "not exist came from outside the run, and the node says so and exits "
                      "128 + the signal's number (empty: every signal is a normal stop)"),
}

FIDELITY = {
    "rung": ("", "beam discretization rung: rigid, cubic, modal, fem, fd, rod or auto "
                 "(empty: the scene's)"),
    "refine": (-1, "modes / elements / FD segments (0: the rung's default; negative: the "
                    "scene's)"),
    "integrator": ("", "time integrator (empty: the scene's)"),
    "rtol": (0.0, "relative tolerance of adaptive integrators (0: the scene's)"),
    "atol": (0.0, "absolute tolerance of adaptive integrators (0: the scene's)"),
    "dt": (-1.0, "fixed step (rk4) or max step, s; 0 automatic (negative: the scene's)"),
    "no_foreshortening": (False, "drop the geometric-stiffening (foreshortening) terms"),
    "max_steps": (0.0, "work budget: most integrator steps a run may need (0: the scene's)"),
}

#: the keyword arguments of :meth:`~flexarm_ros.scene.Scene.with_fidelity` they stand for
FIDELITY_KEYS = ("rung", "refine", "integrator", "rtol", "atol", "dt", "foreshortening",
                 "max_steps")


def fidelity_parameters(overrides: dict | None) -> dict:
    """``Scene.with_fidelity`` keyword arguments (a None value: keep the scene's) → the node
    parameters that carry them (only the ones set)."""
    out = {}
    for key, value in (overrides or {}).items():
        if key not in FIDELITY_KEYS:
            raise ValueError(f"fidelity override {key!r}: expected one of "
                             f"{', '.join(FIDELITY_KEYS)}")
        if value is None:
            continue
        if key == "foreshortening":
            if not value:
                out["no_foreshortening"] = True
        else:
            out[key] = type(FIDELITY[key][0])(value)
    return out


def fidelity_overrides(params: dict) -> dict:
    """Node parameter values → ``Scene.with_fidelity`` keyword arguments (parameters at
    their defaults are left out: the scene's values stay)."""
    out = {}
    for key in ("rung", "integrator"):
        if params.get(key):
            out[key] = params[key]
    if params.get("refine", -1) >= 0:
        out["refine"] = params["refine"]
    for key in ("rtol", "atol", "max_steps"):
        if params.get(key, 0.0) != 0.0:
            out[key] = params[key]
    if params.get("dt", -1.0) >= 0.0:
        out["dt"] = params["dt"]
    if params.get("no_foreshortening"):
        out["foreshortening"] = False
    return out
