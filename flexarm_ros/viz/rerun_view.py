"""Log a recorded twin bag to rerun (https://rerun.io) on the ``sim_time`` timeline.

rerun-sdk is optional (``pip install -e .[viz]``) and imported only by the functions that
need it; without it they raise :class:`RerunUnavailable` saying how to install it.

Entity paths (positions in metres, world frame, on the plane z = 0 seen from +z; the
table with what each holds is in docs/viewing.md): ``world/wall`` (static),
``world/arm/<link>``, ``world/tool``, ``world/tip_path`` (shape frames),
``world/contact_force`` (arrow F_n·n + F_t·t at the tool, every ``tool/wrench`` with
F ≠ 0, cleared at F = 0), and scalars ``plots/joint_angles/{measured,true}/<name>``,
``plots/{accelerometers,strain,potentiometers}/<sensor>`` (one row per sample),
``plots/contact/{in_contact,normal_force,friction_force}``, ``plots/commands/<link>``.

Shape frames are the ``ground_truth/coordinates`` messages thinned to at most
``shape_rate_hz`` (default 100 Hz); the traces keep every message/sample.
"""

from __future__ import annotations

import math
import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm_ros.twin import topics as T
from flexarm_ros.viz.bag_view import BagView, thin

__all__ = ["TIMELINE", "RerunUnavailable", "ViewOptions", "bag_to_rerun", "blueprint",
           "log_view", "require_rerun", "spawn_check", "start_viewer"]

TIMELINE = "sim_time"
"""The rerun timeline (a duration: the simulation time, ns resolution)."""

BATCH_ENTITIES = {T.ACCEL_BATCH: "plots/accelerometers", T.STRAIN_BATCH: "plots/strain",
                  T.POT_BATCH: "plots/potentiometers", T.TIP_BATCH: "plots/tip_position"}

_LINK_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189),
                (140, 86, 75), (227, 119, 194)]


class RerunUnavailable(RuntimeError):
    """rerun-sdk is missing, or no viewer can be started (no display)."""


def require_rerun():
    """The ``rerun`` module, or :class:`RerunUnavailable` with the install command."""
    try:
        import rerun
    except ImportError as err:
        raise RerunUnavailable("the rerun view needs rerun-sdk, which is not installed: "
                               "pip install -e .[viz]  (or: pip install rerun-sdk)") from err
    return rerun


def spawn_check() -> str:
    """The rerun viewer executable (on PATH or next to this Python, where pip puts it),
    or :class:`RerunUnavailable` when a viewer window cannot open here."""
    require_rerun()
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise RerunUnavailable("cannot spawn the rerun viewer: no display (DISPLAY and "
                               "WAYLAND_DISPLAY are unset); write a file with --rerun "
                               "FILE.rrd and open it where there is one: rerun FILE.rrd")
    exe = shutil.which("rerun") or shutil.which("rerun", path=str(Path(sys.executable).parent))
    if exe is None:
        raise RerunUnavailable("cannot spawn the rerun viewer: no `rerun` executable on PATH "
                               f"or in {Path(sys.executable).parent} (pip install rerun-sdk "
                               "installs it)")
    return exe


VIEWER_PORT = 9876                     # rerun's default gRPC port


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def start_viewer(port: int = VIEWER_PORT) -> None:
    """Spawn a rerun viewer listening on ``port`` (none if one already listens there);
    :class:`RerunUnavailable` when it cannot start (no display, no executable, the
    window fails to open)."""
    exe = spawn_check()
    if _listening(port):
        return
    rr = require_rerun()
    from rerun.sinks import spawn
    try:
        spawn(port=port, connect=False, executable_path=exe,
              recording=rr.RecordingStream("flexarm_ros"))
    except Exception as err:           # the binding raises plain RuntimeErrors
        raise RerunUnavailable(f"cannot spawn the rerun viewer {exe}: {err}") from err
    for _ in range(10):
        if _listening(port):
            return
        time.sleep(0.2)
    display = os.environ.get("WAYLAND_DISPLAY") or os.environ.get("DISPLAY")
    raise RerunUnavailable(f"the rerun viewer {exe} did not start (nothing listens on port "
                           f"{port}); can it open a window on display {display!r}? Write a "
                           "file with --rerun FILE.rrd instead")


#: most points per beam centerline in one drawing
MAX_SAMPLES = 10_001


@dataclass
class ViewOptions:
    """``shape_rate_hz``: at most this many arm drawings per simulated second (0: every
    ``ground_truth/coordinates`` message); ``samples``: points per beam centerline;
    ``force_scale``: arrow metres per newton (None: the largest force draws 0.25 of
    the arm's reach)."""
    shape_rate_hz: float = 100.0
    samples: int = 21
    force_scale: float | None = None

    def __post_init__(self):
        if not 2 <= self.samples <= MAX_SAMPLES:
            raise ValueError(f"samples: got {self.samples}, expected 2 to {MAX_SAMPLES} points "
                             f"per beam centerline")
        if not self.shape_rate_hz >= 0:
            raise ValueError(f"shape_rate: got {self.shape_rate_hz}, expected a number >= 0 "
                             f"of arm drawings per simulated second (0: every message)")
        if self.force_scale is not None and not (self.force_scale > 0
                                                 and math.isfinite(self.force_scale)):
            raise ValueError(f"force_scale: got {self.force_scale}, expected a finite number "
                             f"> 0 m/N")


@dataclass
class RerunSummary:
    """What :func:`bag_to_rerun` logged: rows per entity path, shape frames, the file."""
    bag: str
    rrd: Path | None
    rows: dict = field(default_factory=dict)
    shape_frames: int = 0
    force_scale: float | None = None

    @property
    def size_bytes(self) -> int | None:
        return self.rrd.stat().st_size if self.rrd and self.rrd.exists() else None

    def text(self) -> str:
        s = (f"{self.bag}: {len(self.rows)} entities, {sum(self.rows.values())} rows, "
             f"{self.shape_frames} arm drawings")
        if self.rrd:
            s += f" → {self.rrd} ({self.size_bytes / 1e6:.2f} MB)"
        return s


def _xyz(xy) -> np.ndarray:
    xy = np.asarray(xy, float).reshape(-1, 2)
    return np.column_stack([xy, np.zeros(len(xy))])


def _time(rec, t_ns: int) -> None:
    rec.set_time(TIMELINE, duration=np.timedelta64(int(t_ns), "ns"))


def blueprint(view: BagView):
    """Layout: the arm seen from +z (x right, y up) next to the time series."""
    import rerun.blueprint as rrb
    r = view.reach()
    eye = rrb.EyeControls3D(position=[0.0, 0.0, 2.5 * r], look_target=[0.0, 0.0, 0.0],
                            eye_up=[0.0, 1.0, 0.0])
    plots = [rrb.TimeSeriesView(origin="plots/joint_angles", name="joint angles (rad)"),
             rrb.TimeSeriesView(origin="plots/contact", name="contact (N, flag)")]
    for topic, path in BATCH_ENTITIES.items():
        if view.messages(topic):
            plots.insert(1, rrb.TimeSeriesView(origin=path, name=path.split("/")[-1]))
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial3DView(origin="world", name=view.scene.name if view.scene else "world",
                          eye_controls=eye),
        rrb.Vertical(*plots), column_shares=[3, 2]), collapse_panels=True)


def log_view(view: BagView, rec, options: ViewOptions | None = None) -> RerunSummary:
    """Log everything ``view`` holds to the recording stream ``rec``."""
    rr = require_rerun()
    o = options or ViewOptions()
    out = RerunSummary(view.path, None)

    def count(path, n=1):
        out.rows[path] = out.rows.get(path, 0) + n

    def scalars(path, t_ns, values):
        if len(t_ns) == 0:
            return
        rec.send_columns(path, indexes=[rr.TimeColumn(
            TIMELINE, duration=np.asarray(t_ns, np.int64).astype("timedelta64[ns]"))],
            columns=rr.Scalars.columns(scalars=np.asarray(values, float)))
        count(path, len(t_ns))

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    wall = view.wall_line()
    if wall is not None:
        rec.log("world/wall", rr.LineStrips3D([_xyz(wall)], colors=[(120, 120, 120)],
                                              radii=rr.Radius.ui_points(3.0),
                                              labels=["wall"]), static=True)
        count("world/wall")

    # the arm, the tool and the tip path at the shape frames
    frames = view.shape_frames(o.shape_rate_hz, o.samples)
    out.shape_frames = len(frames)
    links = view.link_names
    for f in frames:
        _time(rec, f.t_ns)
        for k, (name, line) in enumerate(zip(links, f.centerlines)):
            rec.log(f"world/arm/{name}", rr.LineStrips3D(
                [_xyz(line)], colors=[_LINK_COLORS[k % len(_LINK_COLORS)]],
                radii=rr.Radius.ui_points(4.0)))
            count(f"world/arm/{name}")
        rec.log("world/tool", rr.Points3D(_xyz(f.tool), radii=rr.Radius.ui_points(6.0),
                                          colors=[(214, 39, 40)]))
        count("world/tool")
    t_tip, xy_tip = view.tip_path()
    picks = thin(t_tip, o.shape_rate_hz)
    for j, k in enumerate(picks):
        _time(rec, t_tip[k])
        rec.log("world/tip_path", rr.LineStrips3D([_xyz(xy_tip[picks[:j + 1]])],
                                                  colors=[(100, 160, 220)],
                                                  radii=rr.Radius.ui_points(1.5)))
        count("world/tip_path")

    # the contact force at the tool
    cf = view.contact_force()
    if cf is not None:
        t_f, force, local = cf
        mag = np.hypot(force[:, 0], force[:, 1])
        scale = o.force_scale or (0.25 * view.reach() / mag.max() if mag.max() > 0 else 1.0)
        out.force_scale = scale
        coords = {int(t): m for t, m in view.messages(T.GT_COORDINATES)}
        shown = False
        for t, fw, fm in zip(t_f, force, mag):
            if fm == 0.0:
                if shown:
                    _time(rec, t)
                    rec.log("world/contact_force", rr.Clear(recursive=False))
                    count("world/contact_force")
                    shown = False
                continue
            if view.tool_at_tip:
                tool = view.tips().get(int(t))
            elif view.chain is not None and int(t) in coords:
                tool = view.tool_position(view.coordinates(coords[int(t)]))
            else:
                tool = None
            if tool is None:
                continue
            _time(rec, t)
            rec.log("world/contact_force", rr.Arrows3D(
                origins=_xyz(tool), vectors=_xyz(scale * fw), colors=[(214, 39, 40)],
                labels=[f"{fm:.3g} N"], radii=rr.Radius.ui_points(3.0)))
            count("world/contact_force")
            shown = True
        scalars("plots/contact/normal_force", t_f, local[:, 0])
        scalars("plots/contact/friction_force", t_f, local[:, 1])
    flag = view.contact_flag()
    if flag is not None:
        scalars("plots/contact/in_contact", flag.t_ns, flag.values)

    # traces
    for tr in view.joint_state_series(T.JOINT_STATES):
        scalars(f"plots/joint_angles/measured/{tr.name}", tr.t_ns, tr.values)
    for tr in view.joint_state_series(T.GT_JOINT_STATES):
        scalars(f"plots/joint_angles/true/{tr.name}", tr.t_ns, tr.values)
    for topic, path in BATCH_ENTITIES.items():
        for tr in view.batch_series(topic):
            scalars(f"{path}/{tr.name}", tr.t_ns, tr.values)
    for tr in view.array_series(T.COMMANDS, links):
        scalars(f"plots/commands/{tr.name}", tr.t_ns, tr.values)
    return out


def bag_to_rerun(bag, rrd=None, *, spawn: bool = False, namespace: str | None = None,
                 options: ViewOptions | None = None) -> RerunSummary:
    """Convert a twin bag (path or :class:`~flexarm_ros.bag.Bag`) to a rerun recording
    written to ``rrd`` and/or shown in a spawned viewer (``spawn=True``)."""
    rr = require_rerun()
    if spawn:
        start_viewer()
    if rrd is None and not spawn:
        raise ValueError("bag_to_rerun: give rrd (a .rrd path) and/or spawn=True")
    view = bag if isinstance(bag, BagView) else BagView(bag, namespace)
    bp = blueprint(view)
    rec = rr.RecordingStream("flexarm_ros")
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    sinks = []
    if spawn:
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"))
    if rrd is not None:
        rrd = Path(rrd)
        if rrd.parent and not rrd.parent.exists():
            raise FileNotFoundError(f"{rrd}: directory {rrd.parent} does not exist")
        sinks.append(rr.FileSink(str(rrd)))
    rec.set_sinks(*sinks, default_blueprint=bp)
    rec.send_recording_name(Path(view.path).name)
    try:
        out = log_view(view, rec, options)
        rec.flush()
    except RuntimeError as err:        # a sink failed (the viewer went away)
        raise RerunUnavailable(f"rerun: {err}") from err
    finally:
        rec.disconnect()
    out.rrd = rrd
    return out
