"""Building a calibration problem: a record's channels on the twin's names, the window,
the clock offset, the noise scales; the spec form (several cases sharing parameters).

Spec (YAML)::

    parameters:                        # shared by every case
      - key: links[0].joint.drive.resistance
        low: 0.8
        high: 1.6
        start: 1.085                   # optional (default: the first case's scene value)
      - keys:                          # one value, several keys
          - links[0].joint.drive.torque_constant
          - links[0].joint.drive.back_emf_constant
        low: 0.02
        high: 0.04
      - name: resistance_factor        # one factor on several keys' scene values
        scale:                         # a block list ([a[0].b] is not flow YAML)
          - links[0].joint.drive.resistance
          - links[1].joint.drive.resistance
        low: 0.8
        high: 1.25
    cases:
      - name: case1
        scene: two_link_case1          # shipped name or path (relative to this file)
        record: case1.csv              # optional: a CSV or MCAP `flexarm compare` reads
        map: map.yaml                  # optional channel map of a foreign record
        channels: [acc_A, acc_C]       # default: every record channel the twin has
        sigma: {acc_A: 0.002}          # noise (1σ, the channel's unit); default: a scale
        weights: {acc_A: 1.0}
        window: [2.2, 3.4]             # s, record clock
        offset: none                   # none | auto | seconds
        duration: 3.5                  # s simulated (default: the scene's)
        set: {fidelity.rung: cubic}    # fixed changes to this case's scene
        targets:                       # features with uncertainties (1σ)
          - {metric: impact_time, value: 2.10, sigma: 0.005}
          - {metric: "frequency:acc_A_true@2.2:3.4", value: 10.96, sigma: 0.2}
    starts: 1
    seed: 0
    diff_step: 1.0e-3
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from flexarm_ros.calibration.observables import Case, FeatureTarget, SeriesTarget, parse_feature
from flexarm_ros.calibration.parameters import (check_distinct, make_param, make_scale,
                                                start_assignment)
from flexarm_ros.errors import InputError
from flexarm_ros.scene.yaml_input import load_yaml

SKIP = {"contact", "contact_phase"}      # flags: not a residual a gradient can follow
MAX_SHIFT_S = 0.1                        # --offset auto: the cross-correlation's search


def _scene_file(name, base_dir: Path | None) -> Path:
    from flexarm_ros.scene.loading import resolve_scene_path
    if base_dir is not None and name and not Path(str(name)).is_absolute():
        cand = base_dir / str(name)
        if cand.exists():
            return cand
    return resolve_scene_path(name)


def _twin_channels(res, scene) -> dict:
    """{name: unit} of every numeric channel of a run (output and sensor tables)."""
    from flexarm_ros.io.units import column_unit
    sensors = tuple(scene.sensors or ())
    names = [k for k, v in res.columns.items()
             if k != "t" and np.asarray(v).dtype.kind in "fiu"]
    for tab in (res.sensor_tables or {}).values():
        names += [k for k in tab if k != "t"]
    return {k: column_unit(k, sensors) or "" for k in names}


def parse_offset(value):
    if value is None or value == "none":
        return "none"
    if value == "auto":
        return "auto"
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not math.isfinite(v):
        raise InputError(f"offset: got {value!r}, expected none, auto or seconds")
    return v


def parse_window(value, where="window"):
    if value is None:
        return None
    if isinstance(value, str):
        parts = value.split(":")
    else:
        parts = list(value)
    try:
        a, b = (float(x) for x in parts)
    except (TypeError, ValueError):
        raise InputError(f"{where}: got {value!r}, expected A:B in s with A < B") from None
    if not (math.isfinite(a) and math.isfinite(b) and a < b):
        raise InputError(f"{where}: got {value!r}, expected A:B in s with A < B")
    return a, b


def check_targets(name, scene, duration, feats) -> None:
    """Each feature can be evaluated on this scene before anything runs: a wall for the
    impact and the bounce, the channel of a frequency, settling time or value in the run,
    the time of a value inside it, the mode number among the model's; InputError else."""
    from flexarm_ros.calibration.observables import mode_frequency
    channels = []
    for i, f in enumerate(feats):
        where = f"{name}: targets[{i}] {f.metric!r}"
        pf = parse_feature(f.metric)
        if isinstance(pf, tuple) and pf[0] == "mode":
            if not math.isfinite(mode_frequency(scene, pf[1], pf[2])):
                raise InputError(f"{where}: the model has fewer than {pf[1]} natural "
                                 f"frequencies (flexarm modes lists them), expected K within")
            continue
        if isinstance(pf, tuple):
            if not 0.0 <= pf[2] <= duration:
                raise InputError(f"{where}: time {pf[2]:g} s, expected one inside the run "
                                 f"0..{duration:g} s")
            channels.append((pf[1], where))
            continue
        if pf.kind in ("impact_time", "bounce_height") and not scene.walls:
            raise InputError(f"{where}: the scene has no wall, expected a scene with walls "
                             f"for {pf.kind}")
        if pf.channel:
            channels.append((pf.channel, where))
    if channels:                    # the probe of the ensemble commands (two samples)
        from flexarm_ros.ensemble.cli import check_channels
        from flexarm_ros.ensemble.metrics import Metric
        for ch, where in channels:
            try:
                check_channels(scene, [Metric(ch, "frequency", ch)], duration=duration)
            except InputError as exc:
                raise InputError(f"{where}: {str(exc).split(': ', 1)[1]}") from None


def system_of_record(scene, record=None, open_loop: bool = False):
    """``scene`` as the system that made ``record`` runs it. A twin bag (an MCAP with the
    twin's embedded scene) was made by the twin's loop — controller and driver at the
    control rate, the efforts held over each period — so a scene that declares no
    controller gets the bag's control section (its default: the input programs sampled
    at 1 kHz); a scene that declares one keeps it. With ``open_loop`` (--open-loop) or
    any other record the scene is returned as it is (batch runs follow
    :func:`flexarm_ros.twin.batch.run_scene`)."""
    import dataclasses
    if open_loop or record is None or scene.control is not None \
            or Path(str(record)).suffix.lower() == ".csv" or not Path(str(record)).is_file():
        return scene
    from flexarm_ros.analysis.channels import scene_of_bag
    from flexarm_ros.bag.reader import BagError, read_bag
    try:
        bag_scene, _ = scene_of_bag(read_bag(str(record)))
    except (BagError, OSError):
        return scene                       # make_case reports what is wrong with it
    if bag_scene is None:                  # a foreign bag: a rig's record
        return scene
    return dataclasses.replace(scene, control=bag_scene.twin_control)


def describe_system(case) -> str:
    """How a case's model runs, in words (the calibration's summary)."""
    from flexarm_ros.twin.batch import closed_loop
    sc = case.scene
    if closed_loop(sc, case.open_loop):
        ctl = sc.control
        if ctl.mode == "open_loop":
            return (f"the twin's loop: the input programs sampled at {ctl.rate_hz:.6g} Hz "
                    f"by the controller, the efforts held over each period by the driver")
        return (f"closed loop: control.mode {ctl.mode} at {ctl.rate_hz:.6g} Hz, the efforts "
                f"held over each period (the twin's loop)")
    return "open loop: the input programs applied continuously"


def make_case(name, scene, record=None, channel_map=None, channels=None, sigma=None,
              weights=None, window=None, offset="none", duration=None, targets=(),
              probe=None, open_loop: bool = False) -> Case:
    """A checked :class:`Case`. ``probe``: the twin's run at the start values (to learn
    its channel names, and for ``offset='auto'``); made here when None. ``open_loop``:
    the input programs alone where the scene declares a controller."""
    from flexarm_ros.twin.batch import run_scene
    duration = float(duration if duration is not None else scene.duration)
    if not (math.isfinite(duration) and duration > 0):
        raise InputError(f"{name}: duration got {duration}, expected a finite number > 0 s")
    feats = []
    for i, t in enumerate(targets or ()):
        where = f"{name}: targets[{i}]"
        if not isinstance(t, dict) or "metric" not in t or "value" not in t:
            raise InputError(f"{where}: got {t!r}, expected a mapping with metric, value "
                             f"and sigma")
        parse_feature(t["metric"])
        v, s, w = t.get("value"), t.get("sigma"), t.get("weight", 1.0)
        for x, what, pos in ((v, "value", False), (s, "sigma", True), (w, "weight", True)):
            if not isinstance(x, (int, float)) or not math.isfinite(x) or (pos and x <= 0):
                raise InputError(f"{where}.{what}: got {x!r}, expected a finite number"
                                 f"{' > 0' if pos else ''}")
        feats.append(FeatureTarget(str(t["metric"]), float(v), float(s), float(w)))
    check_targets(name, scene, duration, feats)
    series = []
    off = parse_offset(offset)
    if record is None:
        if channels:
            raise InputError(f"{name}: channels given without a record, expected a record "
                             f"(CSV or MCAP) to take them from")
        if not feats:
            raise InputError(f"{name}: nothing to fit, expected a record or targets")
        return Case(name, scene, duration, [], feats, 0.0, None, open_loop=open_loop)
    from flexarm_ros.analysis.channels import load_channels, same_unit
    from flexarm_ros.io.experiment import load_channel_map
    cmap = load_channel_map(channel_map) if channel_map else None
    cs = load_channels(record, cmap)
    if probe is None:
        with np.errstate(all="ignore"):
            probe = run_scene(scene, duration, open_loop=open_loop)
    twin = _twin_channels(probe, scene)
    if channels:
        want = list(channels)
        for c in want:
            if c not in cs:
                raise InputError(f"--channels: got {c!r}, not in the record {record}; "
                                 f"expected one of {', '.join(cs.names)}")
            if c not in twin:
                raise InputError(f"--channels: got {c!r}, a channel the twin does not "
                                 f"produce for this scene; expected one of "
                                 f"{', '.join(sorted(twin))}")
    else:
        want = [c for c in cs.names if c in twin and c not in SKIP]
        ignored = [c for c in cs.names if c not in twin and c not in SKIP]
        if ignored:
            import sys
            print(f"calibrate: {name}: record channels the twin does not produce, not "
                  f"fitted: {', '.join(ignored)}", file=sys.stderr)
        if not want:
            raise InputError(f"{record}: no channel the twin also produces (record: "
                             f"{', '.join(cs.names) or 'none'}; twin: "
                             f"{', '.join(sorted(twin))}), expected matching names or a "
                             f"channel map (--map)")
    win = parse_window(window)
    sigma = dict(sigma or {})
    weights = dict(weights or {})
    for d, what in ((sigma, "sigma"), (weights, "weights")):
        for c, v in d.items():
            if c not in want:
                raise InputError(f"{name}: {what} for {c!r}, a channel not fitted (fitted: "
                                 f"{', '.join(want)})")
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InputError(f"{name}: {what}.{c}: got {v!r}, expected a finite "
                                 f"number > 0")
    if off == "auto":
        from flexarm_ros.analysis.metrics import estimate_offset
        from flexarm_ros.ensemble.metrics import channel as run_channel
        ests = []
        for c in want:
            t, y = run_channel(probe, c)
            try:
                ests.append(estimate_offset(cs[c].t, cs[c].y, t, y, MAX_SHIFT_S))
            except ValueError:
                pass
        off = float(np.median(ests)) if ests else 0.0
    elif off == "none":
        off = 0.0
    for c in want:
        ch = cs[c]
        u_tw = twin.get(c, "")
        if ch.unit and u_tw and not same_unit(ch.unit, u_tw):
            raise InputError(f"{record}: channel {c!r} in {ch.unit}, the twin's in {u_tw}; "
                             f"expected the same unit (a channel map can scale it)")
        a, b = win if win is not None else (ch.t[0], ch.t[-1])
        lo, hi = max(a, probe.run.t[0] - off), min(b, duration - off)
        sel = (ch.t >= lo) & (ch.t <= hi)
        if np.count_nonzero(sel) < 2:
            raise InputError(f"{record}: channel {c!r} has no samples in the fitted window "
                             f"{lo:g}..{hi:g} s (record {ch.t[0]:g}..{ch.t[-1]:g} s, run "
                             f"0..{duration:g} s, offset {off:g} s), expected an overlap")
        t, y = ch.t[sel], ch.y[sel]
        given = c in sigma
        s = float(sigma[c]) if given else float(np.std(y))
        if not s > 0:
            s = float(np.max(np.abs(y))) or 1.0
        series.append(SeriesTarget(c, t, y, s, given, ch.unit or u_tw,
                                   float(weights.get(c, 1.0))))
    return Case(name, scene, duration, series, feats, float(off), str(record),
                open_loop=open_loop)


def _mapping(data, where):
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"{where}: got {data!r}, expected a mapping")
    return data


def load_spec(path):
    """(params, cases, options) from a spec file (see the module doc)."""
    from flexarm_ros.ensemble.keys import set_keys
    p = Path(path)
    if not p.exists():
        raise InputError(f"spec: {p}: no such file, expected a calibration spec (YAML)")
    try:
        from flexarm_ros.scene.yaml_input import read_yaml_text
        data = load_yaml(read_yaml_text(p, "calibration spec"),
                         f"spec: {p}")           # bounded: depth, aliases, duplicates
    except InputError as exc:
        hint = ("; a key path with [i] inside [ ] is not flow YAML: write a block list "
                "(- links[0]...) or quote it" if "flow sequence" in str(exc) else "")
        raise InputError(f"{exc}{hint}") from None
    data = _mapping(data, f"spec {p}")
    unknown = set(data) - {"parameters", "cases", "starts", "seed", "diff_step",
                           "max_evaluations"}
    if unknown:
        raise InputError(f"spec: unknown key {sorted(unknown)[0]!r}, expected parameters, "
                         f"cases, starts, seed, diff_step, max_evaluations")
    cases_raw = data.get("cases")
    if not isinstance(cases_raw, list) or not cases_raw:
        raise InputError(f"spec: cases: got {cases_raw!r}, expected a list of cases")
    scenes, files = [], []
    for i, c in enumerate(cases_raw):
        c = _mapping(c, f"cases[{i}]")
        if "scene" not in c:
            raise InputError(f"cases[{i}]: no scene, expected a scene name or path")
        from flexarm_ros.scene import load_scene
        try:
            files.append(_scene_file(c["scene"], p.parent))
            sc = load_scene(files[-1])
        except InputError as exc:
            raise InputError(f"cases[{i}].scene: {exc}") from None
        fixed = _mapping(c.get("set"), f"cases[{i}].set")
        scenes.append(set_keys(sc, fixed) if fixed else sc)
    praw = data.get("parameters")
    if not isinstance(praw, list) or not praw:
        raise InputError(f"spec: parameters: got {praw!r}, expected a list of "
                         f"{{key, low, high}}")
    params = []
    for i, e in enumerate(praw):
        e = _mapping(e, f"parameters[{i}]")
        extra = set(e) - {"key", "keys", "scale", "name", "low", "high", "start"}
        if extra:
            raise InputError(f"parameters[{i}]: unknown key {sorted(extra)[0]!r}, expected "
                             f"key (or keys, or name + scale), low, high, start")
        if "scale" in e:
            keys = e["scale"] if isinstance(e["scale"], list) else [e["scale"]]
            params.append(make_scale(e.get("name"), keys, e.get("low"), e.get("high"),
                                     e.get("start"), scenes[0], f"parameters[{i}]"))
            continue
        keys = e.get("keys") or ([e["key"]] if "key" in e else None)
        if not keys:
            raise InputError(f"parameters[{i}]: got {e!r}, expected key:, keys: or scale:")
        params.append(make_param(keys, e.get("low"), e.get("high"), e.get("start"),
                                 scenes[0], where=f"parameters[{i}]"))
    check_distinct(params, "parameters:")
    cases = []
    start = start_assignment(params)
    for i, (c, sc) in enumerate(zip(cases_raw, scenes)):
        rec = c.get("record")
        if rec is not None and not Path(str(rec)).is_absolute():
            rec = p.parent / str(rec)
        cmap = c.get("map")
        if cmap is not None and not Path(str(cmap)).is_absolute():
            cmap = p.parent / str(cmap)
        extra = set(c) - {"name", "scene", "record", "map", "channels", "sigma", "weights",
                          "window", "offset", "duration", "set", "targets", "open_loop"}
        if extra:
            raise InputError(f"cases[{i}]: unknown key {sorted(extra)[0]!r}, expected name, "
                             f"scene, record, map, channels, sigma, weights, window, offset, "
                             f"duration, set, targets, open_loop")
        open_loop = c.get("open_loop", False)
        if not isinstance(open_loop, bool):
            raise InputError(f"cases[{i}].open_loop: got {open_loop!r}, expected true or "
                             f"false")
        sc = system_of_record(sc, rec, open_loop)
        probe = None
        if rec is not None:
            from flexarm_ros.twin.batch import run_scene
            with np.errstate(all="ignore"):
                probe = run_scene(set_keys(sc, start), c.get("duration", sc.duration),
                                  open_loop=open_loop)
        case = make_case(c.get("name", f"case{i + 1}"), sc, rec, cmap,
                         c.get("channels"), c.get("sigma"), c.get("weights"),
                         c.get("window"), c.get("offset", "none"), c.get("duration"),
                         c.get("targets") or (), probe, open_loop)
        case.scene_file = None if c.get("set") else str(files[i])
        cases.append(case)
    names = [c.name for c in cases]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"cases: name {dup[0]!r} given twice, expected one name per case "
                         f"(each names its calibrated scene)")
    opts = {"starts": data.get("starts", 1), "seed": data.get("seed", 0),
            "diff_step": data.get("diff_step", 1e-3),
            "max_evaluations": data.get("max_evaluations")}
    return params, cases, opts
