"""``visualization_msgs/MarkerArray`` of the running twin (``arm_markers``): what RViz2
and Foxglove draw of the arm, from the geometry the rerun export draws
(:class:`~flexarm_ros.viz.arm_geometry.ArmGeometry`: ``Chain.centerlines``, the tool, the
wall, the contact force F_n·n + F_t·t).

One message holds, in the frame ``world`` and stamped with the simulation time:

====================  ====  ===========  =================================================
namespace             id    type         content
====================  ====  ===========  =================================================
``links``             k     LINE_STRIP   link k's deformed centerline, beam root to tip
``hubs``              k     SPHERE       link k's hub (its joint), at the hub frame origin
``wall``              0     LINE_LIST    the wall line (scenes with a wall)
``tool``              0     SPHERE       the tool point
``contact_force``     0     ARROW        from the tool along the force on it, while in
                                         contact (DELETE otherwise)
====================  ====  ===========  =================================================

Stable namespaces and ids: a viewer updates each marker in place. Points are the model's
coordinates in metres (z = 0: the arm is planar). The bytes come from
:func:`flexarm_ros.bag.writer.encode_cdr` (the recorder writes them as received; the
bag's schema is :mod:`flexarm_ros.bag.msgdefs`'s text of the type).
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.bag import messages as M
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.viz.arm_geometry import ArmGeometry

__all__ = ["ArmMarkers", "MARKER_ARRAY", "ARROW", "SPHERE", "LINE_STRIP", "LINE_LIST",
           "ADD", "DELETE"]

MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
ARROW, SPHERE, LINE_STRIP, LINE_LIST = 0, 2, 4, 5
ADD, DELETE = 0, 2

_IDENTITY = {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
             "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
_COLORS = {"links": (0.15, 0.45, 0.85, 1.0), "hubs": (0.3, 0.3, 0.3, 1.0),
           "wall": (0.55, 0.55, 0.55, 1.0), "tool": (0.95, 0.55, 0.1, 1.0),
           "contact_force": (0.85, 0.1, 0.1, 1.0)}


def _point(xy) -> dict:
    return {"x": float(xy[0]), "y": float(xy[1]), "z": 0.0}


def _color(ns: str) -> dict:
    r, g, b, a = _COLORS[ns]
    return {"r": r, "g": g, "b": b, "a": a}


def marker(t_ns: int, frame: str, ns: str, mid: int, mtype: int, points=(),
           scale=(1.0, 1.0, 1.0), position=None, action: int = ADD) -> dict:
    """One ``visualization_msgs/Marker`` as a plain dict (every field)."""
    pose = _IDENTITY if position is None else {
        "position": _point(position), "orientation": _IDENTITY["orientation"]}
    return {"header": M.header(t_ns, frame), "ns": ns, "id": int(mid), "type": int(mtype),
            "action": int(action), "pose": pose,
            "scale": {"x": float(scale[0]), "y": float(scale[1]), "z": float(scale[2])},
            "color": _color(ns), "lifetime": {"sec": 0, "nanosec": 0},
            "frame_locked": False, "points": [_point(p) for p in points], "colors": [],
            "texture_resource": "",
            "texture": {"header": M.header(0, ""), "format": "", "data": []},
            "uv_coordinates": [], "text": "", "mesh_resource": "",
            "mesh_file": {"filename": "", "data": []},
            "mesh_use_embedded_materials": False}


class ArmMarkers:
    """The arm of ``scene`` as marker arrays; ``chain``: the model whose coordinates
    ``q`` are given (``chain.names`` order; the plant's own). ``samples`` points per
    centerline; ``force_scale``: arrow metres per newton (0: the largest force so far
    draws 0.25 of the reach, as the rerun export draws the largest of a bag)."""

    def __init__(self, scene, chain=None, samples: int = 11, frame: str = "world",
                 force_scale: float = 0.0):
        if not (isinstance(samples, int) and samples >= 2):
            raise ValueError(f"samples: got {samples!r}, expected an integer ≥ 2")
        if not (math.isfinite(force_scale) and force_scale >= 0):
            raise ValueError(f"force_scale: got {force_scale!r}, expected a finite number "
                             f"≥ 0 (m/N; 0: automatic)")
        self.geometry = ArmGeometry(scene, chain)
        self.samples, self.frame, self.force_scale = samples, frame, float(force_scale)
        self.reach = self.geometry.reach()
        self.width = 0.01 * self.reach                 # line width and sphere scale (m)
        self.wall = self.geometry.wall_line()
        self._largest = 0.0

    def message(self, t_ns: int, q, contact: bool = False, normal: float = 0.0,
                friction: float = 0.0) -> dict:
        """The ``MarkerArray`` dict at time ``t_ns`` (ns) of the coordinates ``q`` and the
        tool's contact (``normal``, ``friction``: the forces of ``tool/wrench``, N)."""
        g, fr, w = self.geometry, self.frame, self.width
        q = np.asarray(q, float)
        lines, hubs, tool = g.shape(q, self.samples)
        out = [marker(t_ns, fr, "links", k, LINE_STRIP, line, (2 * w, 0, 0))
               for k, line in enumerate(lines)]
        out += [marker(t_ns, fr, "hubs", k, SPHERE, (), (4 * w,) * 3, position=h)
                for k, h in enumerate(hubs)]
        if self.wall is not None:
            out.append(marker(t_ns, fr, "wall", 0, LINE_LIST, self.wall, (w, 0, 0)))
        out.append(marker(t_ns, fr, "tool", 0, SPHERE, (), (3 * w,) * 3, position=tool))
        force = g.contact_force(normal, friction) if contact else None
        if force is not None:
            mag = float(np.hypot(*force))
            self._largest = max(self._largest, mag)
            scale = self.force_scale or (0.25 * self.reach / self._largest
                                         if self._largest > 0 else 0.0)
            out.append(marker(t_ns, fr, "contact_force", 0, ARROW,
                              (tool, tool + scale * force), (w, 2 * w, 3 * w)))
        elif self.wall is not None:
            out.append(marker(t_ns, fr, "contact_force", 0, ARROW, action=DELETE))
        return {"markers": out}

    def cdr(self, t_ns: int, q, contact: bool = False, normal: float = 0.0,
            friction: float = 0.0) -> bytes:
        """:meth:`message` serialized (CDR, as rclpy's ``serialize_message``)."""
        return encode_cdr(MARKER_ARRAY, self.message(t_ns, q, contact, normal, friction),
                          validate=False)
