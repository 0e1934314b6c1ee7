"""The layers import downwards only (docs/development.md, *Layout*): read from the source, every
``import``/``from`` of the project, lazy ones inside functions included.

    errors   ← nothing of the project
    scene    ← errors
    model    ← scene, errors                 (model.compiled ← model)
    sim      ← model, scene, errors
    analysis, viz: never model/ or sim/ internals (the public ``flexarm_ros.model`` API only)
    nothing  ← cli

and every layer only from the layers before it in :data:`ORDER`. No module imports itself
through others (no import cycle, module- or function-level), and no module imports another
module's ``_private`` name (make it public or move it where it is used).
"""

import ast
import functools
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "flexarm_ros"

# layer -> project packages it may import (besides itself)
ALLOWED = {
    "errors": set(),
    "scene": {"errors"},
    "model": {"scene", "errors"},
    "sim": {"model", "scene", "errors"},
    "testing": set(),
}

#: every layer, lowest first: a layer imports only layers before it (``""`` is the
#: package's own ``__init__``, the version)
ORDER = ("version", "errors", "", "testing", "child_process", "scene", "io", "model", "sim", "control",
         "bag", "twin", "analysis", "estimation", "viz", "ensemble", "studies", "calibration", "nodes",
         "replay", "run", "commands", "api", "cli")

#: (importing module, imported module, name): imports of a ``_private`` name allowed, each
#: with its reason (none today)
PRIVATE_ALLOWED: set[tuple[str, str, str]] = set()


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


@functools.lru_cache(maxsize=None)
def _parsed(path: Path, stamp: tuple[int, int]) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


def _parse(path: Path) -> ast.Module:
    """A file's syntax tree, parsed once per version of the file (the checks below walk
    every source several times)."""
    st = path.stat()
    return _parsed(path, (st.st_mtime_ns, st.st_size))


def _imports(path: Path, module: str | None = None) -> set[str]:
    """Absolute names of the project modules a file imports (relative imports resolved;
    ``module`` is the file's module name, by default from its place in the package)."""
    me = module or _module_name(path)
    found = set()
    for node in ast.walk(_parse(path)):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "flexarm_ros"}
        elif isinstance(node, ast.ImportFrom):
            mod = _resolve(node, me, path)
            if mod.split(".")[0] != "flexarm_ros":
                continue
            # `from flexarm_ros.model import chain` imports the submodule model.chain (as
            # `import flexarm_ros.model.chain` would); the package itself counts when a
            # name is read from its __init__
            subs = {f"{mod}.{a.name}" for a in node.names if _is_module(f"{mod}.{a.name}")}
            found |= subs
            if len(subs) < len(node.names):
                found.add(mod)
    return found


def _resolve(node: ast.ImportFrom, module: str, path: Path) -> str:
    """The absolute module of a ``from … import`` in ``module`` (file ``path``)."""
    if not node.level:
        return node.module or ""
    me = module.split(".")
    package = me if path.name == "__init__.py" else me[:-1]
    base = package[:len(package) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _is_module(name: str) -> bool:
    path = PKG.parent / name.replace(".", "/")
    return path.with_suffix(".py").exists() or path.is_dir()


def _graph(sources) -> dict[str, set[str]]:
    """{module: the project modules it imports} over ``sources`` ({module: path})."""
    return {m: {d for d in _imports(p, m) if d in sources and d != m}
            for m, p in sources.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: one per strongly connected component of more than one
    module (Tarjan), each as a closed path ``[a, b, …, a]`` through it."""
    index, low, stack, on, comps = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(comp)

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return [_path_through(graph, comp) for comp in comps]


def _path_through(graph, comp: set[str]) -> list[str]:
    """A shortest closed path from the component's first module back to it, inside it."""
    start = min(comp)
    prev, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & comp):
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return path[::-1] + [start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return sorted(comp)


def _private_imports(sources) -> list[str]:
    """``module imports _name from other`` for every ``from flexarm_ros… import _name`` (a
    name, module or attribute, that starts with one underscore) of another module, and
    ``module reads other._name`` where ``other`` is a project module it imported."""
    bad = []
    for m, p in sources.items():
        tree = _parse(p)
        bound = {}                   # local name -> the project module it is bound to
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                bound |= {a.asname: a.name for a in node.names
                          if a.asname and a.name.split(".")[0] == "flexarm_ros"}
            if not isinstance(node, ast.ImportFrom):
                continue
            mod = _resolve(node, m, p)
            if mod.split(".")[0] != "flexarm_ros" or mod == m:
                continue
            bound |= {a.asname or a.name: f"{mod}.{a.name}" for a in node.names
                      if f"{mod}.{a.name}" in sources or _is_module(f"{mod}.{a.name}")}
            bad += [f"{m} imports {a.name} from {mod}" for a in node.names
                    if _private(a.name) and (m, mod, a.name) not in PRIVATE_ALLOWED]
        bad += [f"{m} reads {bound[n.value.id]}.{n.attr}" for n in ast.walk(tree)
                if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
                and n.value.id in bound and bound[n.value.id] != m and _private(n.attr)
                and (m, bound[n.value.id], n.attr) not in PRIVATE_ALLOWED]
    return bad


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


SOURCES = sorted(PKG.rglob("*.py"))


def test_the_tree_is_what_this_test_reads():
    assert len(SOURCES) > 50
    assert {_layer(_module_name(p)) for p in SOURCES} >= {
        "errors", "scene", "model", "sim", "studies", "testing", "analysis", "viz", "bag",
        "nodes", "twin", "control", "cli"}


def _violations(layer, forbidden) -> list[str]:
    """``module imports dep`` for every import of a module of ``layer`` that
    ``forbidden(dep)`` refuses."""
    return [f"{_module_name(p)} imports {dep}" for p in SOURCES
            if _layer(_module_name(p)) == layer for dep in _imports(p) if forbidden(dep)]


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_layer_imports_only_the_layers_below(layer):
    bad = _violations(layer, lambda dep: _layer(dep) not in {"", layer, *ALLOWED[layer]})
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("layer", ["analysis", "viz"])
def test_analysis_and_viz_use_only_the_public_model_api(layer):
    bad = _violations(layer, lambda dep: _layer(dep) == "sim"
                      or (_layer(dep) == "model" and len(dep.split(".")) > 2))
    assert not bad, "\n".join(bad)


def test_nothing_imports_the_cli():
    bad = [f"{_module_name(p)} imports {d}" for p in SOURCES for d in _imports(p)
           if d == "flexarm_ros.cli" or d.startswith("flexarm_ros.cli.")]
    assert not bad, "\n".join(bad)


def test_the_checker_sees_a_violation(tmp_path):
    """The reader above resolves relative, lazy and submodule imports (else the layer
    tests could pass on a tree they cannot read)."""
    fake = tmp_path / "probe.py"
    fake.write_text("def f():\n    from ..model import chain\n"
                    "    from flexarm_ros.sim.plant import Plant\n")
    deps = _imports(fake, "flexarm_ros.scene.probe")
    assert {"flexarm_ros.model.chain", "flexarm_ros.sim.plant"} <= deps


# ------------------------------------------------------------------ all layers, no cycles
MODULES = {_module_name(p): p for p in SOURCES}


def test_every_layer_has_its_place_in_the_order():
    missing = {_layer(m) for m in MODULES} - set(ORDER)
    assert not missing, f"layers not in ORDER (place them): {sorted(missing)}"


#: the one import upwards: the package's ``__init__`` hands ``fx.simulate`` and the rest
#: of the Python API on from :mod:`flexarm_ros.api`, on first use (PEP 562 ``__getattr__``)
UPWARD_ALLOWED = {("flexarm_ros", "flexarm_ros.api")}


def _against_order(graph) -> list[str]:
    rank = {layer: i for i, layer in enumerate(ORDER)}
    return [f"{m} ({_layer(m) or 'flexarm_ros'}) imports {d} ({_layer(d) or 'flexarm_ros'})"
            for m, deps in sorted(graph.items()) for d in sorted(deps)
            if _layer(d) != _layer(m) and (m, d) not in UPWARD_ALLOWED
            and rank.get(_layer(d), len(ORDER)) >= rank.get(_layer(m), -1)]


def test_every_layer_imports_only_the_layers_before_it():
    bad = _against_order(_graph(MODULES))
    assert not bad, "imports against ORDER (lowest first):\n" + "\n".join(bad)


def test_no_import_cycle():
    cycles = _cycles(_graph(MODULES))
    assert not cycles, "import cycles (module- and function-level imports):\n" + "\n".join(
        " -> ".join(c) for c in cycles)


def test_no_module_imports_another_modules_private_name():
    bad = _private_imports(MODULES)
    assert not bad, "\n".join(bad)


def _fake_package(tmp_path, files: dict[str, str]) -> dict[str, Path]:
    """{module: path} of a throw-away package ``flexarm_ros.fake`` (``files``: {relative
    path: source})."""
    out = {}
    for rel, text in files.items():
        path = tmp_path / "flexarm_ros" / "fake" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        name = "flexarm_ros.fake." + rel[:-3].replace("/", ".")
        out[name.removesuffix(".__init__")] = path
    return out


def test_the_checks_see_a_cycle_a_private_import_and_an_upward_import(tmp_path):
    """The checks above on a tiny broken tree: a three-module cycle closed by a lazy import,
    a private name taken from another module (imported, and read off the module), and the
    model importing the CLI (so they cannot pass on a graph they fail to read)."""
    fake = _fake_package(tmp_path, {
        "a.py": "from flexarm_ros.fake.b import thing\n",
        "b.py": "import flexarm_ros.fake.c\nthing = 1\n",
        "c.py": "def f():\n    from .a import _hidden\n",
        "d.py": "from flexarm_ros.fake.a import public\n",
        "e.py": "from flexarm_ros.fake import d as D\nD._inside()\nD.public()\n",
    })
    graph = _graph(fake)
    assert graph["flexarm_ros.fake.d"] == {"flexarm_ros.fake.a"}
    assert _cycles(graph) == [["flexarm_ros.fake.a", "flexarm_ros.fake.b",
                               "flexarm_ros.fake.c", "flexarm_ros.fake.a"]]
    assert _private_imports(fake) == [
        "flexarm_ros.fake.c imports _hidden from flexarm_ros.fake.a",
        "flexarm_ros.fake.e reads flexarm_ros.fake.d._inside"]
    # no cycle once the lazy import is gone
    fake["flexarm_ros.fake.c"].write_text("def f():\n    return 0\n")
    assert _cycles(_graph(fake)) == []
    # direction: model (low) importing cli (top), and the reverse that is fine
    assert _against_order({"flexarm_ros.model.chain": {"flexarm_ros.cli"},
                           "flexarm_ros.cli": {"flexarm_ros.model.chain"}}) == [
        "flexarm_ros.model.chain (model) imports flexarm_ros.cli (cli)"]
