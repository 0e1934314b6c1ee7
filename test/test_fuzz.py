"""Fuzz: hostile scenes and command lines end in one clear line, never in a traceback, a
hang or a non-finite number in a file (issue 12).

Every shipped scene is mutated one key at a time (a number to 0, negative, 1e-12, 1e12,
nan, inf, a string, a list; a string to '', 'a,b', a number, null; a key deleted; an
unknown key added) and run through the ``flexarm`` command (``simulate``, or ``modes`` /
``linearize`` / ``explain`` for some cases) in a worker process
(:mod:`fuzz_worker`) under a wall-clock limit per case; misused command-line options are
run the same way. Every outcome must be one of:

* exit 0, and every CSV written holds finite numbers only;
* exit 2 with exactly one line on stderr naming the mutated key path (or option), the
  offending value and the expectation;
* exit 3 (the simulation diverged) with one line saying what diverged, when, and "To fix".

The cases are seeded (a failure names its case and is reproduced by rerunning it). The
fast suite runs a sample of a few hundred; ``-m slow`` runs every mutation of every scene.
The base scenes are shortened to ten output periods and get ``fidelity.max_steps`` 5e4 so a
collapsed step is refused in milliseconds (the budget, :mod:`flexarm_ros.sim.budget`).
"""

from __future__ import annotations

import json
import math
import os
import random
import re
import select
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from flexarm_ros.scene.loading import config_dir, shipped_scenes

HERE = Path(__file__).resolve().parent
WORKER = HERE / "fuzz_worker.py"
CASE_LIMIT_S = 30.0        # longer than this is a hang (the slowest legitimate case: ~3 s)
START_LIMIT_S = 180.0      # the first case of a worker also loads numba's compiled kernels
FUZZ_MAX_STEPS = 5e4       # the base scenes' work budget
SEED = 12
FAST_SCENE_CASES = 300
FAST_CLI_CASES = 100

NUMBER_MUTATIONS = [("zero", 0), ("negative", None), ("tiny", 1e-12), ("huge", 1e12),
                    ("nan", math.nan), ("inf", math.inf), ("string", "fuzz"),
                    ("list", [1.0, 2.0])]
STRING_MUTATIONS = [("empty", ""), ("comma", "a,b"), ("number", 5), ("null", None)]
BOOL_MUTATIONS = [("string", "yes"), ("number", 2)]


# ----------------------------------------------------------------------------- worker
class Worker:
    """One ``fuzz_worker`` process; a case past its limit kills it (a hang) and the next
    case starts a new one."""

    def __init__(self, cwd):
        self.proc = None
        self.fresh = True
        self.cwd = cwd

    def _start(self):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            [str(HERE.parent)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        self.proc = subprocess.Popen([sys.executable, str(WORKER)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, env=env, cwd=self.cwd)
        self.fresh = True

    def run(self, argv, scan=None) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        limit = START_LIMIT_S if self.fresh else CASE_LIMIT_S
        self.fresh = False
        self.proc.stdin.write(json.dumps({"argv": [str(a) for a in argv],
                                          "scan": str(scan) if scan else None}) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], limit)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.close()
            return {"hang": True, "limit_s": limit}
        return json.loads(line)

    def close(self):
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()
            self.proc.stdin.close()
            self.proc.stdout.close()
            self.proc = None


@pytest.fixture(scope="module")
def worker(tmp_path_factory):
    w = Worker(tmp_path_factory.mktemp("fuzz_cwd"))      # default outputs (run.mcap) land here
    yield w
    w.close()


# ------------------------------------------------------------------------------ cases
def key_path(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _leaves(node, path=()):
    """(path, value) of every key and list element of a parsed scene."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield path + (k,), v
            yield from _leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield path + (i,), v
            yield from _leaves(v, path + (i,))


def base_scene(name) -> dict:
    data = yaml.safe_load((config_dir() / f"{name}.yaml").read_text(encoding="utf-8"))
    fid = data.setdefault("fidelity", {})
    data["duration"] = 10 * fid.get("output_dt", 1e-3)
    fid["max_steps"] = FUZZ_MAX_STEPS
    return data


def scene_cases() -> list[tuple]:
    """(case id, scene, path, kind, value); kind "set" / "delete" / "unknown"."""
    cases = []
    for name in shipped_scenes():
        data = base_scene(name)
        for path, value in _leaves(data):
            if path[0] in ("assumptions", "description", "source"):
                continue
            where = key_path(path)
            if isinstance(path[-1], str):
                cases.append((f"{name}:{where}:delete", name, path, "delete", None))
            if isinstance(value, bool):
                muts = BOOL_MUTATIONS
            elif isinstance(value, (int, float)):
                muts = [(m, (-abs(value) if value else -1.0) if v is None else v)
                        for m, v in NUMBER_MUTATIONS]
            elif isinstance(value, str):
                muts = STRING_MUTATIONS
            elif isinstance(value, dict):
                cases.append((f"{name}:{where}:unknown", name, path + ("fuzz_key",),
                              "unknown", 1.0))
                continue
            else:
                continue
            for m, v in muts:
                cases.append((f"{name}:{where}:{m}", name, path, "set", v))
        cases.append((f"{name}:fuzz_key:unknown", name, ("fuzz_key",), "unknown", 1.0))
    return cases


def mutated(name, path, kind, value) -> dict:
    data = base_scene(name)
    node = data
    for p in path[:-1]:
        node = node[p]
    if kind == "delete":
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


def value_forms(value) -> list[str]:
    """How a message may write ``value`` back."""
    if isinstance(value, bool) or value is None or isinstance(value, (str, list)):
        return [repr(value), str(value), json.dumps(value)]
    forms = {repr(value), str(value), f"{value:g}", f"{value:.3g}", f"{value:.6g}"}
    if isinstance(value, float) and value.is_integer():
        forms.add(str(int(value)))
    return sorted(forms)


#: a scene key path with its value or a missing-field note in a message
KEY_IN_MESSAGE = re.compile(r"[A-Za-z_]+(\[\d+\])*(\.[A-Za-z_]+(\[\d+\])*)*: (got|missing)")


def key_forms(key: str) -> list[str]:
    """The key path, or for a list element the list's key (``times[2]`` → ``times``: a
    message about the list shows the element among its values)."""
    forms = [key]
    while forms[-1].endswith("]"):
        forms.append(forms[-1][:forms[-1].rindex("[")])
    return forms


def stderr_lines(err: str) -> list[str]:
    """The lines a terminal shows: the progress line's carriage-return rewrites dropped."""
    lines = []
    for raw in err.split("\n"):
        shown = raw.split("\r")[-1].strip()
        if shown:
            lines.append(shown)
    return lines


def judge(answer, key=None, value=None, kind="set") -> list[str]:
    """The problems of one outcome (empty: it is one of the accepted ones)."""
    if answer.get("hang"):
        return [f"no answer within {answer['limit_s']:g} s (a hang)"]
    problems = []
    if answer["traceback"]:
        problems.append("traceback: " + answer["traceback"].strip().splitlines()[-1])
    code = answer["code"]
    if code not in (0, 2, 3):
        problems.append(f"exit {code}")
    if answer["nonfinite"]:
        problems.append(f"non-finite values written: {answer['nonfinite']}")
    lines = stderr_lines(answer["err"])
    if code in (2, 3):
        if len(lines) != 1:
            problems.append(f"{len(lines)} lines on stderr: {lines}")
        text = " ".join(lines)
        if code == 3 and not ("To fix:" in text and ("diverged" in text
                                                     or "step refused" in text)):
            problems.append(f"exit 3 without what diverged and the fix: {text}")
        if code == 2:
            if kind == "delete":
                # the deleted key, or the key that needed it (a cross-field rule)
                if key not in text and not KEY_IN_MESSAGE.search(text):
                    problems.append(f"deleting {key}: the message names no key: {text}")
            elif key is not None and not any(k in text for k in key_forms(key)):
                problems.append(f"the message does not name {key}: {text}")
            if kind == "set" and value is not None and not any(
                    f in text for f in value_forms(value)):
                problems.append(f"the message does not show the value {value!r}: {text}")
            if "expected" not in text:
                problems.append(f"no expectation: {text}")
    return problems


COMMANDS = ["simulate"] * 7 + ["modes", "linearize", "explain"]


def scene_argv(case_id, path, tmp) -> list:
    command = COMMANDS[sum(map(ord, case_id)) % len(COMMANDS)]
    if command == "simulate":
        return ["simulate", path, "--quiet", "--out", tmp / "run.csv"]
    if command == "modes":
        return ["modes", path, "--count", "3"]
    if command == "linearize":
        return ["linearize", path, "--json"]
    return ["explain", path, "--no-check"]      # the check is simulate --estimate's run


def run_scene_cases(cases, worker, tmp_path):
    failures, codes = [], {}
    for k, (case_id, name, path, kind, value) in enumerate(cases):
        d = tmp_path / f"c{k}"
        d.mkdir()
        scene = d / f"{name}.yaml"
        scene.write_text(yaml.safe_dump(mutated(name, path, kind, value)), encoding="utf-8")
        ans = worker.run(scene_argv(case_id, scene, d), scan=d)
        code = "hang" if ans.get("hang") else ans["code"]
        codes[code] = codes.get(code, 0) + 1
        problems = judge(ans, key_path(path), value, kind)
        if problems:
            failures.append(f"{case_id}: " + "; ".join(problems))
    return failures, codes


def _report(what, n, codes, failures):
    print(f"\n{what}: {n} cases, exits {dict(sorted(codes.items(), key=str))}, "
          f"{len(failures)} failures")


def test_scene_case_list_covers_every_shipped_scene():
    cases = scene_cases()
    assert {c[1] for c in cases} == set(shipped_scenes())
    assert len(cases) > 3000
    kinds = {c[3] for c in cases}
    assert kinds == {"set", "delete", "unknown"}


@pytest.mark.heavy
@pytest.mark.subprocess
def test_fuzz_scenes_sample(worker, tmp_path):
    cases = random.Random(SEED).sample(scene_cases(), FAST_SCENE_CASES)
    failures, codes = run_scene_cases(cases, worker, tmp_path)
    _report("scene fuzz (sample)", len(cases), codes, failures)
    assert not failures, "\n".join(failures)
    assert codes.get(0, 0) > 0 and codes.get(2, 0) > 0      # both paths exercised


@pytest.mark.slow
@pytest.mark.subprocess
def test_fuzz_scenes_all(worker, tmp_path):
    cases = scene_cases()
    failures, codes = run_scene_cases(cases, worker, tmp_path)
    _report("scene fuzz (all)", len(cases), codes, failures)
    assert not failures, "\n".join(failures[:200])


# ----------------------------------------------------------------------- command lines
BAD_NUMBERS = ["nan", "inf", "-inf", "-1", "0", "1e300", "abc", ""]


def cli_cases(tmp) -> list[tuple]:
    """(case id, argv, option named in the message or None, value or None)."""
    tmp = Path(tmp)
    (tmp / "a_dir").mkdir(exist_ok=True)
    (tmp / "a_file").write_text("x")
    (tmp / "latin1.yaml").write_bytes("name: caf\xe9\n".encode("latin-1"))
    (tmp / "broken.yaml").write_text("name: [x\nlinks: {\n")
    (tmp / "list.yaml").write_text("- 1\n- 2\n")
    bag = small_bag(tmp / "small.mcap")
    csv = HERE.parent / "bags" / "synthetic_experiment_case1.csv"
    cases = []
    numeric = {
        "simulate": ["--duration", "--dt", "--rtol", "--atol", "--refine", "--max-steps"],
        "modes": ["--count", "--refine", "--dt"],
        "linearize": ["--refine", "--rtol"],
        "explain": ["--refine", "--max-steps"],
        "study": ["--duration"],
        "run": ["--duration", "--dt", "--refine"],
        "compare": ["--threshold", "--max-shift", "--offset"],
        "replay": ["--rate", "--delay", "--shape-rate", "--samples", "--force-scale"],
    }
    for cmd, opts in numeric.items():
        for opt in opts:
            for v in BAD_NUMBERS:
                if (cmd, opt, v) == ("run", "--duration", "inf"):
                    continue                    # documented: until Ctrl-C
                given = f"{opt}={v}"            # '-inf' would read as an option
                if cmd == "compare":
                    argv = [cmd, bag, csv, given]
                elif cmd == "replay":
                    argv = [cmd, bag, "--rerun", tmp / "o.rrd", given]
                else:
                    argv = [cmd, "link", given] + (["--quiet"] if cmd == "simulate" else [])
                    if cmd == "explain":
                        argv += ["--no-check"]      # the check is simulate --estimate's
                    if cmd in ("simulate", "run") and opt != "--duration":
                        argv += ["--duration", "0.01"]          # a valid case stays short
                    if cmd == "run":
                        argv += ["--no-record", "--quiet"]
                cases.append((f"{cmd} {opt} {v!r}", argv, opt, v))
    paths = {"a directory": tmp / "a_dir", "a missing parent": tmp / "nope" / "x",
             "an unwritable place": Path("/proc/flexarm_fuzz/x"),
             "a file as parent": tmp / "a_file" / "x"}
    for what, p in paths.items():
        for cmd, opt, suffix, extra in [
                ("simulate", "--out", ".csv", ["link", "--duration", "0.01", "--quiet"]),
                ("linearize", "--out", ".npz", ["link"]),
                ("study", "--png", ".png", ["link", "--quick"]),
                ("run", "--record", ".mcap", ["link", "--duration", "0.01"]),
                ("run", "--rerun", ".rrd", ["link", "--duration", "0.01"]),
                ("replay", "--rerun", ".rrd", [bag]),
                ("compare", "--report", "", [bag, csv])]:
            target = p if what == "a directory" else Path(str(p) + suffix)
            cases.append((f"{cmd} {opt} {what}", [cmd, *extra, opt, target], opt, None))
    for ns in ["1abc", "/a//b", "/a/", "a b", "/ä", "/a-b", "~/x", "/" + "n" * 250]:
        cases.append((f"run --namespace {ns[:12]!r}", ["run", "link", "--namespace", ns,
                                                        "--duration", "0.01"], "--namespace",
                      ns))
        cases.append((f"replay --namespace {ns[:12]!r}", ["replay", bag, "--namespace", ns,
                                                           "--rate", "0"], "--namespace", ns))
    for what, scene in [("latin-1", "latin1.yaml"), ("broken YAML", "broken.yaml"),
                        ("a list", "list.yaml"), ("a directory", "a_dir"),
                        ("missing", "no_such_scene")]:
        for cmd in ("simulate", "modes", "linearize", "explain", "study", "run"):
            cases.append((f"{cmd} scene {what}", [cmd, tmp / scene], None, None))
    for cmd in ("simulate", "modes", "run", "replay", "compare", "study"):
        cases.append((f"{cmd} --no-such-option", [cmd, "--no-such-option"], None, None))
    cases.append(("modes --joints bad", ["modes", "link", "--joints", "bad"], None, None))
    cases.append(("simulate --rung bad", ["simulate", "link", "--rung", "bad"], None, None))
    cases.append(("replay missing bag", ["replay", tmp / "none.mcap"], None, None))
    cases.append(("replay not a bag", ["replay", tmp / "a_file", "--rerun", tmp / "o.rrd"],
                  None, None))
    cases.append(("compare missing", ["compare", tmp / "none.mcap", csv], None, None))
    return cases


def small_bag(path, seconds=0.1):
    """The golden bag's first ``seconds`` (its metadata too): replay cases stay cheap."""
    from flexarm_ros.bag import read_bag, to_dict
    from flexarm_ros.bag.writer import BagWriter
    if path.exists():
        return path
    bag = read_bag(HERE.parent / "bags" / "golden_case1.mcap")
    items = sorted(((t, topic, m) for topic in bag.topics for t, m in bag[topic]
                    if t <= seconds * 1e9), key=lambda item: item[:2])
    with BagWriter(path) as w:
        for name, data in bag.metadata.items():
            if name != "rosbag2":
                w.add_metadata(name, data)
        for t, topic, m in items:
            w.write(topic, bag.types[topic], to_dict(m), t)
    return path


def judge_cli(ans, option, value) -> list[str]:
    """As :func:`judge`; exit 1 is also accepted (compare: the check failed) and an exit 2
    must name the option (or its key) and show the value."""
    if not ans.get("hang") and ans["code"] == 1:
        ans = dict(ans, code=0)
    problems = judge(ans)
    if problems or ans["code"] != 2:
        return problems
    text = " ".join(stderr_lines(ans["err"]))
    if option is not None and option not in text and option.lstrip("-").replace(
            "-", "_") not in text:
        problems.append(f"the message does not name {option}: {text}")
    if value not in (None, "") and not any(f in text for f in (value, repr(value))):
        try:
            forms = value_forms(float(value))
        except ValueError:
            forms = []
        if not any(f in text for f in forms):
            problems.append(f"the message does not show {value!r}: {text}")
    return problems


def run_cli_cases(cases, worker):
    failures, codes = [], {}
    for case_id, argv, option, value in cases:
        ans = worker.run(argv)
        code = "hang" if ans.get("hang") else ans["code"]
        codes[code] = codes.get(code, 0) + 1
        problems = judge_cli(ans, option, value)
        if problems:
            failures.append(f"{case_id}: " + "; ".join(problems))
    return failures, codes


def _cheap(case) -> bool:
    """Cases that fail before any long work (a valid study / run would take minutes)."""
    _, argv, option, value = case
    return not (argv[0] in ("study", "run", "replay", "compare") and value in ("1e300",))


@pytest.mark.heavy
@pytest.mark.subprocess
def test_fuzz_command_lines(worker, tmp_path):
    cases = [c for c in cli_cases(tmp_path) if _cheap(c)]
    sample = random.Random(SEED).sample(cases, min(FAST_CLI_CASES, len(cases)))
    failures, codes = run_cli_cases(sample, worker)
    _report("command-line fuzz (sample)", len(sample), codes, failures)
    assert not failures, "\n".join(failures)


@pytest.mark.slow
@pytest.mark.subprocess
def test_fuzz_command_lines_all(worker, tmp_path):
    cases = [c for c in cli_cases(tmp_path) if _cheap(c)]
    failures, codes = run_cli_cases(cases, worker)
    _report("command-line fuzz (all)", len(cases), codes, failures)
    assert not failures, "\n".join(failures)


# ---------------------------------------------------------- the new ground of issue 39
#: YAML structures a file may hold (test_yaml_input.py has the loader's own cases)
YAML_STRUCTURES = {
    "alias bomb": ('a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x", "x"]\n'
                   + "".join(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]\n"
                             for i in range(1, 10)) + "links: *a9\n"),
    "deep nesting": "links: " + "[" * 5000 + "]" * 5000 + "\n",
    "duplicate key": "duration: 1.0\nlinks: []\nduration: 2.0\n",
    "huge string": "name: " + "x" * 2_000_000 + "\nlinks: []\n",
    "non-UTF-8": None,                       # latin-1 bytes, written below
    "empty": "",
}


def new_ground_cases(tmp) -> list[tuple]:
    """Issue 39's inputs: YAML structure for every command that reads YAML (scene, spec,
    calibration spec, channel map), the ensemble commands' numbers, seeds, workers and
    scheduler, and bag repair's input and output. (case id, argv, option, value), as
    :func:`cli_cases`; valid values are kept cheap (serial, 2 samples, 0.01 s)."""
    tmp = Path(tmp)
    cases = []
    files = {}
    for what, text in YAML_STRUCTURES.items():
        p = tmp / f"yaml_{what.replace(' ', '_').replace('-', '_')}.yaml"
        if text is None:
            p.write_bytes("name: caf\xe9\nlinks: []\n".encode("latin-1"))
        else:
            p.write_text(text)
        files[what] = p
    bag = small_bag(tmp / "small.mcap")
    csv = HERE.parent / "bags" / "synthetic_experiment_case1.csv"
    for what, p in files.items():
        for argv in (["simulate", p, "--quiet"], ["explain", p, "--no-check"],
                     ["uncertainty", p],
                     ["sensitivity", p, "--quiet"], ["calibrate", "--spec", p],
                     ["compare", bag, csv, "--map", p]):
            cases.append((f"{argv[0]} {what}", argv, None, None))
    sweep = ["sweep", "link", "--param", "links[0].beam.EI=1:2", "--duration", "0.01"]
    spec = tmp / "uq.yaml"
    spec.write_text("scene: link\nduration: 0.01\nunknowns:\n  - name: EI\n"
                    "    key: links[0].beam.EI\n    dist: uniform\n    low: 1.0\n"
                    "    high: 2.0\n")
    for opt in ("--samples", "--seed", "--workers"):
        for v in BAD_NUMBERS + ["-5", "1000", "2.5", "4294967296"]:
            rest = {"--samples": ["--seed", "0", "--workers", "0"],
                    "--seed": ["--samples", "2", "--workers", "0"],
                    "--workers": ["--samples", "2", "--seed", "0"]}[opt]
            for head in (sweep, ["uncertainty", spec], ["sensitivity", spec, "--quiet"]):
                if opt == "--samples" and v == "1000":
                    # a valid 1000-run study: minutes (uncertainty, sensitivity), and a
                    # sweep's 1000 runs took over the case's 30 s beside a loaded host;
                    # a valid large sample is the 200 below
                    continue
                cases.append((f"{head[0]} {opt} {v!r}", [*head, f"{opt}={v}", *rest],
                              opt, v))
    cases.append(("sweep --samples '200'", [*sweep, "--samples=200", "--seed", "0",
                                             "--workers", "0"], "--samples", "200"))
    for addr in ("garbage", "tcp://host", "tcp://127.0.0.1:99999", "nope://1.2.3.4:1"):
        cases.append((f"sweep --scheduler {addr!r}",
                      [*sweep, "--samples", "2", "--scheduler", addr], "--scheduler", addr))
    (tmp / "b_dir").mkdir(exist_ok=True)
    (tmp / "b_file").write_text("not a bag")
    for what, argv in {"missing bag": ["bag", "repair", tmp / "none.mcap"],
                       "a directory": ["bag", "repair", tmp / "b_dir"],
                       "not a bag": ["bag", "repair", tmp / "b_file"],
                       "--out missing DIR/": ["bag", "repair", bag, "--out",
                                              f"{tmp / 'no_dir'}/"],
                       "--out unwritable": ["bag", "repair", bag, "--out",
                                            "/proc/flexarm_fuzz/x.mcap"],
                       "--out the input": ["bag", "repair", bag, "--out", bag]}.items():
        cases.append((f"bag repair {what}", argv, None, None))
    return cases


@pytest.mark.heavy
@pytest.mark.subprocess
def test_fuzz_new_ground(worker, tmp_path):
    """Every case of :func:`new_ground_cases` ends clean: exit 0 with finite output, or
    one line (exit 2 naming the option and the value, or 3), never a traceback or a hang."""
    cases = new_ground_cases(tmp_path)
    failures, codes = run_cli_cases(cases, worker)
    _report("issue 39's new ground", len(cases), codes, failures)
    assert not failures, "\n".join(failures)
