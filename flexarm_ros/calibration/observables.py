"""What a calibration compares: time series of a record and features with uncertainties,
per case (one scene, one record or none), as weighted residuals.

Residuals (the vector the least-squares fit makes small):

* a **time series** channel ``c`` of a record, samples (t_k, y_k) in the fitted window:
  r_k = w_c (y_twin(t_k + offset) − y_k) / σ_c, with y_twin linearly interpolated on the
  twin's own grid of that channel and ``offset`` the record's clock shift
  (:func:`flexarm_ros.analysis.metrics.estimate_offset`'s convention, y_twin(t + offset) ≈
  y_record(t)); σ_c the channel's noise when given (then the residuals are in units of
  the noise), else the record's standard deviation in the window (a scale, not a noise:
  the fit's covariance then takes the noise level from the residuals);
* a **feature** target: r = w (m − value) / σ, with m one of the ensemble metrics
  (``impact_time``, ``bounce_height``, ``max_tip_deflection``, ``frequency:CH[@A:B]``,
  ``settling_time:CH``, ``energy_drift``; :mod:`flexarm_ros.ensemble.metrics`) or
  ``value:CH@T`` (the channel at time T, linear interpolation: a static deflection, an
  angle at the end of a move) evaluated on the twin's run, or ``mode:K[@locked|@free]``
  (the K-th natural frequency in Hz of the chain linearized at the scene's initial
  configuration, as ``flexarm modes`` prints it: joints locked when the scene has
  inputs unless given; no simulation is run for a case whose targets are all modes).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.errors import InputError

_VALUE = re.compile(r"^value:([^@\s]+)@([-+0-9.eE]+)$")
_MODE = re.compile(r"^mode:(\d+)(?:@(locked|free))?$")


@dataclass(frozen=True)
class SeriesTarget:
    """One record channel in the fitted window (times already on the record's clock)."""
    channel: str
    t: np.ndarray
    y: np.ndarray
    sigma: float
    sigma_given: bool
    unit: str = ""
    weight: float = 1.0

    @property
    def size(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class FeatureTarget:
    """A feature of the run with its measured value and uncertainty (1σ)."""
    metric: str
    value: float
    sigma: float
    weight: float = 1.0

    @property
    def size(self) -> int:
        return 1


@dataclass
class Case:
    """One scene (with its fixed changes applied) against one record and/or features."""
    name: str
    scene: object
    duration: float
    series: list = field(default_factory=list)      # SeriesTarget
    features: list = field(default_factory=list)    # FeatureTarget
    offset_s: float = 0.0
    record: str | None = None
    scene_file: str | None = None     # the scene's file (its own spelling for --out)
    # the input programs alone even where the scene declares a controller (--open-loop);
    # else the run is twin.batch.run_scene's: a controller in the loop when declared
    open_loop: bool = False

    @property
    def size(self) -> int:
        return sum(s.size for s in self.series) + len(self.features)

    def labels(self) -> list[str]:
        """One label per residual block: ``case/channel`` or ``case/metric``."""
        return ([f"{self.name}/{s.channel}" for s in self.series]
                + [f"{self.name}/{f.metric}" for f in self.features])


def parse_feature(text: str):
    """A feature name → ('value', channel, time) or the ensemble Metric; InputError else."""
    m = _VALUE.match(text.strip()) if isinstance(text, str) else None
    if m:
        return ("value", m.group(1), float(m.group(2)))
    m = _MODE.match(text.strip()) if isinstance(text, str) else None
    if m:
        if int(m.group(1)) < 1:
            raise InputError(f"targets: got {text!r}, expected mode:K with K >= 1")
        return ("mode", int(m.group(1)), m.group(2))
    if isinstance(text, str) and text.startswith("mode:"):
        raise InputError(f"targets: got {text!r}, expected mode:K[@locked|@free] (K >= 1, "
                         f"the K-th natural frequency in Hz)")
    if isinstance(text, str) and text.startswith("value:"):
        raise InputError(f"targets: got {text!r}, expected value:CHANNEL@TIME (e.g. "
                         f"value:link1_tip_deflection@2.0)")
    from flexarm_ros.ensemble.metrics import parse_metric
    try:
        m = parse_metric(text)
    except InputError:
        raise InputError(f"targets: got {text!r}, expected impact_time, bounce_height, "
                         f"max_tip_deflection, frequency:CH[@A:B], settling_time:CH, "
                         f"energy_drift, value:CH@T or mode:K[@locked|@free]") from None
    if m.kind in ("final_error", "wall_s_per_sim_s"):
        raise InputError(f"targets: got {text!r}, expected a feature with a value to meet: "
                         f"impact_time, bounce_height, max_tip_deflection, "
                         f"frequency:CH[@A:B], settling_time:CH, energy_drift, value:CH@T")
    return m


def mode_frequency(scene, k: int, joints=None) -> float:
    """The k-th natural frequency (Hz) at the scene's initial configuration (``flexarm
    modes``: rigid-body modes at 0 Hz count), NaN when the model has fewer."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.linear import natural_modes
    from flexarm_ros.model.statics import initial_state
    chain = Chain(scene)
    joints = joints or ("locked" if scene.inputs else "free")
    f = natural_modes(chain, initial_state(chain)[0], joints).frequencies_hz
    return float(f[k - 1]) if k <= len(f) else math.nan


def only_modes(parsed) -> bool:
    return bool(parsed) and all(isinstance(f, tuple) and f[0] == "mode" for f in parsed)


def feature_value(res, feature, scene=None) -> float:
    """The feature evaluated on a SimResult (NaN where undefined, e.g. no impact)."""
    from flexarm_ros.ensemble.metrics import channel, evaluate
    if isinstance(feature, tuple) and feature[0] == "mode":
        return mode_frequency(scene, feature[1], feature[2])
    if isinstance(feature, tuple):
        _, name, at = feature
        t, y = channel(res, name)
        if not t[0] <= at <= t[-1]:
            return math.nan
        return float(np.interp(at, t, y))
    return float(evaluate(res, [feature])[feature.column])


def series_residuals(res, s: SeriesTarget, offset_s: float) -> np.ndarray:
    from flexarm_ros.ensemble.metrics import channel
    t, y = channel(res, s.channel)
    tt = s.t + offset_s
    twin = np.interp(tt, t, y, left=np.nan, right=np.nan)
    return s.weight * (twin - s.y) / s.sigma


def case_residuals(res, case: Case, parsed_features, scene=None) -> tuple[np.ndarray, list,
                                                                          list]:
    """(residual vector, feature values, per-series RMS error in the channel's unit);
    ``scene``: the case's scene with the sample's values (for ``mode:K``)."""
    parts, rms = [], []
    for s in case.series:
        r = series_residuals(res, s, case.offset_s)
        parts.append(r)
        rms.append(float(np.sqrt(np.mean((r * s.sigma / s.weight) ** 2))))
    values = []
    for f, pf in zip(case.features, parsed_features):
        v = feature_value(res, pf, scene)
        values.append(v)
        parts.append(np.array([f.weight * (v - f.value) / f.sigma]))
    vec = np.concatenate(parts) if parts else np.zeros(0)
    return vec, values, rms
