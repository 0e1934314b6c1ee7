"""The ``flexarm`` command: simulate, modes, linearize, explain, study, run, replay, compare,
sweep, uncertainty, sensitivity (the ensembles: :mod:`flexarm_ros.ensemble.cli`).

``simulate``, ``modes``, ``linearize``, ``explain`` and ``study`` need no ROS; ``run`` and
``replay`` use ROS 2 (loopback-only discovery unless set, see
:mod:`flexarm_ros.nodes.environment`); ``compare`` reads bags and CSV files.

Every command that builds a model (simulate, modes, linearize, explain, run) takes the
fidelity overrides ``--rung``, ``--refine``, ``--integrator``, ``--rtol``, ``--atol``,
``--dt``, ``--no-foreshortening`` and ``--max-steps`` (the work budget,
:mod:`flexarm_ros.sim.budget`), and ``--set KEY=VALUE`` (any scene key path,
:mod:`flexarm_ros.scene.overrides`; applied before the fidelity flags, which win);
``study`` varies rung, refinement and integrator itself and takes only
``--no-foreshortening``. ``SCENE`` is a YAML path or the name of a shipped scene
(``flexarm simulate link_tipmass``); without it every command uses
:data:`flexarm_ros.scene.DEFAULT_SCENE` (``two_link_case1``). ``--quiet`` hides progress
(``t = simulated / total s`` on stderr, at most once a second), never the final summary
line.

Exit codes: 0 done, 1 failed (``run``: a node exited with an error; ``compare``: a check
failed; ``replay``: no subscriber in time), 2 bad input (one line on stderr naming the key,
the value and the expectation; arguments, scene, output paths and the work budget are
checked before the work starts), 3 the simulation diverged, 130 interrupted.

The commands live one per module in :mod:`flexarm_ros.commands` (``add_parser(sub)`` +
``main(args)``); this module lists them, builds the top-level parser and runs one.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time

#: the commands in the order ``flexarm --help`` lists them (then the ensembles' and
#: calibrate, registered by their own packages): modules of :mod:`flexarm_ros.commands`,
#: imported by :func:`main` inside its Ctrl-C handling (a Ctrl-C while numpy and the
#: commands load is one line too)
COMMAND_NAMES = ("new", "simulate", "modes", "linearize", "explain", "design", "study",
                 "urdf", "run", "replay", "compare", "estimate", "bag")
#: what a batch process runs with its own collector settings (:func:`_startup_gc`)
BATCH_COMMAND_NAMES = ("simulate", "modes", "linearize", "explain")
#: exit status of an interrupted command (128 + SIGINT, as a shell reports it)
INTERRUPTED = 130


def _commands():
    import importlib
    return [importlib.import_module(f"flexarm_ros.commands.{n}") for n in COMMAND_NAMES]


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (exit 2), like every other bad input."""

    def error(self, message):
        # argparse's "(choose from 'a', 'b')" in the words of every other bad input
        message = message.replace("(choose from ", "(expected one of ")
        if "expected" not in message:
            message += f" (expected the usage that {self.prog} --help shows)"
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser():
    p = _Parser(prog="flexarm", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    for command in _commands():
        command.add_parser(sub)
    from flexarm_ros.ensemble.cli import add_parsers    # sweep, uncertainty, sensitivity
    add_parsers(sub)
    from flexarm_ros.calibration.cli import add_parsers as add_calibrate
    add_calibrate(sub)
    return p


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


#: GC thresholds of a batch command's process (Python's default: 700, 10, 10)
BATCH_GC_THRESHOLD = (200_000, 10, 10)


def _startup_gc():
    """Collector settings of a batch process (:func:`main` with the process's own command
    line, ``_BATCH_COMMANDS``). Start-up creates ~120 000 long-lived objects (imports,
    numba's typing and lowering registries) and almost no cyclic garbage; at the default
    thresholds the collector walks them ~250 times (~0.1 s of a 1 s ``flexarm simulate``).
    A young generation of 200 000 objects makes a short run collect almost never and keeps
    a long one bounded (a first-run numba compile leaves ~10⁶ objects of cyclic garbage).
    Everything alive at the end is frozen (:func:`gc.freeze`, in :func:`main`) just before
    the process exits, which spares the interpreter's final collection over the whole heap
    (~0.2 s). Not for ``run`` / ``replay`` (a large young collection is a pause inside a
    realtime tick; a frozen heap skips the exit-time finalizers of objects in cycles) nor
    ``study`` / ``compare`` (long, plotting)."""
    gc.set_threshold(*BATCH_GC_THRESHOLD)


def main(argv=None) -> int:
    """Exit 0 done, 1 failed (see the module doc), 2 bad input (one line: the key, the
    value, the expectation), 3 diverged, 130 interrupted (one line, whatever was running:
    an import, a compiled integration, a Dask ensemble)."""
    t0 = time.perf_counter()
    try:
        from flexarm_ros.io.paths import forget_written
        forget_written()
        return _main(argv)
    except KeyboardInterrupt:
        return interrupted(t0)
    except Exception as exc:
        if _caused_by_interrupt(exc):   # numba: "returned a result with an exception set"
            return interrupted(t0)
        raise


def _caused_by_interrupt(exc) -> bool:
    """A KeyboardInterrupt among the causes and contexts of ``exc``: a Ctrl-C that arrived
    while compiled code called back into Python (numba's dispatcher then raises
    ``SystemError: ... returned a result with an exception set`` from it)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def interrupted(t0: float) -> int:
    """The one line of a Ctrl-C (what was written before it is kept: tables are written
    beside their names and renamed whole), exit status 130."""
    if "distributed" in sys.modules:   # a Dask cluster closing behind us: no log noise
        from flexarm_ros.ensemble.cluster import quiet_dask_logs
        quiet_dask_logs()
    from flexarm_ros.io.paths import written
    kept = written()
    what = (f"; kept what was written: {', '.join(kept[:4])}"
            + (f" and {len(kept) - 4} more" if len(kept) > 4 else "")) if kept else \
        "; outputs finished before it are kept"
    print(f"flexarm: interrupted (Ctrl-C) after {time.perf_counter() - t0:.3g} s{what}",
          file=sys.stderr, flush=True)
    return INTERRUPTED


def _main(argv=None) -> int:
    import numpy as np
    from flexarm_ros.errors import InputError, SimulationDiverged
    from flexarm_ros.nodes import environment
    environment.use_loopback()
    args = build_parser().parse_args(argv)
    batch = argv is None and args.command in BATCH_COMMAND_NAMES
    if batch:
        _startup_gc()
    try:
        # overflow / invalid arithmetic of a diverging state is reported by the guard in
        # one line (exit 3), not as numpy RuntimeWarnings on the way there
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return args.func(args)
    except InputError as exc:
        print(f"flexarm: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SimulationDiverged as exc:
        print(f"flexarm: {_one_line(exc)}", file=sys.stderr)
        return 3
    except OSError as exc:          # the environment, not the program: a disk filled up
        print(f"flexarm: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        if batch:
            gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
