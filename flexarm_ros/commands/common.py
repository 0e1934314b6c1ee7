"""What the ``flexarm`` commands share: the scene argument, the fidelity overrides and
``--set`` (:func:`fidelity_args`, read back by :func:`overrides` and :func:`set_values`),
the scene they give (:func:`load`), the ``set:`` summary line, ``--duration``'s check and
the progress line on stderr."""

from __future__ import annotations

import math

from flexarm_ros.io.arguments import integer, number, set_option
from flexarm_ros.scene import DEFAULT_SCENE

SCENE_HELP = f"scene YAML path or shipped scene name (default {DEFAULT_SCENE})"
#: the exit status of a run whose tolerance the check against the top rung found not met
#: (its outputs written; ``--best-effort`` exits 0 instead)
TOLERANCE_NOT_MET = 4


def tolerance_status(summ: dict, args) -> int:
    """0, or :data:`TOLERANCE_NOT_MET` with one line on stderr, for a run summary whose
    tolerance the check found not met (``--best-effort``: 0, the warning stands)."""
    import sys
    if summ.get("tolerance_met") is not False or getattr(args, "best_effort", False):
        return 0
    print(f"flexarm: tolerance not met (exit {TOLERANCE_NOT_MET}; the outputs are written; "
          f"--best-effort accepts the run): {summ.get('warning', '')}".rstrip(": "),
          file=sys.stderr)
    return TOLERANCE_NOT_MET


def fail(text):
    from flexarm_ros.errors import InputError
    raise InputError(text)


def check_duration(value, allow_inf=False):
    """``--duration``: None (the scene's) or a number > 0 s, finite unless ``allow_inf``
    (``run``: inf = until Ctrl-C)."""
    if value is None:
        return None
    if math.isnan(value) or not value > 0 or (math.isinf(value) and not allow_inf):
        fail(f"--duration: got {value}, expected a "
             + ("number > 0 s (inf: until Ctrl-C)" if allow_inf else
                "finite number > 0 s"))
    return value


def scene_arg(p):
    p.add_argument("scene", nargs="?", help=SCENE_HELP)


def open_loop_arg(p):
    from flexarm_ros.io.arguments import OPEN_LOOP_HELP
    p.add_argument("--open-loop", action="store_true", help=OPEN_LOOP_HELP)


def fidelity_args(p):
    """The fidelity overrides, and ``--set KEY=VALUE`` (every command that takes them
    builds a model from the scene)."""
    from flexarm_ros.scene import INTEGRATORS, RUNG_CHOICES
    set_option(p.add_argument_group("scene overrides"))
    g = p.add_argument_group("fidelity overrides (default: the scene's)")
    g.add_argument("--rung", choices=RUNG_CHOICES,
                   help="beam discretization rung; auto: the cheapest rung, refinement and "
                        "RK4 step estimated to meet --tolerance (default 1e-5 m tip)")
    g.add_argument("--refine", type=integer,
                   help="modes / elements / FD segments / rod curvature terms (0: the rung's "
                        "default)")
    g.add_argument("--integrator", choices=INTEGRATORS, help="time integrator")
    g.add_argument("--rtol", type=number, help="relative tolerance (adaptive integrators)")
    g.add_argument("--atol", type=number, help="absolute tolerance (adaptive integrators)")
    g.add_argument("--dt", type=number,
                   help="fixed step (rk4, rkn4, trapezoid, lawson4) or max step, s; 0 = "
                        "automatic")
    g.add_argument("--tolerance", type=number, metavar="M",
                   help="tip-position error bound, m: with --rung auto the model and step "
                        "are chosen for it; with a named rung the step (simulate): rk4's "
                        "(the contact stepper's with a wall) or the trapezoid's; 0: none "
                        "(the automatic step; rung auto's default 1e-5 m), e.g. to clear a "
                        "scene's fidelity.tolerance")
    g.add_argument("--best-effort", action="store_true",
                   help="with --tolerance: a run that does not meet it still exits 0 (its "
                        "outputs are written either way; without this flag such a run "
                        f"exits {TOLERANCE_NOT_MET}, 'tolerance not met')")
    g.add_argument("--tolerance-metric", choices=("position", "deflection", "both"),
                   help="what --tolerance bounds: the tip position in the world frame, "
                        "the elastic tip deflection of every link in its hub frame, or both "
                        "(default); checked against the geometrically exact rung over the "
                        "whole run (docs/accuracy.md)")
    g.add_argument("--no-foreshortening", action="store_true",
                   help="drop the geometric-stiffening (foreshortening) terms")
    g.add_argument("--max-steps", type=number, metavar="N",
                   help="work budget: refuse a run needing more integrator steps "
                        "(fidelity.max_steps, default 1e8)")


def overrides(args) -> dict:
    """The fidelity options given → ``Scene.with_fidelity`` keywords (None: not given)."""
    over = {k: getattr(args, k, None) for k in
            ("rung", "refine", "integrator", "rtol", "atol", "dt", "max_steps",
             "tolerance", "tolerance_metric")}
    if getattr(args, "no_foreshortening", False):
        over["foreshortening"] = False
    if getattr(args, "estimate", False):
        over["estimate"] = True
    return over


def set_values(args) -> dict:
    """The ``--set KEY=VALUE`` options → ``{key: value}`` (InputError: one line)."""
    from flexarm_ros.scene.overrides import parse_sets
    return parse_sets(getattr(args, "set", None))


def load(args):
    """The scene with the ``--set`` values, then the fidelity flags
    (:func:`~flexarm_ros.scene.overrides.with_overrides`: an explicit flag wins over a
    ``--set fidelity.…``, which survives a flag's resets)."""
    from flexarm_ros.scene import load_scene
    from flexarm_ros.scene.overrides import with_overrides
    return with_overrides(load_scene(args.scene or DEFAULT_SCENE), set_values(args),
                          overrides(args))


def set_line(sets: dict) -> str | None:
    """The text summaries' ``  set: KEY=VALUE, ...`` line (None: nothing set)."""
    from flexarm_ros.scene.overrides import format_sets
    return f"  set: {format_sets(sets)}" if sets else None


class Progress:
    """The progress line on stderr (simulated time / total), at most once per wall second
    (the integrators call it), cleared at the end; nothing with ``quiet``
    (:class:`~flexarm_ros.io.progress.ProgressLine`)."""

    WIDTH = 48

    def __init__(self, total_s, quiet):
        from flexarm_ros.io.progress import ProgressLine
        self.total = total_s
        self.quiet = quiet
        self.line = ProgressLine(self.WIDTH)

    @property
    def callback(self):
        return None if self.quiet else self

    def __call__(self, frac):
        self.line.show(f"  t = {frac * self.total:.4g} / {self.total:.4g} s "
                       f"({100 * frac:5.1f} %)")

    def clear(self):
        """Blank the progress line, if one was drawn."""
        if not self.quiet:
            self.line.clear()
