"""The wire limits of each joint: the largest command the motor driver accepts on
``motor_driver/commands`` and the largest torque the simulator accepts on
``effort_controller/commands`` (ROS twin, :mod:`flexarm_ros.twin.validation`).

A message beyond a limit is rejected, not clipped: it changes nothing. Every scene has
limits; where the scene does not state one, the default below applies and says so
(``flexarm explain`` prints them):

* command of a ``dc_motor`` joint (V): ``drive.supply_voltage``, else
  :data:`DEFAULT_SUPPLY_VOLTAGE` (48 V, a common industrial DC bus; the drive model itself
  then does not clip the voltage).
* command of a ``hydraulic`` joint (A, valve current without the null bias):
  ``drive.rated_current`` (a required key).
* command of a joint without a drive (N·m): its torque limit.
* torque of a joint without a drive: ``joint.torque_limit``, else
  :data:`DEFAULT_TORQUE_LIMIT` (1000 N·m).
* torque of a ``dc_motor`` joint: n·K_t·i_max with i_max = ``drive.current_limit``, else
  2·V_max/R — the current when the full command voltage reverses a motor turning at its
  no-load speed, the largest the drive draws unless the load drives the motor beyond its
  no-load speed (the motor driver never publishes beyond it: its torque is held there).
* torque of a ``hydraulic`` joint: η_t·D_m·P_s (the load pressure stays within ±P_s).
  Its effort on the wire is the valve current (the plant integrates the actuator,
  :mod:`flexarm_ros.sim.plant`), within the command limit.
"""

from __future__ import annotations

from dataclasses import dataclass

#: V: the command limit of a dc_motor drive without ``supply_voltage``.
DEFAULT_SUPPLY_VOLTAGE = 48.0
#: N·m: the torque limit of a joint without a drive and without ``torque_limit``.
DEFAULT_TORQUE_LIMIT = 1000.0


@dataclass(frozen=True)
class JointLimits:
    """One joint's wire limits and where each comes from (a sentence for ``explain``)."""
    joint: str               # link name
    command: str             # "voltage", "current" or "torque"
    command_unit: str        # "V", "A", "N·m"
    command_limit: float     # |command| ≤ this
    command_from: str
    torque_limit: float      # |effort| ≤ this (N·m)
    torque_from: str

    def text(self) -> str:
        effort = (f"effort: the valve current within the same ±{self.command_limit:.6g} A "
                  f"(the simulator integrates the actuator; its torque stays within "
                  f"±{self.torque_limit:.6g} N·m, {self.torque_from})"
                  if self.command == "current" else
                  f"effort within ±{self.torque_limit:.6g} N·m ({self.torque_from})")
        return (f"{self.joint}: {self.command} command within ±{self.command_limit:.6g} "
                f"{self.command_unit} ({self.command_from}); {effort}")


def joint_limits(scene) -> list[JointLimits]:
    """The wire limits of every joint of ``scene``, base to tip."""
    out = []
    for k, lk in enumerate(scene.links):
        key = f"links[{k}].joint"
        jt, d = lk.joint, lk.joint.drive
        if d is None:
            if jt.torque_limit is not None:
                tau, src = jt.torque_limit, f"{key}.torque_limit"
            else:
                tau, src = DEFAULT_TORQUE_LIMIT, (f"default: {key}.torque_limit not given")
            out.append(JointLimits(lk.name, "torque", "N·m", tau, src, tau, src))
        elif d.type == "dc_motor":
            if d.supply_voltage is not None:
                v, vsrc = d.supply_voltage, f"{key}.drive.supply_voltage"
            else:
                v, vsrc = DEFAULT_SUPPLY_VOLTAGE, (f"default: {key}.drive.supply_voltage "
                                                   f"not given")
            if d.current_limit is not None:
                i, isrc = d.current_limit, f"n·K_t·{key}.drive.current_limit"
            else:
                i = 2.0 * v / d.resistance
                isrc = (f"n·K_t·2·V_max/R, the plugging current from the no-load speed: "
                        f"{key}.drive.current_limit not given")
            out.append(JointLimits(lk.name, "voltage", "V", v, vsrc,
                                   d.gear_ratio * d.output_torque_constant * i, isrc))
        else:
            eta = d.torque_efficiency or 1.0
            out.append(JointLimits(lk.name, "current", "A", d.rated_current,
                                   f"{key}.drive.rated_current",
                                   eta * d.displacement * d.supply_pressure,
                                   "η_t·D_m·P_s"))
    return out
