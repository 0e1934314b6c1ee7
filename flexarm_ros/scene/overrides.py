"""Scene overrides on the command line: ``--set KEY=VALUE`` (repeatable) on ``flexarm
simulate``, ``run``, ``modes``, ``linearize``, ``explain`` and ``calibrate``.

KEY is a scene key path as ``flexarm sweep --param`` takes it
(``links[0].joint.drive.resistance``, ``tool.position[0]``, ``control.kp[0]``,
``fidelity.rung``; :mod:`flexarm_ros.scene.keys`); VALUE is read as one YAML scalar or
flow value with the safe loader (``6.0``, ``[6.0, 8.0]``, ``true``, ``modal``,
``{type: constant, value: 1.5}``), except that a number in exponent form without a dot
or a sign (``1e-3``, ``2e5``, which YAML 1.1 reads as text) is the number.

:func:`apply_sets` writes them with :func:`~flexarm_ros.scene.keys.set_keys`: the whole
scene re-validated, a section the scene leaves out created (``control.rate_hz=500`` on a
scene without ``control:``). The commands apply them to the loaded scene before the
fidelity flags (``--rung`` …), so an explicit flag wins. Every bad input is one
SceneError line naming the key, the value and the expectation.

The twin's nodes take the same assignment as the string parameter ``set``
(:func:`encode_sets` / :func:`decode_sets`: a JSON object), so every node of ``flexarm
run`` — in this process or a child — builds the same modified scene.
"""

from __future__ import annotations

import json
import math
import re

import yaml

from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.scene.keys import parse_path, set_keys

OPTION = "--set"
EXPECTED = ("expected KEY=VALUE with a scene key path such as links[0].beam.EI "
            "(e.g. links[0].beam.EI=12.0, fidelity.rung=fem, tool.position=[1.0, 1.2])")

# what YAML 1.1 leaves as text but a user means as a number: 1e-3, 2E5, -3e+2, 5.e3 (a
# plain scalar only: '1e3' in quotes stays text)
_EXP_NUMBER = re.compile(r"^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$")


class _Loader(yaml.SafeLoader):
    """The safe loader, with ``1e-3`` a float."""


class _Dumper(yaml.SafeDumper):
    """The safe dumper, quoting the text ``'1e-3'`` (else read back as a number)."""


for _cls in (_Loader, _Dumper):
    _cls.add_implicit_resolver("tag:yaml.org,2002:float", _EXP_NUMBER,
                               list("-+0123456789."))


def parse_value(text: str, key: str = "", whole: str | None = None):
    """VALUE of ``KEY=VALUE``: one YAML scalar or flow value (safe loader)."""
    shown = whole if whole is not None else f"{key}={text}"
    if not text.strip():
        raise SceneError(f"{OPTION}: got {shown!r}, expected a VALUE after '=' (a YAML "
                         f"scalar or flow value such as 6.0, [6.0, 8.0], true, modal)")
    try:
        value = yaml.load(text, Loader=_Loader)      # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        what = getattr(exc, "problem", None) or " ".join(str(exc).split())
        raise SceneError(f"{OPTION} {key}: got {text.strip()!r}, expected VALUE as one YAML "
                         f"scalar or flow value (6.0, [6.0, 8.0], true, modal); YAML says: "
                         f"{what}") from None
    if isinstance(value, float) and math.isnan(value):
        raise SceneError(f"{OPTION} {key}: got {text.strip()!r}, expected a number, not NaN")
    return value


def parse_set(text) -> tuple[str, object]:
    """``'links[0].beam.EI=12'`` → ``('links[0].beam.EI', 12)``; SceneError for a text
    without ``=``, a malformed key path or a VALUE that is not YAML (the key's existence
    and the value's range are the schema's, checked by :func:`apply_sets`)."""
    key, sep, raw = str(text).partition("=")
    key = key.strip()
    if not sep or not key:
        raise SceneError(f"{OPTION}: got {text!r}, {EXPECTED}")
    try:
        parse_path(key)
    except InputError:
        raise SceneError(f"{OPTION}: got {text!r}, expected KEY=VALUE with KEY a scene key "
                         f"path of names joined by '.' and [index] (e.g. links[0].beam.EI, "
                         f"tool.position[1])") from None
    return key, parse_value(raw, key, str(text))


def parse_sets(texts) -> dict:
    """The repeated ``--set`` texts (None: none) → ``{key: value}`` in the order given;
    a key given twice is refused (which one was meant?)."""
    out: dict = {}
    for text in texts or ():
        key, value = parse_set(text)
        if key in out:
            raise SceneError(f"{OPTION} {key}: got it twice ({format_value(out[key])} and "
                             f"{format_value(value)}), expected each key once")
        out[key] = value
    return out


def apply_sets(scene, sets: dict | None):
    """``scene`` with ``sets`` written and re-validated (``scene`` itself when none);
    SceneError in the schema's words (``links[0].beam.EI: got -1.0, expected a finite
    number > 0 (N·m²)``, ``links[0].beam.EII: unknown key; expected one of …``)."""
    return set_keys(scene, sets) if sets else scene


def with_overrides(scene, sets: dict | None, fidelity: dict | None = None):
    """``scene`` with ``sets`` written (:func:`apply_sets`), then the fidelity flags
    (``Scene.with_fidelity`` keywords, None: not given). A flag wins over a ``--set
    fidelity.…`` of the same key; a ``fidelity.…`` value set explicitly stays what it was
    set to when a flag changes the model (``--refine 8 --set fidelity.rod_modes=4``: the
    flag alone would send the scene's rod_modes, rod_points and dt back to 0)."""
    scene = apply_sets(scene, sets)
    given = {k: v for k, v in (fidelity or {}).items() if v is not None}
    if not given:
        return scene
    for key, value in (sets or {}).items():
        head, _, name = key.partition(".")
        if head == "fidelity" and name and "." not in name:
            given.setdefault(name, value)
    out = scene.with_fidelity(**given)
    refine = (fidelity or {}).get("refine")
    if refine is not None and refine > 1 and out.fidelity.rung in ("rigid", "cubic"):
        from flexarm_ros.errors import InputError
        raise InputError(f"--refine: got {refine} with the {out.fidelity.rung} rung, expected "
                         f"0 or 1 (it has one shape per beam; the modal, fem, fd and rod "
                         f"rungs take a refinement)")
    return out


def format_value(value) -> str:
    """A value as it would be typed after ``=`` (YAML flow style: ``6.0``, ``[6.0, 8.0]``,
    ``true``, ``modal``)."""
    text = yaml.dump(value, Dumper=_Dumper, default_flow_style=True, width=float("inf"),
                     allow_unicode=True).strip()
    return text[:-4].rstrip() if text.endswith("\n...") else text


def format_sets(sets: dict) -> str:
    """``KEY=VALUE, KEY=VALUE`` (the summaries' ``set:`` line)."""
    return ", ".join(f"{k}={format_value(v)}" for k, v in sets.items())


def encode_sets(sets: dict | None) -> str:
    """The node parameter ``set``: a JSON object (``""`` for none)."""
    return json.dumps(sets, sort_keys=False) if sets else ""


def decode_sets(text: str) -> dict:
    """The node parameter ``set`` → ``{key: value}``; SceneError naming the parameter."""
    if not text:
        return {}
    try:
        sets = json.loads(text)
    except ValueError:
        sets = None
    if not isinstance(sets, dict) or not all(isinstance(k, str) for k in sets):
        raise SceneError(f"parameter set: got {text!r}, expected a JSON object {{\"key "
                         f"path\": value}} (e.g. {{\"links[0].beam.EI\": 12.0}})")
    return sets


def check_not_set(keys, sets: dict, verb: str = "fits") -> None:
    """No key that ``--param`` varies (``keys``: it ``verb``, fits or sweeps) is also fixed
    by ``--set`` (the task would overwrite the set every time); SceneError naming it."""
    from flexarm_ros.scene.keys import parse_path

    def path(k):
        try:
            return tuple(parse_path(k))
        except InputError:           # a malformed --param: its own message, later
            return None
    fixed = {path(k): k for k in sets}
    for k in keys:
        if path(k) is not None and path(k) in fixed:
            raise SceneError(f"--set {fixed[path(k)]}: got a key that --param {verb} too, "
                             f"expected it in one of them (--set fixes a value, --param "
                             f"{verb} it)")
