"""Ensemble metrics by name: one number per simulated sample (SI units).

Names (``flexarm sweep --metric NAME``; the table column in brackets):

``impact_time`` [``impact_time_s``]
    time of the first located impact of the tool on the wall (the impulse rung's event
    time, :mod:`flexarm_ros.sim.contact_stepper`; compliant contact: the first sample with
    gap <= 0, interpolated as in :func:`flexarm_ros.analysis.run_metrics.first_touch`); NaN
    when the tool never reaches the wall. Always in the table of a scene with a wall.
``bounce_height`` [``bounce_height_m``]
    ``max(0, max gap)`` within 0.2 s after the first impact
    (:func:`flexarm_ros.analysis.metrics.bounce_height`, seed 000 Sec. 5: ~5 mm).
``max_tip_deflection`` [``max_tip_deflection_m``]
    ``max_t max_links |w_tip(t)|`` of the ``<link>_tip_deflection`` columns.
``frequency:CHANNEL[@A:B]`` [``frequency_<CHANNEL>_hz``]
    dominant frequency of a channel (output column or sensor-table column, e.g.
    ``acc_A_true``) by the interpolated Hann-windowed FFT
    (:func:`flexarm_ros.analysis.spectra.dominant_frequency`) over the window ``A:B`` s
    (``end`` allowed); default window: from 20 ms after the first impact to the end on a
    scene with a wall (post-impact vibration, as ``tools/reproduce_contact.py``), else
    the whole run; the peak is searched between 3 bins (3 / window) and fs / 2.5.
``settling_time:CHANNEL`` [``settling_time_<CHANNEL>_s``]
    the last time ``|y(t) − y(T)| > 0.02 |y(T) − y(0)|`` (2 % band around the final
    value, relative to the total change), 0 when the channel never leaves the band.
``final_error:CHANNEL=TARGET`` [``final_error_<CHANNEL>``]
    ``|y(T) − TARGET|`` in the channel's unit; ``final_error:CHANNEL`` (no target) takes
    the controller's own target at the end, the run's ``<CHANNEL>_target`` column
    (``link1_joint``, ``tool_x``: a position or sanding controller's targets).
``energy_drift`` [``energy_drift``]
    ``max_t |E − E(0)| / max_t T`` of :func:`flexarm_ros.analysis.run_metrics.energy_drift`,
    defined for a conservative scene (no inputs, no damping); NaN otherwise.
``wall_s_per_sim_s`` [``wall_s_per_sim_s``]
    integration wall seconds per simulated second (``SimResult.summary()``). A
    measurement of the machine: the one column that differs between two runs of the same
    ensemble.
``status``
    always in the table (``ok``, ``diverged``, ``refused``, ``error``); accepted as a name
    for completeness.

A metric that is undefined for a sample (no impact, a window without samples) is NaN;
an ensemble never stops for it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from flexarm_ros.analysis.run_metrics import energy_drift, first_touch
from flexarm_ros.errors import InputError

BOUNCE_WINDOW_S = 0.2
POST_IMPACT_DELAY_S = 0.02
SETTLING_BAND = 0.02
#: columns whose value depends on the machine's speed, not on the model
NONDETERMINISTIC = ("wall_s_per_sim_s",)

SIMPLE = ("impact_time", "bounce_height", "max_tip_deflection", "energy_drift",
          "wall_s_per_sim_s", "status")
PARAMETRIC = ("frequency", "settling_time", "final_error")
_UNITS = {"impact_time": "_s", "bounce_height": "_m", "max_tip_deflection": "_m",
          "energy_drift": "", "wall_s_per_sim_s": ""}


@dataclass(frozen=True)
class Metric:
    """A parsed metric name."""
    name: str                      # as given
    kind: str                      # impact_time, frequency, ...
    channel: str | None = None
    window: tuple | None = None    # (a, b) seconds; b may be inf
    target: float | None = None

    @property
    def column(self) -> str:
        if self.kind in _UNITS:
            return self.kind + _UNITS[self.kind]
        ch = _safe(self.channel)
        return {"frequency": f"frequency_{ch}_hz", "settling_time": f"settling_time_{ch}_s",
                "final_error": f"final_error_{ch}"}[self.kind]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


def parse_metric(text: str) -> Metric:
    """``'frequency:acc_A_true@2.2:end'`` → Metric; InputError for an unknown name."""
    t = str(text).strip()
    kind, _, rest = t.partition(":")
    expect = (f"expected one of {', '.join(SIMPLE)}, frequency:CHANNEL[@A:B], "
              f"settling_time:CHANNEL, final_error:CHANNEL=TARGET")
    if kind in SIMPLE:
        if rest:
            raise InputError(f"--metric: got {t!r}, {kind} takes no argument; {expect}")
        return Metric(t, kind)
    if kind not in PARAMETRIC:
        raise InputError(f"--metric: got {t!r}, {expect}")
    if kind == "frequency":
        ch, _, win = rest.partition("@")
        window = None
        if win:
            a, sep, b = win.partition(":")
            try:
                window = (float(a), math.inf if b.strip() == "end" else float(b))
            except ValueError:
                window = None
            if not sep or window is None or not window[0] < window[1] or window[0] < 0:
                raise InputError(f"--metric: got {t!r}, expected the window as @A:B seconds "
                                 f"with 0 <= A < B (B may be 'end')")
        if not ch:
            raise InputError(f"--metric: got {t!r}, expected frequency:CHANNEL (e.g. "
                             f"frequency:acc_A_true or frequency:link1_tip_deflection)")
        return Metric(t, kind, ch, window)
    if kind == "settling_time":
        if not rest:
            raise InputError(f"--metric: got {t!r}, expected settling_time:CHANNEL")
        return Metric(t, kind, rest)
    ch, sep, target = rest.partition("=")
    if ch and not sep:                 # the controller's own target: <channel>_target
        return Metric(t, kind, ch, target=None)
    try:
        value = float(target)
    except ValueError:
        value = math.nan
    if not ch or not math.isfinite(value):
        raise InputError(f"--metric: got {t!r}, expected final_error:CHANNEL=TARGET with a "
                         f"finite TARGET in the channel's unit, or final_error:CHANNEL "
                         f"for the controller's own target")
    return Metric(t, kind, ch, target=value)


#: input programs whose value changes during a run (a step or ramp in the command)
_CHANGING = ("step", "pulse", "square", "piecewise_constant", "piecewise_linear",
             "spin_up", "smooth_step")


def command_steps(scene, open_loop: bool = False) -> list[str]:
    """What steps or ramps the command of a run of ``scene`` (what a settling time settles
    after): a controller target away from the start (position mode), the sanding task's
    moves, an input program that changes or starts from rest at a non-zero value. Empty
    when the arm is only released (free vibration, a hold)."""
    out = []
    ctl = scene.control
    if ctl is not None and not open_loop and ctl.mode != "open_loop":
        if ctl.mode == "sanding":
            out.append("the sanding task's moves")
        elif ctl.joint_target and any(abs(a - lk.joint.angle0) > 0 for a, lk in
                                      zip(ctl.joint_target, scene.links)):
            out.append("control.joint_target")
        elif ctl.tip_target is not None:
            out.append("control.tip_target")
        return out
    for k, inp in enumerate(scene.inputs):
        prog = inp.program
        if prog.type in _CHANGING or (prog.type == "constant" and prog.value != 0.0):
            out.append(f"inputs[{k}].{inp.kind} ({prog.type})")
    return out


def resolve_metrics(names, scene, open_loop: bool = False) -> list[Metric]:
    """The metrics of an ensemble: the names given (default: max tip deflection), with
    impact_time first on a scene with a wall; duplicates dropped; checks that
    impact/bounce metrics have a wall and a settling time a step in the command
    (:func:`command_steps`)."""
    names = list(names or [])
    if not names:
        names = ["impact_time", "bounce_height", "max_tip_deflection"] if scene.walls else \
            ["max_tip_deflection"]
    out = [parse_metric(n) for n in names]
    out = [m for m in out if m.kind != "status"]
    if scene.walls and not any(m.kind == "impact_time" for m in out):
        out.insert(0, Metric("impact_time", "impact_time"))
    if not scene.walls:
        for m in out:
            if m.kind in ("impact_time", "bounce_height"):
                raise InputError(f"--metric: got {m.name!r} on scene {scene.name!r}, which has "
                                 f"no wall (walls: []), expected a scene with a wall")
    for m in out:
        if m.kind == "settling_time" and not command_steps(scene, open_loop):
            raise InputError(f"--metric: got {m.name!r} on scene {scene.name!r}, whose "
                             f"command has no step or ramp (no input program changes, no "
                             f"controller target), expected a scene with a step in its "
                             f"command (a step/pulse/square/piecewise program, or "
                             f"control.mode position with a target): a settling time "
                             f"settles after one")
    seen, uniq = set(), []
    for m in out:
        if m.column not in seen:
            seen.add(m.column)
            uniq.append(m)
    return uniq


# ------------------------------------------------------------------------- evaluation
def channel(res, name: str):
    """``(t, y)`` of an output column or a sensor-table column of a SimResult; KeyError
    listing the names when there is none."""
    cols = res.columns
    if name in cols and name != "t" and np.asarray(cols[name]).dtype.kind in "fiu":
        return np.asarray(cols["t"], float), np.asarray(cols[name], float)
    for rate in sorted(res.sensor_tables or {}):
        tab = res.sensor_tables[rate]
        if name in tab and name != "t":
            return np.asarray(tab["t"], float), np.asarray(tab[name], float)
    names = [k for k in cols if k != "t" and np.asarray(cols[k]).dtype.kind in "fiu"]
    for tab in (res.sensor_tables or {}).values():
        names += [k for k in tab if k != "t"]
    raise KeyError(f"channel {name!r} not in the run, expected one of {', '.join(names)}")


def impact_time(res) -> float:
    if res.contact is None:
        return math.nan
    return float(first_touch(res))


def _bounce(res) -> float:
    from flexarm_ros.analysis.metrics import bounce_height
    t0 = impact_time(res)
    if not math.isfinite(t0):
        return math.nan
    t = np.asarray(res.columns["t"], float)
    if not np.any(t > t0):
        return math.nan
    return float(bounce_height(t, np.asarray(res.columns["gap"], float), t0,
                               BOUNCE_WINDOW_S))


def _max_deflection(res) -> float:
    cols = [np.abs(np.asarray(v, float)) for k, v in res.columns.items()
            if k.endswith("_tip_deflection")]
    return float(max(c.max() for c in cols)) if cols else math.nan


def _frequency(res, m: Metric) -> float:
    from flexarm_ros.analysis.spectra import dominant_frequency
    t, y = channel(res, m.channel)
    if m.window is not None:
        a, b = m.window
    elif res.contact is not None:
        t0 = impact_time(res)
        if not math.isfinite(t0):
            return math.nan
        a, b = t0 + POST_IMPACT_DELAY_S, math.inf
    else:
        a, b = t[0], math.inf
    sel = (t >= a) & (t <= b)
    if np.count_nonzero(sel) < 16:
        return math.nan
    ts, ys = t[sel], y[sel]
    span = ts[-1] - ts[0]
    fs = (len(ts) - 1) / span
    try:
        return float(dominant_frequency(ts, ys, f_min=3.0 / span, f_max=fs / 2.5).frequency_hz)
    except ValueError:
        return math.nan


def _settling(res, m: Metric) -> float:
    t, y = channel(res, m.channel)
    change = abs(y[-1] - y[0])
    out = np.nonzero(np.abs(y - y[-1]) > SETTLING_BAND * change)[0]
    return float(t[out[-1]]) if len(out) and change > 0 else 0.0


def _final_error(res, m: Metric) -> float:
    t, y = channel(res, m.channel)
    if m.target is None:
        _, target = channel(res, f"{m.channel}_target")
        return float(abs(y[-1] - target[-1]))
    return float(abs(y[-1] - m.target))


def _energy_drift(res) -> float:
    v = energy_drift(res)
    return math.nan if v is None else float(v)


def evaluate(res, metrics) -> dict:
    """``{column: float}`` of the metrics on a SimResult (NaN where undefined)."""
    out = {}
    for m in metrics:
        if m.kind == "impact_time":
            v = impact_time(res)
        elif m.kind == "bounce_height":
            v = _bounce(res)
        elif m.kind == "max_tip_deflection":
            v = _max_deflection(res)
        elif m.kind == "frequency":
            v = _frequency(res, m)
        elif m.kind == "settling_time":
            v = _settling(res, m)
        elif m.kind == "final_error":
            v = _final_error(res, m)
        elif m.kind == "energy_drift":
            v = _energy_drift(res)
        elif m.kind == "wall_s_per_sim_s":
            s = res.summary()
            v = s["wall_time_s"] / s["sim_time_s"] if s["sim_time_s"] > 0 else math.nan
        else:                                               # pragma: no cover
            raise ValueError(m.kind)
        out[m.column] = float(v)
    return out
