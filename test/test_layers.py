"""The layers import downwards only (README, Development): read from the source, every
``import``/``from`` of the project, lazy ones inside functions included.

    errors   ← nothing of the project
    scene    ← errors
    model    ← scene, errors                 (model.compiled ← model)
    sim      ← model, scene, errors
    analysis, viz: never model/ or sim/ internals (the public ``flexarm_ros.model`` API only)
    nothing  ← cli
"""

import ast
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


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path, module: str | None = None) -> set[str]:
    """Absolute names of the project modules a file imports (relative imports resolved;
    ``module`` is the file's module name, by default from its place in the package)."""
    me = (module or _module_name(path)).split(".")
    package = me if path.name == "__init__.py" else me[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "flexarm_ros"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
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


def _is_module(name: str) -> bool:
    path = PKG.parent / name.replace(".", "/")
    return path.with_suffix(".py").exists() or path.is_dir()


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
