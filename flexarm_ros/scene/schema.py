"""Declarative parameters: frozen dataclasses whose fields carry unit, bounds and a description.

One generic loader turns a nested mapping (parsed YAML) into these objects and rejects
anything it cannot place: unknown keys, wrong types, out-of-range values, missing required
fields. Every error names the key path, the value and the expectation, e.g.::

    links[0].beam.EI: got -2.0, expected a number > 0 (N·m²)

The field metadata (``unit``, ``gt``/``ge``/``le``, ``doc``, ``choices``) is the single source
of truth for validation and for the generated configuration reference
(:func:`reference_markdown`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from typing import Any, Mapping

from flexarm_ros.errors import InputError, SceneError

_MISSING = dataclasses.MISSING


def param(default=_MISSING, *, unit: str = "", doc: str = "", gt=None, ge=None, le=None,
          lt=None, choices=None, default_factory=_MISSING):
    """A dataclass field with validation metadata (unit, bounds, description)."""
    meta = {"unit": unit, "doc": doc, "gt": gt, "ge": ge, "le": le, "lt": lt,
            "choices": choices}
    if default_factory is not _MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _fmt(value) -> str:
    return repr(value) if isinstance(value, str) else str(value)


#: a number without an upper bound of its own is refused beyond this magnitude: 1e15 in SI
#: units is beyond any arm (E of diamond 1.2e12 Pa) and below what overflows the model's
#: powers and matrices (a beam of 1e300 m raised OverflowError)
MAX_MAGNITUDE = 1e15


def _expect_number(meta) -> str:
    parts = []
    if meta.get("gt") is not None:
        parts.append(f"> {meta['gt']}")
    if meta.get("ge") is not None:
        parts.append(f">= {meta['ge']}")
    if meta.get("lt") is not None:
        parts.append(f"< {meta['lt']}")
    if meta.get("le") is not None:
        parts.append(f"<= {meta['le']}")
    text = "a finite number" + (" " + " and ".join(parts) if parts else "")
    if meta.get("unit"):
        text += f" ({meta['unit']})"
    return text


def _check_bounds(path, value, meta):
    if (math.isfinite(value) and meta.get("le") is None and meta.get("lt") is None
            and not abs(value) <= MAX_MAGNITUDE):
        raise SceneError(f"{path}: got {_fmt(value)}, expected {_expect_number(meta)} "
                         f"within ±{MAX_MAGNITUDE:g} (no arm needs more; larger values "
                         f"overflow the model)")
    bad = (not math.isfinite(value)
           or (meta.get("gt") is not None and not value > meta["gt"])
           or (meta.get("ge") is not None and not value >= meta["ge"])
           or (meta.get("lt") is not None and not value < meta["lt"])
           or (meta.get("le") is not None and not value <= meta["le"]))
    if bad:
        raise SceneError(f"{path}: got {_fmt(value)}, expected {_expect_number(meta)}")


def _convert(path: str, value: Any, tp, meta: Mapping) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        non_none = [a for a in args if a is not type(None)]
        if value is None and type(None) in args:
            return None
        if len(non_none) == 1:
            return _convert(path, value, non_none[0], meta)
        errors = []
        for alt in non_none:
            try:
                return _convert(path, value, alt, meta)
            except InputError as exc:
                errors.append(str(exc))
        raise SceneError(errors[0] if len(errors) == 1 else
                         f"{path}: got {_fmt(value)}, expected one of: "
                         + "; ".join(e.split(', expected ', 1)[-1] for e in errors))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{path}: got {_fmt(value)} ({type(value).__name__}), "
                             f"expected {_expect_number(meta)}")
        value = float(value)
        _check_bounds(path, value, meta)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{path}: got {_fmt(value)} ({type(value).__name__}), "
                             f"expected an integer" + _int_bounds(meta))
        _check_bounds(path, value, meta)
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise SceneError(f"{path}: got {_fmt(value)}, expected true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise SceneError(f"{path}: got {_fmt(value)}, expected a string"
                             + (f" (one of {', '.join(meta['choices'])})"
                                if meta.get("choices") else ""))
        if meta.get("choices") and value not in meta["choices"]:
            raise SceneError(f"{path}: got {_fmt(value)}, expected one of "
                             f"{', '.join(meta['choices'])}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"{path}: got {_fmt(value)}, expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(f"{path}[{i}]", v, args[0], meta)
                         for i, v in enumerate(value))
        if len(value) != len(args):
            raise SceneError(f"{path}: got {_fmt(value)}, expected a list of {len(args)} "
                             f"numbers" + (f" ({meta['unit']})" if meta.get('unit') else ""))
        return tuple(_convert(f"{path}[{i}]", v, a, meta)
                     for i, (v, a) in enumerate(zip(value, args)))
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, path)
    raise TypeError(f"unsupported schema type {tp!r} at {path}")  # programming error


def _int_bounds(meta) -> str:
    text = _expect_number(meta).replace("a finite number", "")
    return text


@functools.cache
def _type_hints(cls) -> dict:
    """The resolved field types of a schema dataclass (``typing.get_type_hints`` evaluates
    the string annotations every call: 40 % of loading a scene before it was kept)."""
    return typing.get_type_hints(cls)


def from_mapping(cls, data: Any, path: str = ""):
    """Build dataclass ``cls`` from a mapping, validating every field (see module doc)."""
    where = path or "scene"
    if not isinstance(data, Mapping):
        raise SceneError(f"{where}: got {_fmt(data)}, expected a mapping of "
                         f"{cls.__name__} fields")
    hints = _type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    if unknown:
        raise SceneError(f"{_join(path, str(unknown[0]))}: unknown key; expected one of "
                         f"{', '.join(sorted(fields))}")
    allowed = accepted_keys(cls, data)
    if allowed is not None:
        misplaced = [k for k in data if k not in allowed]
        if misplaced:
            key, kind = misplaced[0], data[cls.KEYED_BY]
            article = "an" if kind[:1] in "aeiou" else "a"
            raise SceneError(f"{_join(path, str(key))}: got {_fmt(data[key])}, but "
                             f"{article} {kind} {cls.NOUN} takes no {key}; expected one of "
                             f"{', '.join(allowed)}")
    kwargs = {}
    for name, f in fields.items():
        sub = _join(path, name)
        if name not in data:
            if f.default is _MISSING and f.default_factory is _MISSING:
                raise SceneError(f"{sub}: missing required field, expected "
                                 f"{_describe(f, hints[name])}")
            continue
        kwargs[name] = _convert(sub, data[name], hints[name], f.metadata)
    obj = cls(**kwargs)
    check = getattr(obj, "validate", None)
    if check is not None:
        check(where)
    return obj


def accepted_keys(cls, data) -> tuple | None:
    """The keys a section whose fields depend on its kind takes, for the mapping ``data``:
    a class naming its discriminating field ``KEYED_BY`` ("type", "kind", "shape") takes
    ``COMMON`` (the discriminator's by default) plus ``KEYS[kind]``. None: every field
    (any other class, or a kind the field's own check refuses first)."""
    by = getattr(cls, "KEYED_BY", None)
    if by is None or not isinstance(data.get(by), str) or data[by] not in cls.KEYS:
        return None
    return getattr(cls, "COMMON", (by,)) + cls.KEYS[data[by]]


def to_mapping(obj):
    """The mapping a scene file would hold for the schema object ``obj`` (lists for
    tuples): every field, except those a section does not take for its kind
    (:func:`accepted_keys`) (a step program has no ``value``) and those it derived (``derived_keys``: a
    beam's EI from E and its section), so :func:`from_mapping` of the result
    gives ``obj`` back."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        derived = getattr(obj, "derived_keys", ())
        names = [f.name for f in dataclasses.fields(obj) if f.init and f.name not in derived]
        out = {n: to_mapping(getattr(obj, n)) for n in names}
        allowed = accepted_keys(type(obj), out)
        return out if allowed is None else {k: v for k, v in out.items() if k in allowed}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _describe(f, tp) -> str:
    meta = f.metadata
    if dataclasses.is_dataclass(tp):
        return f"a {tp.__name__} mapping"
    text = meta.get("doc") or ""
    if meta.get("unit"):
        text += f" [{meta['unit']}]"
    return text or str(tp)


def reference_markdown(cls, heading: str | None = None, _seen=None) -> str:
    """The configuration reference of ``cls`` and its nested sections, as Markdown tables."""
    _seen = set() if _seen is None else _seen
    if cls in _seen:
        return ""
    _seen.add(cls)
    hints = typing.get_type_hints(cls)
    lines = [f"### `{heading or cls.__name__}`", "",
             (cls.__doc__ or "").strip().splitlines()[0], "",
             "| key | type | unit | default | bounds | meaning |",
             "|---|---|---|---|---|---|"]
    nested = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        meta = f.metadata
        tname = getattr(tp, "__name__", None) or str(tp).replace("typing.", "")
        if f.default is not _MISSING:
            default = f"`{f.default}`"
        elif f.default_factory is not _MISSING:
            default = "(see section)"
        else:
            default = "required"
        bounds = " ".join(f"{op}{meta[k]}" for k, op in
                          (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
                          if meta.get(k) is not None)
        if meta.get("choices"):
            bounds = " / ".join(meta["choices"])
        lines.append(f"| `{f.name}` | {tname} | {meta.get('unit', '')} | {default} | "
                     f"{bounds} | {meta.get('doc', '')} |")
        for sub in (tp, *typing.get_args(tp)):
            for s in (sub, *typing.get_args(sub)):
                if dataclasses.is_dataclass(s):
                    nested.append(s)
    out = "\n".join(lines) + "\n\n"
    for sub in nested:
        out += reference_markdown(sub, None, _seen)
    return out
