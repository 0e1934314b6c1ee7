"""The package uses rclpy's public API only (issue 38): no module of rclpy's private
bindings (``rclpy.impl``, ``_rclpy``, ``rclpy._*``) is imported anywhere in the package,
the benches or the examples, and no private member of rclpy's classes is read (the
executor's generator, a subscription's callback type, a guard condition's state...).
The former lean executor had waited on ``_rclpy.WaitSet`` with positional counts, which
tied the package to rclpy 9.1."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for d in ("flexarm_ros", "bench", "examples")
                 for p in (ROOT / d).rglob("*.py"))

#: members rclpy marks private (leading underscore) that code reaching into rclpy's
#: executors, entities or contexts would read; our own classes do not use these names
RCLPY_PRIVATE_MEMBERS = {
    "_callback_type", "_executor_triggered", "_executor_event", "_cb_iter", "_last_args",
    "_wait_for_ready_callbacks", "_take_subscription", "_take_timer", "_take_service",
    "_take_client", "_take_guard_condition", "_take_waitable", "_make_handler",
    "_spin_once_impl", "_guard", "_sigint_gc", "_is_shutdown", "_tasks", "_nodes_lock",
    "_work_tracker", "_parameter_service", "_parameter_overrides", "_descriptors",
    "_type_description_service", "_time_source", "_rosout_publisher",
}


def private_rclpy_uses(source: str, name: str = "<source>") -> list[str]:
    """Each import of a private rclpy module and each read of a private rclpy member in
    ``source``, as ``name:line: what``."""
    found = []
    for n in ast.walk(ast.parse(source)):
        mods = []
        if isinstance(n, ast.Import):
            mods = [a.name for a in n.names]
        elif isinstance(n, ast.ImportFrom) and n.module:
            mods = [n.module] + [f"{n.module}.{a.name}" for a in n.names]
        for m in mods:
            parts = m.split(".")
            if parts[0] == "rclpy" and any(p.startswith("_") for p in parts[1:]) or \
                    m.startswith("rclpy.impl") or "_rclpy" in parts:
                found.append(f"{name}:{n.lineno}: import {m}")
        if isinstance(n, ast.Attribute) and n.attr in RCLPY_PRIVATE_MEMBERS:
            found.append(f"{name}:{n.lineno}: .{n.attr}")
        if isinstance(n, ast.Name) and n.id == "_rclpy":
            found.append(f"{name}:{n.lineno}: _rclpy")
    return found


def test_no_private_rclpy_name_in_the_package_the_benches_or_the_examples():
    assert len(SOURCES) > 50
    bad = [u for p in SOURCES
           for u in private_rclpy_uses(p.read_text(), str(p.relative_to(ROOT)))]
    assert not bad, "private rclpy API (use rclpy's public classes):\n" + "\n".join(bad)


def test_the_check_sees_each_kind_of_private_use():
    src = ("from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy\n"
           "import rclpy._rclpy_pybind11\n"
           "from rclpy import _rclpy_pybind11\n"
           "ws = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, ctx)\n"
           "t = sub._callback_type\n"
           "g = executor._wait_for_ready_callbacks(0.1)\n")
    got = private_rclpy_uses(src)
    assert [g.split(":")[1] for g in got].count("1") >= 1
    assert any("rclpy._rclpy_pybind11" in g for g in got)
    assert any(":3:" in g for g in got)
    assert any(":4:" in g for g in got) and any("._callback_type" in g for g in got)
    assert any("._wait_for_ready_callbacks" in g for g in got)
    public = ("from rclpy.executors import SingleThreadedExecutor\n"
              "from rclpy.guard_condition import GuardCondition\n"
              "executor.wake(); sub.handle\n")
    assert private_rclpy_uses(public) == []
