"""One YAML loader, with limits, for every YAML file a user hands the project (issue 39).

``yaml.safe_load`` builds what a file says, however much that is: nine nested levels of
anchors that each alias the one below ten times (the "billion laughs") load into a small
graph of shared objects whose walk — validation, a JSON dump — visits 10⁹ nodes; a
document nested 5,000 levels deep ends in a ``RecursionError``; a key given twice is
taken silently, the last one winning. :func:`load_yaml` refuses each, before building
anything, with one line naming the file, the place and the limit:

- nesting deeper than :data:`MAX_DEPTH` levels (the deepest scene is 6);
- a document that expands (aliases followed) to more than :data:`MAX_NODES` nodes (a
  scene is about 300);
- a key twice in one mapping (line and column of both);
- a node that contains itself through an alias (``x: &x [*x]``), at once.

The loader is PyYAML's safe loader (no tags beyond the standard ones) with one change:
numbers are read as YAML 1.2 reads them, so ``3.5e6`` and ``1e-5`` are floats (YAML 1.1,
which PyYAML follows, reads them as strings and a scene refused "3.5e6 (str)"). Every
other value is what ``yaml.safe_load`` gives for every document within the limits.
"""

from __future__ import annotations

import re

import yaml

from flexarm_ros.errors import InputError

MAX_DEPTH = 64
MAX_NODES = 1_000_000


class _Refused(Exception):
    """A limit crossed while composing (turned into an :class:`InputError` naming the
    source by :func:`load_yaml`)."""


class BoundedLoader(yaml.SafeLoader):
    """The safe loader with a bound on nesting depth and on duplicate keys."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise _Refused(f"nested deeper than {MAX_DEPTH} levels at line "
                               f"{mark.line + 1}, expected at most {MAX_DEPTH}")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            self.flatten_mapping(node)
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:                # an unhashable key: PyYAML says so below
                    continue
                if first is not None:
                    raise _Refused(
                        f"key {key!r} given twice (line {first.line + 1} and line "
                        f"{key_node.start_mark.line + 1}), expected each key once")
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


#: YAML 1.2's core-schema float (``1e-5``, ``3.5e6``, ``.5``, ``-2.``, ``.inf``, ``.nan``)
_FLOAT_12 = re.compile(r"""^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?
                        |[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$""", re.X)
BoundedLoader.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:float"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
BoundedLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12,
                                    list("-+0123456789."))


def _expanded_size(root) -> int:
    """Nodes of the document with every alias followed (each shared node counted as often
    as it is reached), computed once per node; stops counting past MAX_NODES."""
    size: dict[int, int] = {}
    open_: set[int] = set()              # nodes whose children are still being counted
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in size:
            continue
        if isinstance(node, yaml.ScalarNode):
            size[id(node)] = 1
            continue
        children = ([c for pair in node.value for c in pair]
                    if isinstance(node, yaml.MappingNode) else list(node.value))
        if done:
            open_.discard(id(node))
            size[id(node)] = min(MAX_NODES + 1, 1 + sum(size[id(c)] for c in children))
        else:
            if any(id(c) in open_ or c is node for c in children):
                mark = node.start_mark
                raise _Refused(f"a node at line {mark.line + 1} contains itself through an "
                               f"alias, expected no recursive alias")
            open_.add(id(node))
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in size)
    return size[id(root)]


def read_yaml_text(path, what: str) -> str:
    """The UTF-8 text of the YAML file ``path`` (``what`` it is: "spec", "map file"...),
    or InputError naming the file, what went wrong and what was expected."""
    from pathlib import Path
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: got byte 0x{exc.object[exc.start]:02x} at offset "
                         f"{exc.start}, expected a UTF-8 text file (a {what} is YAML "
                         f"text)") from None
    except FileNotFoundError:
        raise InputError(f"{p}: no such file, expected a {what} (YAML)") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read the {what} ({exc.strerror or exc}), expected a "
                         f"readable YAML file") from None


def load_yaml(text: str, source: str):
    """The document in ``text`` (from ``source``, named in errors) as ``yaml.safe_load``
    gives it, or :class:`InputError` — invalid YAML, or one of the limits above."""
    loader = BoundedLoader(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None
        n = _expanded_size(root)
        if n > MAX_NODES:
            raise _Refused(f"expands to more than {MAX_NODES:,} nodes with its aliases "
                           f"followed, expected at most {MAX_NODES:,} (an alias bomb?)")
        return loader.construct_document(root)
    except _Refused as exc:
        raise InputError(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where else ""
        what = getattr(exc, "problem", None) or " ".join(str(exc).split())
        raise InputError(f"{source}: not valid YAML{at}: {what}") from None
    finally:
        loader.dispose()
