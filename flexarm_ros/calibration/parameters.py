"""The parameters of a calibration: scene keys, their bounds and start values, and the
box coordinates the fit works in.

A parameter is a scene key path holding one number (``links[0].joint.drive.resistance``,
``tool.position[0]``), given on the command line as ``KEY=LO:HI`` (start: the scene's
value) or ``KEY=LO:HI@START``; one parameter may set several keys to one value (the spec
form's ``keys:``, e.g. K_t and K_b of one motor).

The fit works in box coordinates z ∈ [0, 1] per parameter: z = (p − lo)/(hi − lo), or
z = ln(p/lo)/ln(hi/lo) when ``lo > 0`` and ``hi/lo ≥ 10`` (a range over a decade or more:
relative changes matter, and a product of two parameters becomes a sum of their
coordinates, which the identifiability analysis names as such). Both make the box's width
1 in every direction, so the Jacobian's columns and the singular values are comparable.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError

LOG_RATIO = 10.0      # hi / lo at or above which a positive range is taken on a log scale

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PARAM = re.compile(rf"^\s*([^=\s]+)\s*=\s*({_NUM})\s*:\s*({_NUM})\s*(?:@\s*({_NUM}))?\s*$")


@dataclass(frozen=True)
class CalParam:
    """One fitted value: its name (the first key), the keys it sets, bounds, start."""
    name: str
    keys: tuple
    low: float
    high: float
    start: float
    unit: str = ""
    log: bool = False
    factors: tuple | None = None     # a scale parameter: key k set to value × factors[k]

    def to_z(self, p):
        p = np.asarray(p, float)
        if self.log:
            return np.log(p / self.low) / math.log(self.high / self.low)
        return (p - self.low) / (self.high - self.low)

    def from_z(self, z):
        z = np.asarray(z, float)
        if self.log:
            return self.low * np.exp(z * math.log(self.high / self.low))
        return self.low + z * (self.high - self.low)

    def dp_dz(self, p) -> float:
        """dp/dz at p (the chain rule from box to physical units)."""
        if self.log:
            return float(p) * math.log(self.high / self.low)
        return self.high - self.low

    def assignment(self, value) -> dict:
        if self.factors is not None:
            return {k: float(value) * f for k, f in zip(self.keys, self.factors)}
        return {k: float(value) for k in self.keys}


def _check_keys(keys, scene):
    from flexarm_ros.ensemble.keys import check_numeric, get_key
    unit, current = "", None
    for k in keys:
        kf = check_numeric(k)
        unit = unit or kf.unit
        if scene is not None:
            v = get_key(scene, k)
            if current is None and v is not None:
                current = float(v)
    return unit, current


def make_param(keys, low, high, start=None, scene=None, where: str = "--param") -> CalParam:
    """A checked :class:`CalParam`: the keys are numeric scene keys, ``low < high`` are
    finite and inside the schema's bounds of every key, and the start (given, else the
    scene's value of the first key) lies inside ``[low, high]``."""
    from flexarm_ros.ensemble.keys import key_field
    keys = tuple(keys)
    name = keys[0]
    for x, what in ((low, "low"), (high, "high")):
        if not (isinstance(x, (int, float)) and math.isfinite(x)):
            raise InputError(f"{where} {name}: {what} bound got {x!r}, expected a finite "
                             f"number")
    if not low < high:
        raise InputError(f"{where} {name}: got bounds {low:g}:{high:g}, expected low < high")
    unit, current = _check_keys(keys, scene)
    for k in keys:
        kf = key_field(k)
        for x in (low, high):
            if not kf.admits(x):
                raise InputError(f"{where} {k}: got bound {x:g}, expected bounds "
                                 f"{kf.bounds_text()} (the schema's range of the key)")
    if start is None:
        if current is None:
            raise InputError(f"{where} {name}: the scene has no value there, expected a "
                             f"start value: {name}={low:g}:{high:g}@START")
        start = current
        origin = "the scene's value"
    else:
        origin = "the start"
    if not low <= start <= high:
        hint = (f" (or give one: {name}={low:g}:{high:g}@START)" if origin != "the start"
                else "")
        raise InputError(f"{where} {name}: {origin} {start:g} lies outside the bounds "
                         f"{low:g}:{high:g}, expected bounds that contain the start{hint}")
    log = low > 0 and high / low >= LOG_RATIO
    return CalParam(name, keys, float(low), float(high), float(start), unit, log)


def make_scale(name: str, keys, low, high, start, scene, where: str) -> CalParam:
    """A common factor on several keys (e.g. both motors' resistances): the fitted value
    multiplies each key's value in the scene; start 1 unless given."""
    from flexarm_ros.ensemble.keys import check_numeric, get_key
    keys = tuple(keys)
    if not name or not isinstance(name, str):
        raise InputError(f"{where}: a scale parameter needs a name, expected name: TEXT")
    for x, what in ((low, "low"), (high, "high")):
        if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
            raise InputError(f"{where} {name}: {what} got {x!r}, expected a factor > 0")
    if not low < high:
        raise InputError(f"{where} {name}: got bounds {low:g}:{high:g}, expected low < high")
    start = 1.0 if start is None else start
    if not low <= start <= high:
        raise InputError(f"{where} {name}: start {start:g} lies outside the bounds "
                         f"{low:g}:{high:g}, expected bounds that contain it")
    factors = []
    for k in keys:
        check_numeric(k)
        v = get_key(scene, k)
        if v is None:
            raise InputError(f"{where} {name}: {k} has no value in the scene, expected a "
                             f"key with a value to scale")
        factors.append(float(v))
    return CalParam(name, keys, float(low), float(high), float(start), "1",
                    low > 0 and high / low >= LOG_RATIO, tuple(factors))


def parse_param(text: str, scene=None) -> CalParam:
    """``KEY=LO:HI`` or ``KEY=LO:HI@START`` → :class:`CalParam` (InputError naming the
    argument and the expected form)."""
    m = _PARAM.match(text or "")
    if not m:
        raise InputError(f"--param: got {text!r}, expected KEY=LO:HI or KEY=LO:HI@START "
                         f"(e.g. links[0].joint.drive.resistance=0.8:1.6)")
    key, lo, hi, start = m.groups()
    return make_param([key], float(lo), float(hi),
                      None if start is None else float(start), scene)


def start_assignment(params) -> dict:
    """``{key: value}`` of every parameter at its start (scale factors applied)."""
    out = {}
    for p in params:
        out.update(p.assignment(p.start))
    return out


def check_distinct(params, where: str = "--param") -> None:
    seen = {}
    for p in params:
        for k in p.keys:
            if k in seen:
                raise InputError(f"{where} {k}: given twice, expected each key once")
            seen[k] = p
