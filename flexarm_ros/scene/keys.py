"""Scene key paths: read and set one value of a scene by its path, re-validated.

A key path is the name the scene's error messages already print::

    links[0].joint.drive.resistance      tool.position[0]      fidelity.rung

:func:`set_keys` writes values at paths into the scene's mapping
(:func:`flexarm_ros.scene.schema.to_mapping`) and validates the result with the scene loader, so a value
the schema refuses raises :class:`~flexarm_ros.errors.SceneError` naming the key, the
value and the expectation (``links[0].joint.drive.resistance: got -1.0, expected a finite
number > 0 (Ω)``), exactly as a scene file with that value would. A path through a section
the scene leaves out (``links[0].joint.backlash.width`` on a scene without backlash)
creates the section, which the loader then checks for its required fields.

:func:`key_field` walks the schema types (not a scene) to the field a path names: its
type and its metadata (unit and bounds), to check a range or a distribution against the
schema before anything runs.

Here in :mod:`flexarm_ros.scene` (it needs the scene's types and loader only) for every
command that sets keys: the ensembles, calibration and ``--set KEY=VALUE``
(:mod:`flexarm_ros.scene.overrides`); :mod:`flexarm_ros.ensemble.keys` re-exports it.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing

from flexarm_ros.errors import SceneError

_TOKEN = re.compile(r"\.?([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


def parse_path(path: str) -> list:
    """``'links[0].joint.drive.resistance'`` → ``['links', 0, 'joint', 'drive',
    'resistance']``; a malformed path raises SceneError."""
    if not isinstance(path, str) or not path:
        raise SceneError(f"key: got {path!r}, expected a scene key path such as "
                         f"links[0].joint.drive.resistance")
    out, pos = [], 0
    while pos < len(path):
        m = _TOKEN.match(path, pos)
        if not m or (pos == 0 and path[0] == ".") or (pos > 0 and m.group(1) and
                                                         path[pos] != "."):
            raise SceneError(f"key: got {path!r}, expected a scene key path of names "
                             f"joined by '.' and [index] (e.g. links[0].beam.EI, "
                             f"tool.position[1])")
        out.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not isinstance(out[0], str):
        raise SceneError(f"key: got {path!r}, expected a path starting with a section name")
    return out


def _plain(obj):
    """asdict output with tuples turned into lists (mutable, YAML-like)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


def scene_mapping(scene) -> dict:
    """The scene as the nested mapping a YAML file would hold (``load_scene_dict`` of it
    gives the scene back): each section's own keys (a step program has no ``value``)."""
    from flexarm_ros.scene.schema import to_mapping
    return to_mapping(scene)


def _where(tokens) -> str:
    text = ""
    for t in tokens:
        text += f"[{t}]" if isinstance(t, int) else (f".{t}" if text else t)
    return text


def _put(data: dict, tokens: list, value, path: str) -> None:
    node = data
    for i, tok in enumerate(tokens):
        last = i == len(tokens) - 1
        here = _where(tokens[:i + 1])
        if isinstance(tok, int):
            if not isinstance(node, list):
                raise SceneError(f"{path}: {_where(tokens[:i]) or 'scene'} is not a list, "
                                 f"expected no [index] after it")
            if tok >= len(node):
                raise SceneError(f"{path}: got index {tok} of {_where(tokens[:i])}, "
                                 f"expected 0..{len(node) - 1} ({len(node)} entries)")
        else:
            if not isinstance(node, dict):
                raise SceneError(f"{path}: {_where(tokens[:i]) or 'scene'} is not a section, "
                                 f"expected no .{tok} after it")
            if tok not in node and node.get("__created__") is None:
                raise SceneError(f"{here}: unknown key; expected one of "
                                 f"{', '.join(sorted(k for k in node if k != '__created__'))}")
        if last:
            node[tok] = value
            return
        nxt = node[tok] if not (isinstance(node, dict) and tok not in node) else None
        if nxt is None:                      # an optional section the scene leaves out
            nxt = {"__created__": True}
            node[tok] = nxt
        node = nxt


def _strip_created(obj):
    if isinstance(obj, dict):
        return {k: _strip_created(v) for k, v in obj.items() if k != "__created__"}
    if isinstance(obj, list):
        return [_strip_created(v) for v in obj]
    return obj


def _plain_value(v):
    """numpy scalars → Python numbers (the schema checks Python types)."""
    if hasattr(v, "item") and not isinstance(v, (list, dict, str)):
        try:
            return v.item()
        except (TypeError, ValueError):
            return v
    return v


def set_keys(scene, assignment: dict):
    """A copy of ``scene`` with ``{key path: value}`` written and the whole scene
    re-validated; SceneError names the key, the value and the expectation. Values may be
    numbers, strings, lists or mappings (a whole section)."""
    from flexarm_ros.scene.loading import load_scene_dict
    if not assignment:
        return scene
    data = scene_mapping(scene) if not isinstance(scene, dict) else _plain(scene)
    fidelity = {}          # fidelity.<field>: as the command line's overrides apply them
    for path, value in assignment.items():
        tokens = parse_path(path)
        if len(tokens) == 2 and tokens[0] == "fidelity" and isinstance(tokens[1], str):
            fidelity[tokens[1]] = _plain(_plain_value(value))
        else:
            _put(data, tokens, _plain(_plain_value(value)), path)
    out = load_scene_dict(_strip_created(data))
    # Scene.with_fidelity: a scene's fixed step goes with the model it names
    return out.with_fidelity(**fidelity) if fidelity else out


def put_keys(data: dict, assignment: dict) -> dict:
    """Write ``{key path: value}`` into a scene *mapping* in place (a scene file's YAML as
    loaded, its own spelling kept) and return it; the caller validates (``set_keys`` on
    the result). Sections a path runs through are created."""
    for path, value in assignment.items():
        tokens = parse_path(path)
        node = data
        for i, tok in enumerate(tokens):
            last = i == len(tokens) - 1
            if isinstance(tok, int):
                if not isinstance(node, list) or tok >= len(node):
                    raise SceneError(f"{path}: {_where(tokens[:i])} has no entry {tok} in "
                                     f"this file")
            elif not isinstance(node, dict):
                raise SceneError(f"{path}: {_where(tokens[:i]) or 'scene'} is not a section")
            if last:
                node[tok] = _plain(_plain_value(value))
            else:
                if isinstance(node, dict) and node.get(tok) is None:
                    node[tok] = {}
                node = node[tok]
    return data


def get_key(scene, path: str):
    """The value at ``path`` (None when the path runs through a section the scene leaves
    out); SceneError for a path the schema does not have."""
    key_field(path)
    node = scene_mapping(scene)
    for tok in parse_path(path):
        if node is None:
            return None
        if isinstance(tok, int):
            if not isinstance(node, list) or tok >= len(node):
                raise SceneError(f"{path}: got index {tok}, expected 0.."
                                 f"{len(node) - 1 if isinstance(node, list) else 0}")
            node = node[tok]
        else:
            node = node.get(tok)
    return node


@dataclasses.dataclass(frozen=True)
class KeyField:
    """What the schema says about a key path: the value type (float, int, str, bool, or a
    dataclass for a section), the unit and the bounds (``gt``, ``ge``, ``lt``, ``le``;
    None where open) and the choices of a string."""
    path: str
    type: type
    unit: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple | None = None

    def lower(self) -> tuple[float | None, bool]:
        """(lower bound, inclusive)."""
        if self.gt is not None:
            return float(self.gt), False
        if self.ge is not None:
            return float(self.ge), True
        return None, False

    def upper(self) -> tuple[float | None, bool]:
        if self.lt is not None:
            return float(self.lt), False
        if self.le is not None:
            return float(self.le), True
        return None, False

    def bounds_text(self) -> str:
        parts = [f"{op} {v:g}" for op, v in ((">", self.gt), (">=", self.ge), ("<", self.lt),
                                                 ("<=", self.le)) if v is not None]
        text = " and ".join(parts) if parts else "any finite value"
        return text + (f" ({self.unit})" if self.unit else "")

    def admits(self, x: float) -> bool:
        """Whether the number ``x`` is inside the schema's bounds (cross-field checks of
        the scene are not seen here)."""
        lo, lo_in = self.lower()
        hi, hi_in = self.upper()
        if lo is not None and (x < lo or (x == lo and not lo_in)):
            return False
        if hi is not None and (x > hi or (x == hi and not hi_in)):
            return False
        return True


def _unwrap(tp):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return _unwrap(args[0])
    return tp


def key_field(path: str) -> KeyField:
    """The schema field at ``path`` (see :class:`KeyField`); SceneError naming the first
    unknown part and the keys expected there."""
    from flexarm_ros.scene.sections import Scene
    tokens = parse_path(path)
    tp, meta = Scene, {}
    for i, tok in enumerate(tokens):
        tp = _unwrap(tp)
        here = _where(tokens[:i + 1])
        if isinstance(tok, int):
            if typing.get_origin(tp) is not tuple:
                raise SceneError(f"{path}: {_where(tokens[:i])} is not a list, expected no "
                                 f"[index] after it")
            args = typing.get_args(tp)
            if len(args) == 2 and args[1] is Ellipsis:
                tp = args[0]
            else:
                if tok >= len(args):
                    raise SceneError(f"{path}: got index {tok} of {_where(tokens[:i])}, "
                                     f"expected 0..{len(args) - 1}")
                tp = args[tok]
            continue
        if not dataclasses.is_dataclass(tp):
            raise SceneError(f"{path}: {_where(tokens[:i]) or 'scene'} is a value, expected "
                             f"no .{tok} after it")
        fields = {f.name: f for f in dataclasses.fields(tp) if f.init}
        if tok not in fields:
            raise SceneError(f"{here}: unknown key; expected one of "
                             f"{', '.join(sorted(fields))}")
        hints = typing.get_type_hints(tp)
        tp, meta = hints[tok], dict(fields[tok].metadata)
    tp = _unwrap(tp)
    base = tp if isinstance(tp, type) else object
    if typing.get_origin(tp) is tuple:
        base = tuple
    return KeyField(path, base, meta.get("unit", ""), meta.get("gt"), meta.get("ge"),
                    meta.get("lt"), meta.get("le"),
                    tuple(meta["choices"]) if meta.get("choices") else None)


def check_numeric(path: str) -> KeyField:
    """The field at ``path``, which must hold one number (a range or a distribution sets
    it); SceneError otherwise."""
    kf = key_field(path)
    if kf.type not in (float, int):
        what = getattr(kf.type, "__name__", str(kf.type))
        raise SceneError(f"{path}: a {what} key, expected a key holding one number for a "
                         f"range or a distribution (index a list, e.g. {path}[0])"
                         if kf.type is tuple else
                         f"{path}: a {what} key, expected a key holding one number for a "
                         f"range or a distribution (give a list of values instead)")
    return kf
