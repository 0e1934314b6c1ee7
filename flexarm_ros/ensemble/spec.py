"""Uncertainty specs: which scene keys are unknown and how (YAML), for Monte Carlo and
sensitivity analysis.

.. code-block:: yaml

    scene: two_link_case1          # shipped name or path (relative to this file)
    duration: 3.0                  # s (default: the scene's)
    set:                           # fixed changes to the scene before sampling
      links[0].joint.backlash: {width: 0.0, stiffness: 2000.0}
    unknowns:
      - name: K_base               # optional (default: the first key)
        keys:                      # one value, several keys (a block list: [a[0].b]
          - links[0].joint.drive.torque_constant         # is not valid flow YAML)
          - links[0].joint.drive.back_emf_constant
        dist: uniform
        low: 0.0272
        high: 0.0332
      - key: links[0].beam.damping.viscous_per_length
        dist: lognormal            # ln x ~ N(ln median, sigma²), truncated to [low, high]
        median: 2.0
        sigma: 0.5
        low: 0.5
        high: 8.0
      - key: tool.position[0]
        dist: normal               # N(mean, std²), truncated to [low, high] if given
        mean: 0.0
        std: 0.005
    metrics: [impact_time, bounce_height, "frequency:acc_A_true"]
    channel: tip_x                 # the envelope's channel (uncertainty)
    samples: 256                   # Monte Carlo samples
    seed: 0

Every draw goes through the inverse CDF of its distribution, ``x = F⁻¹(u)`` with ``u`` in
the unit cube: uniform ``x = low + u (high − low)``; truncated normal ``x = μ + σ
Φ⁻¹(Φ(a) + u (Φ(b) − Φ(a)))`` with ``a, b = (low − μ)/σ, (high − μ)/σ``; log-normal the
same on ``ln x``. Sensitivity analyses sample the unit cube (where the elementary effects
and the Sobol decomposition are taken, the map being monotone per coordinate) and send the
points through ``F⁻¹``. A distribution whose support leaves the schema's bounds of a key
(a normal on a resistance > 0 without ``low``) is refused before anything runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.ensemble.keys import check_numeric
from flexarm_ros.scene.yaml_input import load_yaml

DISTRIBUTIONS = ("uniform", "normal", "lognormal")
_FIELDS = {"uniform": {"low", "high"}, "normal": {"mean", "std", "low", "high"},
           "lognormal": {"median", "sigma", "low", "high"}}
_REQUIRED = {"uniform": {"low", "high"}, "normal": {"mean", "std"},
             "lognormal": {"median", "sigma"}}


@dataclass(frozen=True)
class Unknown:
    """An uncertain value set on one or several keys."""
    name: str
    keys: tuple
    dist: str
    par: dict

    @property
    def low(self) -> float:
        lo = self.par.get("low")
        if lo is not None:
            return float(lo)
        return 0.0 if self.dist == "lognormal" else -math.inf

    @property
    def high(self) -> float:
        hi = self.par.get("high")
        return math.inf if hi is None else float(hi)

    @property
    def bounded(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)

    def ppf(self, u):
        """Inverse CDF (see module doc) of ``u`` in [0, 1]."""
        from scipy.stats import norm
        u = np.asarray(u, float)
        if self.dist == "uniform":
            return self.low + u * (self.high - self.low)
        if self.dist == "normal":
            mu, sd = float(self.par["mean"]), float(self.par["std"])
            lo, hi = self.low, self.high
        else:
            mu, sd = math.log(float(self.par["median"])), float(self.par["sigma"])
            lo = math.log(self.low) if self.low > 0 else -math.inf
            hi = math.log(self.high) if math.isfinite(self.high) else math.inf
        a, b = norm.cdf((lo - mu) / sd), norm.cdf((hi - mu) / sd)
        z = norm.ppf(a + u * (b - a))
        x = mu + sd * z
        x = np.clip(x, lo, hi)
        return np.exp(x) if self.dist == "lognormal" else x

    def describe(self) -> str:
        par = ", ".join(f"{k} {v:g}" for k, v in self.par.items())
        return f"{self.dist}({par})"


@dataclass
class Spec:
    """A parsed spec (see module doc)."""
    scene: str
    unknowns: list
    metrics: list = field(default_factory=list)
    duration: float | None = None
    set: dict = field(default_factory=dict)
    channel: str | None = None
    samples: int = 256
    seed: int = 0
    path: Path | None = None

    @property
    def names(self) -> list[str]:
        return [u.name for u in self.unknowns]

    def assignments(self, unit_points) -> list[dict]:
        """Unit-cube points ``(n, d)`` → ``[{key: value}]`` (every key of an unknown gets
        its value)."""
        u = np.asarray(unit_points, float)
        cols = [unk.ppf(u[:, j]) for j, unk in enumerate(self.unknowns)]
        out = []
        for i in range(u.shape[0]):
            a = {}
            for j, unk in enumerate(self.unknowns):
                for k in unk.keys:
                    a[k] = float(cols[j][i])
            out.append(a)
        return out

    def named(self, assignment: dict) -> dict:
        """An assignment by unknown name (the table's parameter columns)."""
        return {u.name: assignment[u.keys[0]] for u in self.unknowns}

    def base_scene(self):
        """The scene with ``set`` applied (InputError naming the key)."""
        from flexarm_ros.ensemble.keys import set_keys
        from flexarm_ros.scene import load_scene
        name = self.scene
        if self.path is not None and (self.path.parent / name).is_file():
            name = str(self.path.parent / name)
        scene = load_scene(name)
        try:
            return set_keys(scene, self.set)
        except InputError as exc:
            raise InputError(f"{self._where('set')}: {' '.join(str(exc).split())}") from None

    def _where(self, key) -> str:
        return f"{self.path.name if self.path else 'spec'}: {key}"


def _num(where, key, v):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}.{key}: got {v!r}, expected a finite number")
    return float(v)


def _unknown(k: int, raw, where: str, check_keys: bool) -> Unknown:
    w = f"{where}unknowns[{k}]"
    if not isinstance(raw, dict):
        raise InputError(f"{w}: got {raw!r}, expected a mapping with key (or keys), dist and "
                         f"its parameters")
    allowed = {"name", "key", "keys", "dist"}
    keys = raw.get("keys", [raw["key"]] if "key" in raw else None)
    if not keys or not isinstance(keys, list) or not all(isinstance(x, str) for x in keys):
        raise InputError(f"{w}: got {raw!r}, expected key: PATH or keys: [PATH, ...]")
    dist = raw.get("dist")
    if dist not in DISTRIBUTIONS:
        raise InputError(f"{w}.dist: got {dist!r}, expected one of {', '.join(DISTRIBUTIONS)}")
    extra = set(raw) - allowed - _FIELDS[dist]
    if extra:
        raise InputError(f"{w}.{sorted(extra)[0]}: unknown key for dist {dist}; expected "
                         f"{', '.join(sorted(_FIELDS[dist]))}")
    missing = _REQUIRED[dist] - set(raw)
    if missing:
        raise InputError(f"{w}: missing {', '.join(sorted(missing))}, expected them for dist "
                         f"{dist}")
    par = {f: _num(w, f, raw[f]) for f in ("low", "high", "mean", "std", "median", "sigma")
           if f in raw and raw[f] is not None}
    for f in ("std", "sigma", "median"):
        if f in par and not par[f] > 0:
            raise InputError(f"{w}.{f}: got {par[f]:g}, expected a number > 0")
    name = str(raw.get("name") or keys[0])
    unk = Unknown(name, tuple(keys), dist, par)
    if unk.low >= unk.high:
        raise InputError(f"{w}: got low = {unk.low:g} >= high = {unk.high:g}, expected "
                         f"low < high")
    if dist == "lognormal" and "low" in par and not par["low"] > 0:
        raise InputError(f"{w}.low: got {par['low']:g}, expected a number > 0 (log-normal)")
    if check_keys:
        for key in keys:
            kf = check_numeric(key)
            lo_ok = kf.admits(unk.low) if math.isfinite(unk.low) else kf.lower()[0] is None
            hi_ok = kf.admits(unk.high) if math.isfinite(unk.high) else kf.upper()[0] is None
            if dist == "lognormal" and "low" not in par:       # support (0, inf)
                lo_ok = kf.lower()[0] is None or kf.lower()[0] <= 0.0
            if not (lo_ok and hi_ok):
                raise InputError(f"{w} ({key}): got {unk.describe()} with support "
                                 f"[{unk.low:g}, {unk.high:g}], expected a distribution inside "
                                 f"the schema's bounds {kf.bounds_text()} (give low/high "
                                 f"inside them)")
    return unk


def parse_spec(data, path: Path | None = None, check_keys: bool = True) -> Spec:
    """A spec mapping → Spec (InputError naming the entry, the value and the
    expectation). ``check_keys=False`` for specs of analytic models (no scene)."""
    where = f"{path.name}: " if path else ""
    if not isinstance(data, dict):
        raise InputError(f"{where}spec: got {data!r}, expected a mapping with scene and "
                         f"unknowns")
    allowed = {"scene", "unknowns", "metrics", "duration", "set", "channel", "samples", "seed"}
    extra = set(data) - allowed
    if extra:
        raise InputError(f"{where}{sorted(extra)[0]}: unknown key; expected one of "
                         f"{', '.join(sorted(allowed))}")
    unk_raw = data.get("unknowns")
    if not isinstance(unk_raw, list) or not unk_raw:
        raise InputError(f"{where}unknowns: got {unk_raw!r}, expected a list of at least one "
                         f"unknown")
    unknowns = [_unknown(k, u, where, check_keys) for k, u in enumerate(unk_raw)]
    names = [u.name for u in unknowns]
    if len(set(names)) != len(names):
        raise InputError(f"{where}unknowns: got names {names}, expected unique names")
    dur = data.get("duration")
    if dur is not None:
        dur = _num(f"{where}spec", "duration", dur)
        if not dur > 0:
            raise InputError(f"{where}duration: got {dur:g}, expected a number > 0 s")
    samples = data.get("samples", 256)
    seed = data.get("seed", 0)
    from flexarm_ros.ensemble.limits import check_samples, check_seed
    check_samples(samples, f"{where}samples")
    check_seed(seed, f"{where}seed")
    metrics = data.get("metrics") or []
    if not isinstance(metrics, list):
        raise InputError(f"{where}metrics: got {metrics!r}, expected a list of metric names")
    fixed = data.get("set") or {}
    if not isinstance(fixed, dict):
        raise InputError(f"{where}set: got {fixed!r}, expected a mapping of key path: value")
    return Spec(scene=str(data.get("scene") or "two_link_case1"), unknowns=unknowns,
                metrics=[str(m) for m in metrics], duration=dur, set=dict(fixed),
                channel=data.get("channel"), samples=samples, seed=seed, path=path)


def load_spec(path) -> Spec:
    from flexarm_ros.scene.yaml_input import read_yaml_text
    p = Path(path)
    text = read_yaml_text(p, "spec")
    data = load_yaml(text, str(p))           # bounded: depth, alias expansion, duplicates
    return parse_spec(data, p)
