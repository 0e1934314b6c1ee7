"""A node process's life: its ``main()`` (:func:`node_main`: ``--help``, rclpy init,
spin until done or stopped, clean shutdown on Ctrl-C / SIGTERM, the exit status), the
executor it spins (:func:`make_executor`), SIGINT/SIGTERM as a flag (:class:`StopFlag`),
a bounded exit (:class:`ShutdownGuard`), what it tells ``flexarm run`` of how it ended
(:func:`stopped_from_outside`, :func:`tell_the_run`) and optional profiling
(:class:`profiled`)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time

import flexarm_ros.nodes.environment as environment
from flexarm_ros.nodes.parameters import COMMON, FIDELITY

class ShutdownGuard:
    """Bounds a node process's exit once its work is done (its loop ended; the recorder:
    its bag finalized). Should the rest — the final log line, the executor's and the DDS
    participant's teardown, exit handlers — hang for ``limit_s`` (seen once under a full
    test suite's load: a motor driver that a Ctrl-C had stopped was still alive 15 s
    later, and ``flexarm run --processes`` had to SIGKILL it), the guard prints every
    thread's stack to stderr, saying so, and ends the process with the status the node
    earned (3 after a divergence or a stall, else 0), before the parent's own 15 s."""

    LIMIT_S = 8.0

    def __init__(self, name: str, node, limit_s: float | None = None):
        self.name, self.node = name, node
        self.limit_s = self.LIMIT_S if limit_s is None else limit_s
        t = threading.Timer(self.limit_s, self._fire)
        t.daemon = True
        t.start()

    def _fire(self):
        import faulthandler
        import os
        limit = self.limit_s
        try:
            print(f"{self.name}: its work is done but the process has not exited {limit:g} "
                  f"s later (DDS or executor teardown hung); ending it. Where each thread "
                  f"was:", file=sys.stderr, flush=True)
            faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
            sys.stderr.flush()
        finally:
            bad = getattr(self.node, "diverged", None) or getattr(self.node, "stalled", None)
            os._exit(3 if bad else 0)


class StopFlag:
    """SIGINT / SIGTERM set the flag (the spin loop then shuts down cleanly) instead of
    raising inside a callback; the previous handlers come back with ``restore()``."""

    def __init__(self):
        self.set = False
        self.signum = None
        self._old = {}
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)

    def _handle(self, signum, frame):
        if self.set and signum == signal.SIGINT:      # second Ctrl-C: give up at once
            raise KeyboardInterrupt
        self.set, self.signum = True, signum

    @property
    def signal_name(self) -> str | None:
        """'SIGINT', 'SIGTERM', or None while no signal came."""
        return signal.Signals(self.signum).name if self.signum else None

    def restore(self):
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}


def tell_the_run(node, text: str) -> None:
    """For ``flexarm run``, which started this node as a process: one line of why it
    ended, appended to ``<stop_file>.conflict`` (run.ProcessGraph.conflict)."""
    path = getattr(node, "p", {}).get("stop_file")
    if path:
        try:
            with open(path + ".conflict", "a") as f:
                f.write(f"{node.get_name()}: {text}\n")
        except OSError:
            pass


def stopped_from_outside(stop: StopFlag, node) -> str | None:
    """The name of the signal that stopped a node ``flexarm run`` started as a process
    when the run did not send it (its ``stop_file`` does not exist yet: the run creates it
    before it stops its nodes), else None."""
    path = getattr(node, "p", {}).get("stop_file") if node is not None else None
    if not (stop.set and stop.signum and path) or os.path.exists(path):
        return None
    return signal.Signals(stop.signum).name


def make_executor(context, kind="twin"):
    """The executor of the twin's nodes: ``"twin"`` (default),
    :class:`~flexarm_ros.nodes.executor.TwinExecutor` (rclpy's SingleThreadedExecutor that
    also runs the intra-process bus, where one is installed); ``"single"``, rclpy's
    SingleThreadedExecutor; ``"events"``, rclpy's experimental EventsExecutor (fails on
    callbacks that take a MessageInfo, i.e. on the twin's nodes: kept for measurements)."""
    if kind == "twin":
        from flexarm_ros.nodes.executor import TwinExecutor
        return TwinExecutor(context)
    if kind == "events":
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind != "single":
        raise ValueError(f"executor: got {kind!r}; expected 'twin', 'single' or 'events'")
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor(context=context)


PROFILE_ENV = "FLEXARM_PROFILE_DIR"


class profiled:
    """With ``$FLEXARM_PROFILE_DIR`` set, profile the node's spinning (cProfile) and write
    ``<dir>/<executable>.prof`` (``python -m pstats``): where a node process's CPU goes,
    measured in the run itself. A thread profiles itself: the realtime simulator's pacing
    thread writes ``simulator-pacer.prof``."""

    def __init__(self, name: str):
        import os
        self.path = None
        d = os.environ.get(PROFILE_ENV)
        if d:
            try:
                os.makedirs(d, exist_ok=True)
                self.path = os.path.join(d, f"{name}.prof")
            except OSError as exc:        # a profiling aid never stops a node
                print(f"{name}: {PROFILE_ENV}={d!r}: {exc.strerror or exc}; expected a "
                      f"writable directory (not profiling)", file=sys.stderr)
        self.prof = None

    def __enter__(self):
        if self.path:
            import cProfile
            self.prof = cProfile.Profile()
            self.prof.enable()
        return self

    def __exit__(self, *exc):
        if self.prof is not None:
            self.prof.disable()
            self.prof.dump_stats(self.path)
        return False


def node_main(cls, args=None):
    """``main()`` of a node's process: ``--help``, init, spin until done or stopped, shut
    down, then end the process with the exit status (it does not return): exit handlers
    run and streams are flushed, the interpreter's teardown is skipped (1–2 s per node
    on a loaded machine, mostly DDS and extension modules), so the nodes of a stopped
    graph are gone at once."""
    code = _node_main(cls, args)
    import atexit
    import os
    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):
                pass
        os._exit(code if isinstance(code, int) else 1)


def _node_main(cls, args=None) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args
    argv = list(sys.argv if args is None else args)
    params = {**COMMON, **FIDELITY, **getattr(cls, "PARAMS", {})}
    epilog = "parameters (--ros-args -p name:=value):\n" + "\n".join(
        f"  {k} (default {v[0]!r}): {v[1]}" for k, v in params.items())
    mod_doc = (sys.modules[cls.__module__].__doc__ or "").strip().split("\n\n")
    ap = argparse.ArgumentParser(
        prog=cls.EXECUTABLE, formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(cls.__doc__ or "").strip().splitlines()[0] + "\n\n" +
        "\n\n".join(mod_doc[1:2]),
        epilog=epilog + f"\n\nexample: ros2 run flexarm_ros {cls.EXECUTABLE} --ros-args "
                        "-r __ns:=/flexarm -p scene:=two_link_position -p mode:=realtime")
    ap.parse_args(remove_ros_args(argv)[1:])
    environment.use_loopback()
    ctx = Context()
    rclpy.init(args=argv, context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    from flexarm_ros.nodes.bridge import attach_from_environment
    bus = attach_from_environment(ctx)      # `flexarm run --layout split`'s simulator
    stop = StopFlag()
    node = None
    try:
        from rclpy.exceptions import ParameterException
        try:
            node = cls(context=ctx)
        except (ValueError, OSError, ParameterException) as exc:    # InputError: ValueError
            print(f"{cls.EXECUTABLE}: error: {exc}", file=sys.stderr)
            return 2
        exe = make_executor(ctx)
        exe.add_node(node)
        # a node that need not answer at once (the recorder) pauses between drains: one
        # wake-up takes a batch of messages instead of one (measured: the recorder's CPU
        # per tick at 1 kHz fell from 650 to 360 µs,
        # docs/decisions/0007-realtime-on-two-cores.md)
        pause = float(getattr(node, "spin_pause_s", 0.0))
        with profiled(cls.EXECUTABLE):
            while ctx.ok() and not stop.set and not getattr(node, "finished", False) \
                    and not getattr(node, "conflict", None):
                if pause > 0:
                    exe.spin_ready(timeout_sec=0.1)     # the batch, then the pause
                    time.sleep(pause)
                else:
                    exe.spin_once(timeout_sec=0.1)
        # the node's work is done: from here its exit is bounded (the recorder's from
        # when its bag is finalized, below)
        if not hasattr(node, "close"):
            ShutdownGuard(cls.EXECUTABLE, node)
        outside = stopped_from_outside(stop, node)
        if outside:
            node.stopped_by = outside           # the simulator's summary names it
        if hasattr(node, "finish"):
            node.finish(exe)
        if bus is not None:
            bus.flush()
        exe.shutdown()
        diverged = getattr(node, "diverged", None)
        if diverged is not None:                 # like flexarm simulate: the message, 3
            print(f"{cls.EXECUTABLE}: {diverged}", file=sys.stderr)
            return 3
        if getattr(node, "stalled", None):       # lockstep without answers: the message, 3
            print(f"{cls.EXECUTABLE}: {node.stalled}", file=sys.stderr)
            return 3
        if getattr(node, "conflict", None):      # another twin on this graph: 3
            print(f"{cls.EXECUTABLE}: {node.conflict}", file=sys.stderr)
            tell_the_run(node, node.conflict)
            return 3
        if outside:                              # killed from outside the run: say so
            where = getattr(node, "where", None)
            print(f"{cls.EXECUTABLE}: stopped by {outside} from outside the run"
                  + (f" {where()}" if where else ""), file=sys.stderr)
            return 128 + stop.signum
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        # Shutting down: a further SIGINT/SIGTERM (a second Ctrl-C; the SIGTERM with which
        # `flexarm run --processes` stops nodes that a terminal's Ctrl-C already reached)
        # must neither interrupt the recorder finalizing its bag nor kill the exit. This
        # is the process's main, so they stay ignored until the process ends.
        stop.restore()
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                signal.signal(s, signal.SIG_IGN)
        if node is not None:
            if hasattr(node, "close"):
                node.close()
                ShutdownGuard(cls.EXECUTABLE, node)
            node.destroy_node()
        if ctx.ok():
            rclpy.shutdown(context=ctx)
