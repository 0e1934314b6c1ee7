"""The estimate of a twin bag's arm from its bench topics (``flexarm estimate BAG``):
``encoders/counts`` and ``accelerometers/batch`` as the bench measured them, the commands
on ``motor_driver/commands`` as the controller sent them, through
:class:`flexarm_ros.estimation.kalman.ModelFilter`; and, where the bag has
``ground_truth/*``, the estimate scored against it (a truth the filter never reads).

Columns (one row per encoder tick): ``t [s]``, ``<link>_tip_deflection [m]`` (each link's
hub-frame transverse tip deflection of the estimated coordinates), ``tip_x [m]``,
``tip_y [m]`` (the estimated coordinates through the model's kinematics), ``nis [1]``
(the tick's normalized innovation squared per scalar measurement), ``event``
(``departure`` while the window's mean ν is above the χ² threshold).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.errors import InputError
from flexarm_ros.estimation.kalman import WINDOW_TICKS, Measurement, ModelFilter


def UNITS(column: str) -> str | None:
    """The unit of an estimate column (None: no unit)."""
    if column == "t":
        return "s"
    if column.endswith("_tip_deflection") or column in ("tip_x", "tip_y"):
        return "m"
    return "1" if column == "nis" else None


@dataclass
class Estimate:
    """What :func:`estimate_bag` found: the columns of the module doc, the score against
    the bag's ground truth (None without one), notes on the bag's topics, and the
    filter's CPU per encoder tick (µs: its updates, not the kinematics of the outputs)."""
    columns: dict
    score: dict | None
    notes: list = field(default_factory=list)
    cpu_per_tick_us: float = 0.0


def _events(bag, scene, ns):
    """Measurements and commands in time order: [(t_ns, order, kind, payload)]."""
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.recording import sensor_batches, twin_messages
    out = []
    enc = sorted((s for s in scene.sensors if s.kind == "encoder"), key=lambda s: s.joint)
    names = tuple(s.name for s in enc)
    counts = twin_messages(bag, T.ENCODER_COUNTS, ns)
    if not counts or not names:
        raise InputError(f"{bag.path}: no {T.resolve(ns, T.ENCODER_COUNTS)} messages or no "
                         f"encoder in the scene, expected the bench's encoder counts (the "
                         f"estimate is corrected by them at every tick)")
    for t, m in counts:
        v = np.asarray(m.data, float)
        if v.size != len(names):
            raise InputError(f"{bag.path}: {T.ENCODER_COUNTS} at {t} ns carries {v.size} "
                             f"counts, expected {len(names)} (the scene's encoders)")
        out.append((int(t), 2, "encoder", Measurement(int(t), "encoder", names, v)))
    for t, m in twin_messages(bag, T.COMMANDS, ns):
        out.append((int(t), 0, "command", np.asarray(m.data, float)))
    acc = sensor_batches(bag, T.ACCEL_BATCH, scene, ns)
    notes = []
    if acc is not None and acc.sensors:
        anames = tuple(acc.names)
        for t, row in zip(acc.t_ns, acc.values):
            out.append((int(t), 1, "accelerometer",
                        Measurement(int(t), "accelerometer", anames, row)))
        notes += acc.notes
    out.sort(key=lambda e: (e[0], e[1]))
    return out, notes


def check_sensors(sensors: str) -> None:
    """InputError unless ``sensors`` is a measurement set the filter reads."""
    if sensors not in ("all", "encoders"):
        raise InputError(f"--sensors: got {sensors!r}, expected all or encoders")


class Follower:
    """The filter fed one event at a time, in time order — (t_ns, order, kind, payload)
    with kind "command" (order 0, the command from t on), "accelerometer" (1) or
    "encoder" (2, a :class:`~flexarm_ros.estimation.kalman.Measurement`) — as the bag
    estimate and the live ``estimator`` node both feed it. :meth:`feed` returns the row
    of an encoder tick: (t s, the estimated full coordinates, ν per dof, event)."""

    def __init__(self, scene, sensors: str = "all", process_share=None, accelerometers=True):
        check_sensors(sensors)
        kw = {} if process_share is None else {"process_share": process_share}
        self.use_acc = sensors == "all" and accelerometers and any(
            s.kind == "accelerometer" for s in scene.sensors)
        self.filter = ModelFilter(scene, disturbance=self.use_acc, **kw)
        self.nis, self.dof, self.window, self.threshold = 0.0, 0, [], None
        self.cpu_s, self.ticks = 0.0, 0

    def feed(self, t, kind, payload):
        c0 = time.process_time()
        try:
            return self._feed(t, kind, payload)
        finally:
            self.cpu_s += time.process_time() - c0

    def _feed(self, t, kind, payload):
        f = self.filter
        if kind == "command":
            f.predict_to(t)
            f.command(payload)
            return None
        if kind == "accelerometer" and not self.use_acc:
            return None
        f.predict_to(t)
        v, dof = f.update(payload)
        self.nis, self.dof = self.nis + v, self.dof + dof
        if kind != "encoder":
            return None
        self.ticks += 1
        per = self.nis / max(self.dof, 1)
        if self.threshold is None:
            self.threshold = f.departure_threshold(self.dof)
        self.window.append(per)
        if len(self.window) > WINDOW_TICKS:
            self.window.pop(0)
        event = ("departure" if len(self.window) == WINDOW_TICKS
                 and np.mean(self.window) > self.threshold else "")
        self.nis, self.dof = 0.0, 0
        return t * 1e-9, f.full_q(), per, event

    @property
    def cpu_per_tick_us(self) -> float:
        return self.cpu_s / max(self.ticks, 1) * 1e6


def estimate_bag(path, scene=None, sensors: str = "all", process_share=None,
                 progress=None) -> Estimate:
    """The estimate of the bag at ``path`` with ``scene`` (default: the scene it recorded)
    and the measurements ``sensors`` ("all" or "encoders")."""
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.twin.recording import embedded_scene, namespace
    check_sensors(sensors)                  # before the bag is read
    bag = read_bag(path)
    rig = embedded_scene(bag)
    scene = scene or rig
    if scene is None:
        raise InputError(f"--scene: got none for {path}, which embeds no scene; expected "
                         f"the scene to estimate with")
    ns = namespace(bag)
    events, notes = _events(bag, scene, ns)
    fol = Follower(scene, sensors, process_share,
                   accelerometers=any(e[2] == "accelerometer" for e in events))
    rows = []
    for k, (t, _, kind, payload) in enumerate(events):
        row = fol.feed(t, kind, payload)
        if row is not None:
            rows.append(row)
            if progress is not None and len(rows) % 500 == 0:
                progress(k / len(events))
    cols = output_columns(fol.filter.chain, [lk.name for lk in scene.links], rows)
    score = _score(bag, rig or scene, ns, cols, [lk.name for lk in scene.links])
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.recording import twin_messages
    touch = [t for t, m in twin_messages(bag, T.TOOL_CONTACT, ns) if bool(m.data)]
    if touch:
        notes.append(f"the tool touches the wall from {touch[0] * 1e-9:.4g} s: the filter "
                     f"does not model contact, and its estimate from there on is outside "
                     f"what it was measured on (docs/estimation.md)")
    return Estimate(cols, score, notes, fol.cpu_per_tick_us)


def output_columns(chain, links, rows) -> dict:
    """The columns of the module doc from the Follower's rows."""
    qs = [r[1] for r in rows]
    defl = np.array([chain.tip_deflections(q) for q in qs]).reshape(len(qs), len(links))
    tip = np.array([chain.tip_position(q) for q in qs]).reshape(len(qs), 2)
    cols = {"t": np.array([r[0] for r in rows])}
    for j, name in enumerate(links):
        cols[f"{name}_tip_deflection"] = defl[:, j]
    cols["tip_x"], cols["tip_y"] = tip[:, 0], tip[:, 1]
    cols["nis"] = np.array([r[2] for r in rows])
    cols["event"] = [r[3] for r in rows]
    return cols


def _score(bag, rig, ns, cols, links):
    """RMSE and largest error per link as fractions of the true peak deflection, and of the
    tip position in m, against ``ground_truth/coordinates`` and ``ground_truth/tip`` at the
    estimate's ticks; None without them."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.recording import twin_messages
    coords = twin_messages(bag, T.GT_COORDINATES, ns)
    tips = twin_messages(bag, T.GT_TIP, ns)
    if not coords or not tips:
        return None
    chain = Chain(rig)
    t_ns = np.round(cols["t"] * 1e9).astype(np.int64)
    by_t = {int(t): m for t, m in coords}
    tip_t = {int(t): m for t, m in tips}
    rows = [(k, by_t[int(t)], tip_t[int(t)]) for k, t in enumerate(t_ns)
            if int(t) in by_t and int(t) in tip_t]
    if not rows:
        return None
    idx = [k for k, _, _ in rows]
    true_d = []
    for _, m, _ in rows:
        order = {n: i for i, n in enumerate(m.name)}
        q = np.array([m.position[order[n]] for n in chain.names])
        true_d.append(chain.tip_deflections(q))
    true_d = np.array(true_d)
    true_tip = np.array([[p.point.x, p.point.y] for _, _, p in rows])
    out = {"ticks": len(rows), "links": {}}
    for j, name in enumerate(links):
        est = np.asarray(cols[f"{name}_tip_deflection"])[idx]
        err = est - true_d[:, j]
        peak = float(np.max(np.abs(true_d[:, j])))
        out["links"][name] = {
            "peak_m": peak, "rmse_m": float(np.sqrt(np.mean(err ** 2))),
            "max_error_m": float(np.max(np.abs(err))),
            "rmse_of_peak": float(np.sqrt(np.mean(err ** 2)) / peak) if peak > 0 else None,
            "max_error_of_peak": float(np.max(np.abs(err)) / peak) if peak > 0 else None}
    e = np.hypot(np.asarray(cols["tip_x"])[idx] - true_tip[:, 0],
                 np.asarray(cols["tip_y"])[idx] - true_tip[:, 1])
    out["tip_rmse_m"] = float(np.sqrt(np.mean(e ** 2)))
    out["tip_max_error_m"] = float(np.max(e))
    return out
