"""Units of the twin's named quantities, by name: the columns ``flexarm simulate`` writes
(so its CSV headers read ``name [unit]``, the convention ``flexarm compare`` reads) and the
generalized coordinates of the model.

Spellings are ASCII (``m/s^2``, ``N*m``); ``1`` is dimensionless; :data:`TEXT` marks a
column of labels (``contact_phase``). Names follow the model's conventions:

* ``t``: s;
* ``<link>_joint``, ``_motor``, ``_drive``: rad (joint, motor-side and drive angles);
* beam coordinates ``<link>_tip_disp``, ``_w<k>``, ``_y<k>``, ``_mode<k>``, ``_rod<k>``: m
  (modes, the rod's too, are scaled to unit peak deflection); ``<link>_tip_rot``, ``_th<k>``, ``_spring`` (the rigid
  rung's hub spring): rad;
* ``<coordinate>_rate``: the coordinate's unit per second;
* ``tip_x``, ``tip_y``, ``<link>_tip_deflection``: m; ``energy``: J;
* ``<link>_torque_cmd``, ``_drive_torque``: N*m; ``<link>_voltage``: V;
  ``<link>_current``, ``_valve_current``: A; ``<link>_pressure``: Pa;
* a closed-loop run's targets: ``<link>_joint_target``: rad; ``tool_x_target``,
  ``tool_y_target``: m;
* contact: ``gap``, ``tool_x``, ``tool_y``: m; ``tool_vx``, ``tool_vy``: m/s;
  ``contact_normal_force``, ``contact_friction_force``: N; ``contact_normal_impulse``:
  N*s; ``contact_phase``: :data:`TEXT`.

Sensor tables (one per sample rate) add, per declared sensor: ``<name>`` as the
instrument gives it (encoder ``count``; V with a ``sensitivity``, else the SI unit of
the kind: accelerometer ``m/s^2``, strain ``1``, potentiometer ``rad``), ``<name>_true`` in
that SI unit (encoder ``count``) and, for a ``tip_position`` sensor, ``<name>_x``,
``<name>_y`` in m.
"""

from __future__ import annotations

import re

__all__ = ["SENSOR_SI_UNIT", "TEXT", "beam_coordinate", "column_unit", "coordinate_unit",
           "table_units"]

#: The unit of a column of labels.
TEXT = "text"

#: SI unit of each sensor kind's true value.
SENSOR_SI_UNIT = {"encoder": "count", "accelerometer": "m/s^2", "strain": "1",
                  "potentiometer": "rad", "tip_position": "m"}

_BEAM = re.compile(r"_(tip_disp|tip_rot|w\d+|th\d+|y\d+|mode\d+|rod\d+|spring)$")
_COORDINATE = ((re.compile(r"_(joint|motor|drive|tip_rot|th\d+|spring)$"), "rad"),
               (re.compile(r"_(tip_disp|w\d+|y\d+|mode\d+|rod\d+)$"), "m"))
_FIXED = {"t": "s", "tip_x": "m", "tip_y": "m", "energy": "J", "gap": "m", "tool_x": "m",
          "tool_y": "m", "tool_vx": "m/s", "tool_vy": "m/s", "contact_normal_force": "N",
          "contact_friction_force": "N", "contact_normal_impulse": "N*s",
          "contact_phase": TEXT, "tool_x_target": "m", "tool_y_target": "m"}
_SUFFIX = ((re.compile(r"_tip_deflection$"), "m"),
           (re.compile(r"_joint_target$"), "rad"),
           (re.compile(r"_(torque_cmd|drive_torque)$"), "N*m"),
           (re.compile(r"_voltage$"), "V"),
           (re.compile(r"_(valve_current|current)$"), "A"),
           (re.compile(r"_pressure$"), "Pa"))


def beam_coordinate(name: str) -> bool:
    """Whether ``name`` is an elastic beam coordinate (``<link>_tip_disp``, ``_tip_rot``,
    ``_w<k>``, ``_th<k>``, ``_y<k>``, ``_mode<k>``, the rigid rung's ``_spring``)."""
    return bool(_BEAM.search(name))


def coordinate_unit(name: str) -> str | None:
    """The unit of a generalized coordinate by its name (``rad`` or ``m``), or None when
    the name follows none of the model's patterns."""
    for pattern, unit in _COORDINATE:
        if pattern.search(name):
            return unit
    return None


def _sensor_units(sensors) -> dict:
    out = {}
    for s in sensors:
        si = SENSOR_SI_UNIT.get(s.kind)
        if si is None:
            continue
        if s.kind == "tip_position":
            out[f"{s.name}_x"] = out[f"{s.name}_y"] = "m"
            continue
        out[s.name] = "V" if (s.kind != "encoder" and s.sensitivity is not None) else si
        out[f"{s.name}_true"] = si
    return out


def column_unit(name: str, sensors=()) -> str | None:
    """The unit of one output column (table in the module docstring); ``sensors`` are the
    scene's sensor specs (for the sensor-table columns; their names win over the
    patterns). None when the name is unknown."""
    unit = _sensor_units(sensors).get(name) or _FIXED.get(name)
    if unit is not None:
        return unit
    if name.endswith("_rate"):
        base = coordinate_unit(name[:-len("_rate")])
        return None if base is None else f"{base}/s"
    for pattern, unit in _SUFFIX:
        if pattern.search(name):
            return unit
    return coordinate_unit(name)


def table_units(columns, scene=None) -> dict:
    """``{name: unit}`` for every column of ``columns`` (names) whose unit is known; the
    scene's sensors name the sensor-table columns (sensor names win over the patterns)."""
    sensors = tuple(getattr(scene, "sensors", ()) or ())
    units = {name: column_unit(name, sensors) for name in columns}
    return {name: unit for name, unit in units.items() if unit is not None}
