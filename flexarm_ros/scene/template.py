"""A commented scene of one's own (``flexarm new``): N links of aluminium strip on geared
DC motors, in the datasheet's terms, every key explained where it stands.

The values are a bench a lab could build (0.4 m strips 25 × 2 mm, Maxon-class motors
with 100:1 gearheads); the user edits them to their arm. :func:`scene_text` returns the
YAML text, which loads as it is (tested: ``flexarm simulate`` runs every template).
"""

from __future__ import annotations

MAX_LINKS = 8
CONTROLS = ("open_loop", "position")

_HEAD = """\
# A scene of one's own, written by `flexarm new` (flexarm_ros {version}). SI units.
# Every key: docs/config_reference.md; a walk through one arm: docs/scenes.md.
name: {name}
description: >-
  {links} aluminium strip link(s) on geared DC motors ({plane}), {what}.
gravity: [0.0, {gravity}]          # m/s² in the arm's plane (0, 0: a horizontal table)
links:
"""

_LINK = """\
  - name: link{k}                  # becomes column and joint names: link{k}_joint, ...
    joint:
      initial_angle: {angle}       # rad, relative to the previous link
      drive_damping: 0.01          # N·m·s/rad, viscous loss of the gearbox output
      drive:                       # the motor's and gearhead's datasheet
        type: dc_motor
        gear_ratio: 100.0          # n, motor turns per output turn
        gear_efficiency: 0.8       # η: output torque η·n·K_t·i
        torque_constant: 0.0302    # N·m/A, K_t
        back_emf_constant: 0.0302  # V·s/rad, K_b (= K_t in SI)
        resistance: 1.2            # Ω, terminal resistance
        rotor_inertia: 1.0e-5      # kg·m², J_m on the motor shaft (n²·J_m at the joint)
        supply_voltage: 24.0       # V, the amplifier clips |V| to this
    hub:                           # the body on the joint (clamp, encoder disc)
      mass: 0.05                   # kg
      inertia: 2.0e-5              # kg·m² about its CG
    beam:
      length: {length}             # m, from the hub clamp to the tip body
      hub_radius: 0.02             # m, joint axis to the clamped beam root
      E: 69.0e9                    # Pa, Young's modulus (6061-T6 aluminium)
      density: 2700.0              # kg/m³
      section:                     # or: {{shape: tube, outer_diameter, wall_thickness}}
        shape: rectangle
        width: 0.025               # m, across the bending plane (along the joint axis)
        thickness: 0.002           # m, in the bending plane: I = width·thickness³/12
      damping:                     # viscous: cheap for every model. D = β·K
        viscous_per_length: 0.05   # (stiffness_proportional) damps mode ω at β·ω² and
                                   # shortens the explicit step of fine models a lot
    tip:                           # the next motor, or the payload on the last link
      mass: {tip_mass}             # kg
      inertia: {tip_inertia}       # kg·m² about its CG
"""

_OPEN_LOOP = """\
inputs:                            # one program per driven joint (docs/config_reference.md)
{inputs}"""

_INPUT = """\
  - joint: {k}
    voltage: {{type: step, offset: 0.0, amplitude: {amp}, start: 0.1}}   # V
"""

_POSITION = """\
control:                           # joint PD at the control rate (seed 000 Eq. 5.16)
  mode: position
  rate_hz: 1000.0                  # Hz, encoder and command rate
  kp: [{kp}]                       # N·m/rad per joint
  kd: [{kd}]                       # N·m·s/rad per joint
  joint_target: [{target}]         # rad per joint
"""

_TAIL = """\
sensors:                           # what the bench measures (topics in the ROS twin)
{encoders}  - {{name: acc_tip, kind: accelerometer, link: link{n}, body: tip, rate_hz: 2000.0,
     sensitivity: 0.00051, noise_std: 2.0e-4, seed: 1}}   # V per m/s² (5 mV/g), V rms
duration: 3.0                      # s
# no fidelity section: the default model (cubic, RK4 at its automatic step); flexarm
# explain says how far it is from the exact rod, --rung auto --tolerance M chooses the
# model for an error bound, a fidelity section fixes one (docs/ladder.md)
"""

_ENCODER = """\
  - {{name: enc{k}, kind: encoder, joint: {k}, rate_hz: 1000.0, lines_per_rev: 500,
     quadrature: 4, on_motor_shaft: true}}
"""


def scene_text(name: str, links: int, control: str = "open_loop",
               vertical: bool = False) -> str:
    """The commented YAML of a ``links``-link arm called ``name``."""
    from flexarm_ros import __version__
    n = links
    head = _HEAD.format(version=__version__, name=name, links=n,
                        plane="a vertical plane, gravity in it" if vertical
                        else "a horizontal table",
                        what=("joint PD position control" if control == "position"
                              else "a voltage step on each motor"),
                        gravity=-9.81 if vertical else 0.0)
    body = "".join(_LINK.format(k=k, angle=0.0, length=round(0.5 - 0.1 * k / max(n - 1, 1), 3),
                                tip_mass=0.3 if k < n else 0.1,
                                tip_inertia=3.0e-4 if k < n else 5.0e-5)
                   for k in range(1, n + 1))
    if control == "position":
        ctl = _POSITION.format(kp=", ".join(f"{4.0 * (n - k):g}" for k in range(n)),
                               kd=", ".join(f"{2.0 * (n - k):g}" for k in range(n)),
                               target=", ".join("0.3" for _ in range(n)))
    else:
        ctl = _OPEN_LOOP.format(inputs="".join(_INPUT.format(k=k, amp=2.0 if k == 1 else 0.0)
                                               for k in range(1, n + 1)))
    tail = _TAIL.format(n=n, encoders="".join(_ENCODER.format(k=k) for k in range(1, n + 1)))
    init = ("initial:\n  static_equilibrium: true    # start at rest, bent under gravity\n"
            if vertical else "")
    return head + body + ctl + init + tail
