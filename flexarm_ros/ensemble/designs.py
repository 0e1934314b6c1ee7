"""Sweep parameters and designs: ``--param KEY=LO:HI`` / ``KEY=v1,v2,…`` → assignments.

Designs (``--design``), ``N = --samples``:

``grid``
    the Cartesian product, first parameter slowest: a range takes ``N`` evenly spaced
    values ``LO + k (HI − LO)/(N − 1)``, a list its values.
``lhs``
    Latin hypercube of ``N`` points (``scipy.stats.qmc.LatinHypercube``, one point per
    stratum ``[k/N, (k+1)/N)`` of every axis).
``sobol``
    the first ``N`` points of a scrambled Sobol' sequence (``scipy.stats.qmc.Sobol``);
    ``N`` a power of two, as the sequence's balance properties need.
``random``
    ``N`` independent uniform points (``numpy.random.default_rng(seed)``).

A unit coordinate ``u`` in ``[0, 1)`` becomes ``LO + u (HI − LO)`` for a range and the
value ``floor(u · n)`` of a list of ``n`` values. Every design is a function of
``(parameters, N, seed)`` only. Integer keys (``fidelity.refine``) take rounded values.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.ensemble.keys import key_field

DESIGNS = ("grid", "lhs", "sobol", "random")
DEFAULT_SAMPLES = {"grid": 5, "lhs": 16, "sobol": 16, "random": 16}


@dataclass(frozen=True)
class Param:
    """One swept key: a range ``lo..hi`` or a list of ``values``."""
    key: str
    lo: float | None = None
    hi: float | None = None
    values: tuple | None = None
    integer: bool = False

    @property
    def is_range(self) -> bool:
        return self.values is None

    def at(self, u: float):
        if self.is_range:
            x = self.lo + u * (self.hi - self.lo)
            return int(round(x)) if self.integer else float(x)
        return self.values[min(int(u * len(self.values)), len(self.values) - 1)]

    def levels(self, n: int) -> list:
        if not self.is_range:
            return list(self.values)
        xs = [float(v) for v in np.linspace(self.lo, self.hi, n)] if n > 1 else [
            float(self.lo)]
        if self.integer:
            xs = list(dict.fromkeys(int(round(x)) for x in xs))
        return xs


def _number(text: str):
    t = text.strip()
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def parse_param(text: str, scene=None) -> Param:
    """``'links[0].joint.drive.resistance=1.0:1.2'`` or ``'fidelity.rung=rigid,cubic'``
    → Param; checks the key against the schema and the values against its bounds
    (InputError naming key, value and expectation)."""
    key, sep, spec = str(text).partition("=")
    key, spec = key.strip(), spec.strip()
    if not sep or not key or not spec:
        raise InputError(f"--param: got {text!r}, expected KEY=LO:HI or KEY=v1,v2,... (e.g. "
                         f"links[0].joint.drive.resistance=1.0:1.2)")
    kf = key_field(key)
    if ":" in spec and "," not in spec:
        lo_t, _, hi_t = spec.partition(":")
        lo, hi = _number(lo_t), _number(hi_t)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in (lo, hi)):
            raise InputError(f"--param {key}: got {spec!r}, expected LO:HI with two finite "
                             f"numbers")
        if kf.type not in (int, float):
            raise InputError(f"--param {key}: got a range {spec!r} on a "
                             f"{getattr(kf.type, '__name__', kf.type)} key, expected a list "
                             f"of values v1,v2,...")
        if lo > hi:
            raise InputError(f"--param {key}: got LO = {lo:g} > HI = {hi:g}, expected "
                             f"LO <= HI")
        for name, v in (("LO", lo), ("HI", hi)):
            if not kf.admits(float(v)):
                raise InputError(f"--param {key}: got {name} = {v:g}, expected "
                                 f"{kf.bounds_text()} (the schema's bounds of {key})")
        p = Param(key, float(lo), float(hi), integer=kf.type is int)
    else:
        vals = tuple(_number(v) for v in spec.split(",") if v.strip())
        if not vals:
            raise InputError(f"--param {key}: got {spec!r}, expected v1,v2,...")
        for v in vals:
            if kf.type in (int, float):
                if not isinstance(v, (int, float)) or (kf.type is int and not isinstance(v, int)):
                    raise InputError(f"--param {key}: got {v!r}, expected "
                                     f"{'an integer' if kf.type is int else 'a number'} "
                                     f"{kf.bounds_text()}")
                if not kf.admits(float(v)):
                    raise InputError(f"--param {key}: got {v:g}, expected {kf.bounds_text()} "
                                     f"(the schema's bounds of {key})")
            elif kf.choices and v not in kf.choices:
                raise InputError(f"--param {key}: got {v!r}, expected one of "
                                 f"{', '.join(kf.choices)}")
        if kf.type is float:
            vals = tuple(float(v) for v in vals)
        p = Param(key, values=vals)
    if scene is not None:
        _check_on_scene(p, scene)
    return p


def _check_on_scene(p: Param, scene) -> None:
    """The key set to its first value on the base scene: a path into a section the scene
    cannot grow from one value (a missing required field) is a bad parameter, not a row
    of refused samples."""
    from flexarm_ros.ensemble.keys import set_keys
    v = p.levels(2)[0]
    try:
        set_keys(scene, {p.key: v})
    except InputError as exc:
        msg = " ".join(str(exc).split())
        if "missing required field" in msg or "unknown key" in msg:
            raise InputError(f"--param {p.key}: {msg}") from None


def unit_points(design: str, d: int, n: int, seed: int) -> np.ndarray:
    """``(n, d)`` points of the unit cube for lhs, sobol and random."""
    if design == "random":
        return np.random.default_rng(seed).random((n, d))
    from scipy.stats import qmc
    if design == "lhs":
        return qmc.LatinHypercube(d, rng=np.random.default_rng(seed)).random(n)
    if design == "sobol":
        m = int(round(math.log2(n))) if n > 0 else -1
        if n < 1 or 2 ** m != n:
            lo = 2 ** max(0, math.floor(math.log2(max(n, 1))))
            raise InputError(f"--samples: got {n} with --design sobol, expected a power of "
                             f"two (e.g. {lo} or {2 * lo}) for a balanced Sobol' sequence")
        return qmc.Sobol(d, scramble=True, rng=np.random.default_rng(seed)).random_base2(m)
    raise InputError(f"--design: got {design!r}, expected one of {', '.join(DESIGNS)}")


def design_runs(params: list[Param], design: str = "grid", samples: int | None = None
                ) -> int:
    """The number of runs :func:`make_design` would make, without making them (the grid's
    product of levels can be astronomically large: checked before it is built)."""
    n = DEFAULT_SAMPLES.get(design, 1) if samples is None else int(samples)
    if not params:
        return 1
    if design == "grid":
        return math.prod(n if p.is_range else len(p.values) for p in params)
    return n


def make_design(params: list[Param], design: str = "grid", samples: int | None = None,
                seed: int = 0) -> list[dict]:
    """The assignments ``[{key: value}, ...]`` of a design (see module doc)."""
    if design not in DESIGNS:
        raise InputError(f"--design: got {design!r}, expected one of {', '.join(DESIGNS)}")
    n = DEFAULT_SAMPLES[design] if samples is None else int(samples)
    from flexarm_ros.ensemble.limits import check_samples, check_seed
    check_samples(n)
    check_seed(seed)
    if not params:
        return [{}]
    if design == "grid":
        axes = [p.levels(n) for p in params]
        return [dict(zip((p.key for p in params), combo)) for combo in itertools.product(*axes)]
    u = unit_points(design, len(params), n, seed)
    return [{p.key: p.at(float(u[i, j])) for j, p in enumerate(params)} for i in range(n)]
