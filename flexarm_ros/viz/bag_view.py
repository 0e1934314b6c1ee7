"""What a recorded twin bag shows, as plain numpy arrays on the simulation time (ns):
the deformed arm, the wall, the tool and its contact force, the tip path and the sensor
traces. No viewer here: :mod:`flexarm_ros.viz.rerun_view` logs these arrays to rerun. The
geometry (centerlines, tool, wall, force) is :class:`~flexarm_ros.viz.arm_geometry.ArmGeometry`'s,
which the simulator node's ``arm_markers`` draw too.

The bag's conventions (embedded scene, namespace, sensor batch layout and timing) are
read by :mod:`flexarm_ros.twin.recording`, as ``flexarm compare`` reads them. The model
comes from the bag itself: :class:`~flexarm_ros.model.chain.Chain` of the embedded scene
(``from flexarm_ros.model import Chain``, the model's public API, imported when a scene
is present; nothing of ``flexarm_ros.sim``) turns the full coordinate
vector of ``ground_truth/coordinates`` (mapped by name onto ``Chain.names``) into beam
centerlines (``Chain.centerlines``). Time is the log time of each message, which the
recorder sets to the simulation time. :meth:`BagView.batch_series` expands the sensor
batches to one time stamp per sample.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from flexarm_ros.twin import recording
from flexarm_ros.bag.reader import Bag, BagError, read_bag
from flexarm_ros.twin import topics as T
from flexarm_ros.viz.arm_geometry import ArmGeometry

__all__ = ["BagView", "ShapeFrame", "Trace", "thin"]


@dataclass
class Trace:
    """One scalar signal: ``t_ns`` (int64, simulation time) and ``values`` (float64)."""
    name: str
    t_ns: np.ndarray
    values: np.ndarray


@dataclass
class ShapeFrame:
    """The arm at one instant: one (samples, 2) world-frame centerline per link (m), the
    tool point (m) and the full coordinate vector q in ``Chain.names`` order."""
    t_ns: int
    centerlines: list
    tool: np.ndarray
    q: np.ndarray


def thin(t_ns, rate_hz: float) -> list[int]:
    """Indices into the sorted times ``t_ns`` keeping at most ``rate_hz`` per second: the
    first, then the first at or after each 1/rate_hz step, and always the last
    (``rate_hz`` ≤ 0: all)."""
    if len(t_ns) == 0:
        return []
    step = 0 if rate_hz <= 0 else int(round(1e9 / rate_hz))
    out, due = [], None
    for k, t in enumerate(t_ns):
        if due is None or t >= due:
            out.append(k)
            due = int(t) + step
    if out[-1] != len(t_ns) - 1:
        out.append(len(t_ns) - 1)
    return out


class BagView:
    """The drawable content of one twin bag (a path or a :class:`~flexarm_ros.bag.Bag`).

    ``namespace``: where the twin's topics are (default: the bag's metadata
    ``flexarm_ros.namespace``, else ``/flexarm``). A bag without the scene metadata
    still gives its traces and tip path, but no arm, wall or channel names.
    """

    def __init__(self, bag, namespace: str | None = None):
        self.bag: Bag = bag if isinstance(bag, Bag) else read_bag(bag)
        self.namespace = recording.namespace(self.bag, namespace)
        self.scene = recording.embedded_scene(self.bag)
        self.geometry = self.chain = None
        if self.scene is not None:
            self.geometry = ArmGeometry(self.scene)
            self.chain = self.geometry.chain
        self._index: dict = {}
        self._tips: dict | None = None

    # ------------------------------------------------------------------ access
    @property
    def path(self) -> str:
        return self.bag.path

    def topic(self, name: str) -> str:
        """Absolute name of a twin topic in this bag."""
        return T.resolve(self.namespace, name)

    def messages(self, name: str) -> list:
        """[(log time ns, decoded message)] of a twin topic (empty when absent).

        Raises:
            BagError: the bag's topic of that name carries another message type than the
                twin's contract (:data:`flexarm_ros.twin.topics.TYPES`)."""
        topic = self.topic(name)
        found, want = self.bag.types.get(topic), T.TYPES.get(name)
        if found is not None and want is not None and found != want:
            raise BagError(f"{self.path}: {topic}: got message type {found}, expected {want} "
                           f"(the twin's {name} topic)")
        return recording.twin_messages(self.bag, name, self.namespace)

    @property
    def link_names(self) -> list[str]:
        return [lk.name for lk in self.scene.links] if self.scene else []

    @property
    def tool_at_tip(self) -> bool:
        """The scene's tool point is the last beam's tip (ground_truth/tip is the tool)."""
        return self.geometry is None or self.geometry.tool_at_tip

    # ------------------------------------------------------------------ geometry
    def wall_normal_tangent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(unit inward normal n, tangent t = E·n, E the +90° rotation) of the wall."""
        return None if self.geometry is None else self.geometry.wall_normal_tangent()

    def reach(self) -> float:
        """Sum of the beam lengths (m), the scale of the drawing (1 m without a scene)."""
        return 1.0 if self.geometry is None else self.geometry.reach()

    def wall_line(self, half_length: float | None = None) -> np.ndarray | None:
        """(2, 2) end points of the wall: ``point ± half_length·t`` (default: the reach)."""
        return None if self.geometry is None else self.geometry.wall_line(half_length)

    def _q_index(self, names: tuple) -> np.ndarray:
        """Message index of every ``Chain.names`` entry (by name, not position)."""
        idx = self._index.get(names)
        if idx is None:
            where = {n: i for i, n in enumerate(names)}
            missing = [n for n in self.chain.names if n not in where]
            if missing:
                raise BagError(f"{self.path}: {self.topic(T.GT_COORDINATES)}: the model of "
                               f"scene {self.scene.name!r} needs the coordinates "
                               f"{self.chain.names}, the message lacks {missing} "
                               f"(it has {list(names)})")
            idx = self._index[names] = np.array([where[n] for n in self.chain.names], int)
        return idx

    def coordinates(self, msg) -> np.ndarray:
        """Full q (``Chain.names`` order) of one ``ground_truth/coordinates`` message."""
        return np.asarray(msg.position, float)[self._q_index(tuple(msg.name))]

    def has_shape(self) -> bool:
        return self.chain is not None and bool(self.messages(T.GT_COORDINATES))

    def tool_position(self, q: np.ndarray, t_ns: int | None = None) -> np.ndarray:
        """Tool point (m): ``ground_truth/tip`` at ``t_ns`` when the tool is at the tip
        and that message exists, else the last tip frame o + A(ψ)·tool.position."""
        if self.tool_at_tip and t_ns is not None:
            tip = self.tips().get(int(t_ns))
            if tip is not None:
                return tip
        return self.geometry.tool_position(q)

    def tips(self) -> dict:
        """{log time ns: ground_truth/tip (x, y)}."""
        if self._tips is None:
            self._tips = {int(t): np.array([m.point.x, m.point.y])
                          for t, m in self.messages(T.GT_TIP)}
        return self._tips

    def tip_path(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_ns (N,), xy (N, 2)) of ``ground_truth/tip``."""
        msgs = self.messages(T.GT_TIP)
        t = np.array([t for t, _ in msgs], np.int64)
        xy = np.array([[m.point.x, m.point.y] for _, m in msgs], float).reshape(-1, 2)
        return t, xy

    def shape_frames(self, rate_hz: float = 100.0, samples: int = 21) -> list[ShapeFrame]:
        """The arm at ``ground_truth/coordinates`` messages thinned to at most
        ``rate_hz`` (the first message, then the first at or after each 1/rate_hz step;
        the last message always), ``samples`` points per centerline."""
        if not self.has_shape():
            return []
        msgs = self.messages(T.GT_COORDINATES)
        chosen = thin(np.array([t for t, _ in msgs], np.int64), rate_hz)
        out = []
        for k in chosen:
            t, m = msgs[k]
            q = self.coordinates(m)
            out.append(ShapeFrame(int(t), self.geometry.centerlines(q, samples),
                                  self.tool_position(q, t), q))
        return out

    # ------------------------------------------------------------------ contact
    def contact_force(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(t_ns (N,), force on the tool in the world frame (N, 2) = F_n·n + F_t·t,
        (F_n, F_t) (N, 2)) from ``tool/wrench`` (frame ``wall``: x normal, y tangent)."""
        msgs = self.messages(T.TOOL_WRENCH)
        if not msgs or self.wall_normal_tangent() is None:
            return None
        t = np.array([t for t, _ in msgs], np.int64)
        f = np.array([[m.wrench.force.x, m.wrench.force.y] for _, m in msgs], float)
        return t, self.geometry.contact_force(f[:, 0], f[:, 1]), f

    # ------------------------------------------------------------------ traces
    def batch_series(self, topic: str) -> list[Trace]:
        """Per-sample traces of a batch topic, one per channel, named after the scene's
        sensors of its kind (``<kind>_<j>`` when the counts differ or the scene has none;
        :func:`flexarm_ros.twin.recording.sensor_batches`, whose notes are warned)."""
        self.messages(topic)                     # the type of the topic: the twin's
        sb = recording.sensor_batches(self.bag, topic, self.scene, self.namespace)
        if sb is None:
            return []
        for note in sb.notes:
            warnings.warn(note, stacklevel=2)
        return [Trace(n, sb.t_ns, sb.values[:, j].copy()) for j, n in enumerate(sb.names)]

    def joint_state_series(self, topic: str, field: str = "position") -> list[Trace]:
        """One trace per joint name of a ``sensor_msgs/JointState`` topic (by name)."""
        msgs = self.messages(topic)
        series: dict[str, tuple[list, list]] = {}
        for t, m in msgs:
            for name, v in zip(m.name, getattr(m, field)):
                ts, vs = series.setdefault(name, ([], []))
                ts.append(t)
                vs.append(v)
        return [Trace(n, np.array(ts, np.int64), np.array(vs, float))
                for n, (ts, vs) in series.items()]

    def array_series(self, topic: str, names: list[str] | None = None) -> list[Trace]:
        """One trace per element of a 1-D ``*MultiArray`` topic (e.g. commands)."""
        msgs = self.messages(topic)
        if not msgs:
            return []
        t = np.array([t for t, _ in msgs], np.int64)
        width = min(len(m.data) for _, m in msgs)
        v = np.array([list(m.data)[:width] for _, m in msgs], float).reshape(len(msgs), width)
        names = names if names and len(names) == width else [f"{j}" for j in range(width)]
        return [Trace(n, t, v[:, j].copy()) for j, n in enumerate(names)]

    def contact_flag(self) -> Trace | None:
        msgs = self.messages(T.TOOL_CONTACT)
        if not msgs:
            return None
        return Trace("in_contact", np.array([t for t, _ in msgs], np.int64),
                     np.array([float(bool(m.data)) for _, m in msgs]))
