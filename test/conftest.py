"""Suite-wide settings.

* DDS on loopback and a private ROS domain per test run — and, under pytest-xdist
  (``-n``), one domain per worker, so the workers' graphs never hear each other.
* Markers for what is slow to set up, so a developer can leave it out of the inner loop
  (README, Development): ``ros`` (the test opens a ROS 2 context in its own process),
  ``subprocess`` (it starts a child process: a twin in processes, a CLI, a build),
  ``heavy`` (a numerical study or long run, over ~2 s on a 2-core host), ``slow`` (long
  studies CI leaves out). A test carrying none of them is marked ``quick``:
  ``python -m pytest -m "quick and not extended"`` is the inner loop.
* ``extended``: the tests listed in ``test/extended.txt`` (1.5 s or more each, measured):
  the README's test command (``-m "not slow and not extended"``) leaves them out to stay
  within 5 minutes on 2 cores beside other work, and ``.ci/run`` runs them after it. A
  file whose every test is listed, or an entry that names no collected test of its file,
  stops the collection.
* The ``ros`` and ``subprocess`` markers are kept true: a test that opens a ROS context or
  starts a process without its marker fails and says which marker to add, so the inner
  loop never grows a ROS graph or a child process unnoticed.
* A worker that dies of a fatal signal (a segfault in a native library) has its
  ``faulthandler`` dump, the crashing thread first, printed in the run's summary under
  "fatal error in worker gwN": xdist's own report says only that the worker crashed, and
  the dump it relays scrolls far above the summary.
"""

import faulthandler
import os
import shutil
import subprocess
import tempfile

import numpy as np
import pytest

from flexarm_ros.nodes import environment

SET_UP = ("ros", "subprocess", "heavy", "slow")


def _worker_domain() -> None:
    """Under xdist, worker ``gwN`` takes the run's domain shifted by N + 1 (mod the valid
    range), so parallel workers of one run, and the run's controller, differ."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw"):
        return
    environment.private_graph(pid=os.getppid())      # the run's domain (the controller's)
    base = int(os.environ[environment.DOMAIN])
    os.environ[environment.DOMAIN] = str(1 + (base + int(worker[2:])) % environment.DOMAINS)


_worker_domain()
environment.private_graph()


CRASH_DIR = "FLEXARM_TEST_CRASH_DIR"


def pytest_configure(config):
    if getattr(config.option, "numprocesses", None) and CRASH_DIR not in os.environ:
        # the controller of an xdist run: its workers (spawned later) inherit the folder
        os.environ[CRASH_DIR] = tempfile.mkdtemp(prefix="flexarm_crash_")
        config.add_cleanup(lambda: shutil.rmtree(os.environ.pop(CRASH_DIR), True))
    for line in (
            "slow: long studies (CI runs -m 'not slow'; run them with -m slow)",
            "ros: opens a ROS 2 context (rclpy) in the test's process",
            "subprocess: starts a child process (a twin in processes, a CLI, a build)",
            "heavy: a numerical study or long run (over ~2 s on a 2-core host)",
            "quick: none of ros, subprocess, heavy, slow (added by conftest): the inner "
            "loop",
            "extended: listed in test/extended.txt (added by conftest): 1.5 s or more; the "
            "README's test command leaves them out, .ci/run runs them after it"):
        config.addinivalue_line("markers", line)


def pytest_sessionstart(session):
    """In an xdist worker: fatal-signal dumps go to a file of the run's crash folder (after
    pytest's faulthandler plugin set stderr, which a crash report scrolls away)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker and os.environ.get(CRASH_DIR):
        fd = os.open(os.path.join(os.environ[CRASH_DIR], f"{worker}.txt"),
                     os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        faulthandler.enable(file=fd, all_threads=True)   # open until the worker exits


def pytest_terminal_summary(terminalreporter):
    """The controller prints every dump a worker left: the crashing thread comes first."""
    folder = os.environ.get(CRASH_DIR)
    if os.environ.get("PYTEST_XDIST_WORKER") or not folder or not os.path.isdir(folder):
        return
    for name in sorted(os.listdir(folder)):
        with open(os.path.join(folder, name), errors="replace") as f:
            lines = f.read().splitlines()
        if lines:
            terminalreporter.write_sep("=", f"fatal error in worker {name[:-4]}")
            for line in lines[:60]:
                terminalreporter.write_line(line)


EXTENDED_LIST = os.path.join(os.path.dirname(__file__), "extended.txt")


def _extended() -> set:
    """The node ids of test/extended.txt (its comments and the figures after ``#`` left)."""
    with open(EXTENDED_LIST) as f:
        return {line.split("#")[0].strip() for line in f
                if line.split("#")[0].strip()}


@pytest.hookimpl(tryfirst=True)      # before -m deselects: every collected test is seen
def pytest_collection_modifyitems(items):
    extended = _extended()
    seen, files = set(), {}
    for item in items:
        if not any(item.get_closest_marker(m) for m in SET_UP):
            item.add_marker(pytest.mark.quick)
        nodeid = item.nodeid
        fast = True
        if nodeid in extended:
            item.add_marker(pytest.mark.extended)
            seen.add(nodeid)
            fast = False
        if not item.get_closest_marker("slow"):
            path = nodeid.split("::")[0]
            files[path] = files.get(path, False) or fast
    stale = sorted(n for n in extended - seen if n.split("::")[0] in files)
    starved = sorted(f for f, has_fast in files.items() if not has_fast)
    if stale or starved:
        raise pytest.UsageError(
            "test/extended.txt: " + "; ".join(
                ([f"names no collected test: {', '.join(stale)}"] if stale else []) +
                ([f"leaves no test of {', '.join(starved)} in the fast suite (keep its "
                  f"cheapest one there)"] if starved else [])))


class _Seen:
    """What the running test (its set-up, call and tear-down) started: ROS contexts and
    child processes (``subprocess`` and ``multiprocessing``: a Dask local cluster's
    workers count)."""
    ros = 0
    processes = 0


def _count(owner, name, field):
    original = getattr(owner, name)

    def counted(self, *args, **kwargs):
        setattr(_Seen, field, getattr(_Seen, field) + 1)
        return original(self, *args, **kwargs)
    setattr(owner, name, counted)


def _count_what_tests_start():
    import multiprocessing.process
    _count(subprocess.Popen, "__init__", "processes")
    _count(multiprocessing.process.BaseProcess, "start", "processes")
    try:
        from rclpy.context import Context
    except ImportError:                  # no rclpy: no test can open a context
        return
    _count(Context, "init", "ros")


_count_what_tests_start()


#: Shared fixtures (module or session scope) that opened a ROS context or started a
#: process when they were set up, by name: every test using one needs its marker, not only
#: the test that happened to set it up first on this worker.
_SHARED_FIXTURES: dict[str, set[str]] = {}


@pytest.hookimpl(hookwrapper=True)
def pytest_fixture_setup(fixturedef, request):
    before = (_Seen.ros, _Seen.processes)
    yield
    if fixturedef.scope != "function":
        kinds = {m for m, b, a in (("ros", before[0], _Seen.ros),
                                   ("subprocess", before[1], _Seen.processes)) if a > b}
        if kinds:
            _SHARED_FIXTURES.setdefault(fixturedef.argname, set()).update(kinds)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _Seen.ros = _Seen.processes = 0


def needed_markers(item) -> list[str]:
    """The set-up markers the test's run showed it needs: what it (or its function
    fixtures) opened, plus what its shared fixtures opened when they were set up."""
    kinds = {m for m, n in (("ros", _Seen.ros), ("subprocess", _Seen.processes)) if n}
    for name in getattr(item, "fixturenames", ()):
        kinds |= _SHARED_FIXTURES.get(name, set())
    return sorted(kinds)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Fail a test that opened a ROS context or started a process without the marker
    that says so (see the module doc): its tear-down report turns failed, naming the
    marker (failing the report, not raising, keeps pytest's set-up state intact)."""
    outcome = yield
    if call.when != "teardown":
        return
    missing = [m for m in needed_markers(item) if not item.get_closest_marker(m)]
    report = outcome.get_result()
    if missing and report.passed:
        report.outcome = "failed"
        report.longrepr = (
            f"{item.nodeid} opened {_Seen.ros} ROS context(s) and started "
            f"{_Seen.processes} process(es) (its shared fixtures included): mark it "
            + " and ".join(f"@pytest.mark.{m}" for m in missing) + " (test/conftest.py)")


def _ros_against_batch(scene_path, bag_path, duration: float, namespace: str):
    """(messages recorded, largest |q_ros − q_batch| rad over every joint and tick, the
    largest joint travel in the run rad) of a lockstep ``flexarm run`` of ``scene_path``
    recorded to ``bag_path``."""
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.run import run
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.batch import run_scene
    run(str(scene_path), duration, "lockstep", record=bag_path, namespace=namespace,
        progress=False)
    msgs = read_bag(bag_path)[f"{namespace}/{T.GT_JOINT_STATES}"]
    scene = load_scene(scene_path)
    res = run_scene(scene, duration)
    ns = np.round(np.asarray(res.columns["t"]) * 1e9).astype(np.int64)
    idx = np.searchsorted(ns, np.array([ts for ts, _ in msgs], dtype=np.int64))
    gap = travel = 0.0
    for j, lk in enumerate(scene.links):
        q = np.array([m.position[j] for _, m in msgs])
        gap = max(gap, float(np.max(np.abs(np.asarray(res.columns[f"{lk.name}_joint"])[idx]
                                           - q))))
        travel = max(travel, float(np.ptp(q)))
    return len(msgs), gap, travel


@pytest.fixture
def ros_against_batch():
    """A lockstep ROS run of a scene beside its batch run ("one system"):
    ``ros_against_batch(scene_path, bag_path, duration, namespace)`` → (messages recorded,
    largest |q_ros − q_batch| rad over every joint and tick of ground_truth/joint_states,
    the largest joint travel rad)."""
    return _ros_against_batch


#: the options of ``flexarm run`` that choose each kept layout
LAYOUT_ARGS = {"one": [], "split": ["--layout", "split"], "processes": ["--processes"]}


class RosClient:
    """A plain rclpy user in the test's process (its own context, one node, one
    executor): what ``ros2 topic echo`` or ``ros2 param`` would be."""

    def __init__(self, name: str):
        import rclpy
        import flexarm_ros.nodes.common  # noqa: F401  (loads message support quietly)
        from rclpy.executors import SingleThreadedExecutor
        self.rclpy, self.context = rclpy, rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_once(self, timeout_sec: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout_sec)

    def call(self, srv_type, name: str, request, timeout: float = 30.0):
        """The response of service ``name`` to ``request`` (asserting it answers)."""
        import time
        client = self.node.create_client(srv_type, name)
        try:
            deadline = time.monotonic() + timeout
            while not client.wait_for_service(timeout_sec=0.5):
                assert time.monotonic() < deadline, f"{name}: no service within {timeout} s"
            future = client.call_async(request)
            self.executor.spin_until_future_complete(future, timeout_sec=timeout)
            assert future.done(), f"{name}: no answer within {timeout} s"
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


@pytest.fixture
def ros_client():
    """``ros_client(name)`` → a :class:`RosClient`, shut down after the test."""
    made = []

    def make(name: str) -> RosClient:
        made.append(RosClient(name))
        return made[-1]
    yield make
    for client in made:
        client.close()


@pytest.fixture
def twin_process():
    """``twin_process(scene, *options, layout="one")`` → the Popen of ``flexarm run scene
    options`` in a child (stderr piped), stopped after the test if it still runs."""
    import sys
    procs = []

    def start(scene: str, *options: str, layout: str = "one"):
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "flexarm_ros.cli", "run", scene, *options,
             *LAYOUT_ARGS[layout]], env=environment.child_environment(),
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
        return procs[-1]
    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate(timeout=10)
