"""Scene files: one YAML file describes a rig and an experiment (SI units).

A scene is loaded into frozen, typed objects (:class:`Scene` and its sections). Anything the
loader cannot place is an error naming the key path, the value and the expectation
(see :mod:`flexarm_ros.scene.schema`). Components absent from a scene are absent from the
model built from it (no gravity → no gravity forces; no joint flexibility → no motor-side
coordinate).
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Optional

from flexarm_ros.errors import SceneError
from flexarm_ros.scene.schema import from_mapping, param

RUNGS = ("rigid", "cubic", "modal", "fem", "fd", "rod")
#: what ``fidelity.rung`` / ``--rung`` accept: a rung of the ladder, or ``auto`` (the
#: cheapest rung, refinement and RK4 step estimated to meet the tip tolerance,
#: :mod:`flexarm_ros.model.autofidelity`)
RUNG_CHOICES = RUNGS + ("auto",)
#: rkn4: RK4 with the positions stepped by the Runge–Kutta–Nyström formulas (same cost, about
#: half the error on the arms' oscillations; :func:`flexarm_ros.sim.step.rk4_step`)
INTEGRATORS = ("rk4", "rkn4", "trapezoid", "lawson4", "rk45", "dop853", "radau", "bdf", "lsoda")
TORQUE_PROGRAMS = ("constant", "step", "pulse", "square", "piecewise_constant",
                   "piecewise_linear")
MOTION_PROGRAMS = ("spin_up", "smooth_step", "hold")
INPUT_KINDS = ("torque", "voltage", "current", "motion")
SENSOR_KINDS = ("encoder", "accelerometer", "strain", "potentiometer", "tip_position")

#: link and sensor names become table columns (``<link>_joint``, ``<sensor>_true``), channel
#: and ROS joint names: ASCII letters, digits and underscores, starting with a letter (a
#: comma, a space or an empty name would break the CSV header or the message contract)
NAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
NAME_RULE = ("a non-empty name of ASCII letters, digits and underscores that starts with a "
             "letter")
#: the encoder counts travel as int32 (std_msgs/Int32MultiArray): a scene's encoders must
#: count this many output revolutions either way without leaving int32
ENCODER_REVOLUTIONS = 1000
INT32_MAX = 2**31 - 1
#: a beam's hub radius beyond this many beam lengths is refused (see Link.validate)
HUB_RADIUS_PER_LENGTH = 100.0


def check_name(where: str, name: str) -> None:
    """SceneError unless ``name`` follows :data:`NAME_RULE`."""
    if not NAME_PATTERN.fullmatch(name):
        raise SceneError(f"{where}: got {name!r}, expected {NAME_RULE} (it becomes a table "
                         f"column and a channel name)")


@dataclass(frozen=True, kw_only=True)
class RigidBody:
    """A rigid body fixed in a frame: mass, inertia about its CG and the CG offset."""
    mass: float = param(0.0, unit="kg", ge=0.0, doc="mass")
    inertia: float = param(0.0, unit="kg·m²", ge=0.0, doc="rotary inertia about the CG")
    cg: tuple[float, float] = param((0.0, 0.0), unit="m",
                                    doc="CG offset (x along the link, y across) in the frame")


@dataclass(frozen=True, kw_only=True)
class TipBody(RigidBody):
    """The body at a beam's tip; the next joint sits at ``joint_offset`` in its frame."""
    joint_offset: tuple[float, float] = param((0.0, 0.0), unit="m",
                                              doc="next joint position in the tip frame")


@dataclass(frozen=True, kw_only=True)
class BeamDamping:
    """Beam damping: distributed viscous (transverse velocity) plus stiffness-proportional."""
    viscous_per_length: float = param(0.0, unit="N·s/m²", ge=0.0,
                                      doc="c in the distributed force −c·ẇ(x)")
    stiffness_proportional: float = param(0.0, unit="s", ge=0.0,
                                          doc="β in D = β·K (Rayleigh)")


SECTION_SHAPES = ("rectangle", "tube", "circle")


@dataclass(frozen=True, kw_only=True)
class Section:
    """A beam's cross-section by its dimensions; with the beam's ``E`` and ``density`` it
    gives EI = E·I and ρA = density·A (Roark's Formulas, Table A.1):
    rectangle I = b·h³/12, A = b·h with h the side in the bending plane (``in_plane``);
    tube I = π(D⁴ − d⁴)/64, A = π(D² − d²)/4 with d = D − 2·wall_thickness;
    circle I = π·D⁴/64, A = π·D²/4."""
    shape: str = param(choices=SECTION_SHAPES, doc="section shape")
    width: Optional[float] = param(None, unit="m", gt=0.0, doc="rectangle: width")
    thickness: Optional[float] = param(None, unit="m", gt=0.0, doc="rectangle: thickness")
    in_plane: str = param("thickness", choices=("thickness", "width"),
                          doc="rectangle: the side that lies in the bending plane — "
                              "thickness (a strip bending the easy way, I = w·t³/12) or "
                              "width (edgewise, I = t·w³/12)")
    outer_diameter: Optional[float] = param(None, unit="m", gt=0.0,
                                            doc="tube / circle: outer diameter D")
    wall_thickness: Optional[float] = param(None, unit="m", gt=0.0,
                                            doc="tube: wall thickness")

    #: the keys each shape takes (:func:`flexarm_ros.scene.schema.accepted_keys`)
    KEYED_BY, NOUN = "shape", "section"
    KEYS = {"rectangle": ("width", "thickness", "in_plane"),
            "tube": ("outer_diameter", "wall_thickness"), "circle": ("outer_diameter",)}

    def validate(self, where):
        for key in (k for k in self.KEYS[self.shape] if k != "in_plane"):   # dimensions
            if getattr(self, key) is None:
                raise SceneError(f"{where}.{key}: missing, expected a value > 0 (m) for a "
                                 f"{self.shape} section")
        if self.shape == "tube" and not 2.0 * self.wall_thickness <= self.outer_diameter:
            raise SceneError(f"{where}.wall_thickness: got {self.wall_thickness} m, expected "
                             f"at most half the outer diameter ({self.outer_diameter / 2:g} m)")

    @property
    def area(self) -> float:
        """A, m²."""
        if self.shape == "rectangle":
            return self.width * self.thickness
        D = self.outer_diameter
        d = D - 2.0 * self.wall_thickness if self.shape == "tube" else 0.0
        return math.pi * (D * D - d * d) / 4.0

    @property
    def second_moment(self) -> float:
        """I about the axis normal to the bending plane, m⁴."""
        if self.shape == "rectangle":
            h, b = ((self.thickness, self.width) if self.in_plane == "thickness"
                    else (self.width, self.thickness))
            return b * h ** 3 / 12.0
        D = self.outer_diameter
        d = D - 2.0 * self.wall_thickness if self.shape == "tube" else 0.0
        return math.pi * (D ** 4 - d ** 4) / 64.0

    @property
    def depth(self) -> float:
        """The section's depth in the bending plane (the strain gauge's lever ×2), m."""
        if self.shape == "rectangle":
            return self.thickness if self.in_plane == "thickness" else self.width
        return self.outer_diameter

    def describe(self) -> str:
        if self.shape == "rectangle":
            return (f"rectangle {1e3 * self.width:g} × {1e3 * self.thickness:g} mm, "
                    f"{self.in_plane} in the bending plane")
        if self.shape == "tube":
            return (f"tube Ø{1e3 * self.outer_diameter:g} × {1e3 * self.wall_thickness:g} mm "
                    f"wall")
        return f"circle Ø{1e3 * self.outer_diameter:g} mm"


#: a datasheet value (E, density, section) and the schema value it gives, if both given,
#: must agree to this relative difference
DERIVED_AGREE = 1e-9


@dataclass(frozen=True, kw_only=True)
class Beam:
    """A uniform Euler–Bernoulli beam clamped to its hub at ``hub_radius`` from the joint.

    In the schema's terms (``EI``, ``mass_per_length``) or the datasheet's: a material
    (``E``, ``density``) and a :class:`Section`, from which EI = E·I, ρA = density·A and
    the gauge depth ``thickness`` are derived (``flexarm explain`` prints them)."""
    length: float = param(unit="m", gt=0.0, doc="beam length L")
    EI: Optional[float] = param(None, unit="N·m²", gt=0.0,
                                doc="bending stiffness E·I (in the plane); or E and section")
    EA: Optional[float] = param(None, unit="N", gt=0.0,
                                doc="axial stiffness E·A: the rod rung's stretch (none: "
                                    "an inextensible rod; the other rungs are inextensible)")
    mass_per_length: Optional[float] = param(None, unit="kg/m", gt=0.0,
                                             doc="ρ·A; or density and section")
    E: Optional[float] = param(None, unit="Pa", gt=0.0, le=1e13,
                               doc="Young's modulus (aluminium 6061 ≈ 69e9, steel ≈ 200e9, "
                                   "CFRP along the fibres ≈ 70e9-135e9); with section → EI")
    density: Optional[float] = param(None, unit="kg/m³", gt=0.0, le=1e5,
                                     doc="material density (aluminium 2700, steel 7850, "
                                         "CFRP ≈ 1550); with section → mass_per_length")
    section: Optional[Section] = param(None, doc="cross-section dimensions (with E / "
                                                 "density)")
    hub_radius: float = param(0.0, unit="m", ge=0.0, doc="distance joint axis → beam root")
    thickness: Optional[float] = param(None, unit="m", gt=0.0,
                                       doc="section depth in the bending plane (for strain; "
                                           "default: the section's)")
    damping: BeamDamping = param(default_factory=BeamDamping, doc="beam damping")

    def __post_init__(self):
        derived = []
        sec = self.section
        if sec is not None:
            try:
                sec.validate("section")
            except SceneError:               # the loader reports it with its path
                object.__setattr__(self, "_derived", ())
                return
            for key, base, value in (("EI", self.E, sec.second_moment),
                                     ("mass_per_length", self.density, sec.area),
                                     ("thickness", 1.0, sec.depth)):
                if base is not None and getattr(self, key) is None:
                    object.__setattr__(self, key, base * value)
                    derived.append(key)
        object.__setattr__(self, "_derived", tuple(derived))

    @property
    def derived_keys(self) -> tuple:
        """The keys computed from the datasheet terms (not written by to_mapping)."""
        return getattr(self, "_derived", ())

    def validate(self, where):
        sec = self.section
        for key, base, name, unit in (("EI", "E", "second_moment", "N·m²"),
                                      ("mass_per_length", "density", "area", "kg/m")):
            given = getattr(self, base)
            if given is not None and sec is None:
                raise SceneError(f"{where}.section: missing, expected a section (rectangle, "
                                 f"tube or circle) with {where}.{base}")
            if getattr(self, key) is None:
                raise SceneError(f"{where}.{key}: missing, expected {key} [{unit}] or "
                                 f"{base} with a section")
            if given is not None and key not in self.derived_keys:
                want = given * getattr(sec, name)
                if abs(getattr(self, key) - want) > DERIVED_AGREE * want:
                    raise SceneError(f"{where}.{key}: got {getattr(self, key):g} and "
                                     f"{base} with a section giving {want:g}, expected one "
                                     f"of them")
        if sec is not None and self.E is None and self.density is None:
            raise SceneError(f"{where}.section: got a section without E or density, "
                             f"expected E (→ EI) and/or density (→ mass_per_length) with it")

    def datasheet(self) -> str:
        """What the datasheet terms gave, for ``flexarm explain`` ('' if none)."""
        if not self.derived_keys:
            return ""
        parts = [self.section.describe()]
        if "EI" in self.derived_keys:
            parts.append(f"E {self.E:.4g} Pa → EI {self.EI:.4g} N·m² "
                         f"(I {self.section.second_moment:.4g} m⁴)")
        if "mass_per_length" in self.derived_keys:
            parts.append(f"density {self.density:.4g} kg/m³ → ρA {self.mass_per_length:.4g} "
                         f"kg/m (A {self.section.area:.4g} m²)")
        if "thickness" in self.derived_keys:
            parts.append(f"gauge depth {self.thickness:.4g} m")
        if self.E is not None and self.EA is None:
            parts.append(f"E·A {self.E * self.section.area:.4g} N, not used (give EA for the "
                         f"rod's stretch)")
        return "; ".join(parts)


@dataclass(frozen=True, kw_only=True)
class JointFlexibility:
    """Joint flexibility: a motor-side angle coupled to the link by a spring and damper."""
    stiffness: float = param(unit="N·m/rad", gt=0.0, doc="joint spring k")
    damping: float = param(0.0, unit="N·m·s/rad", ge=0.0, doc="joint damper c")
    motor_inertia: float = param(unit="kg·m²", gt=0.0,
                                 doc="motor-side inertia (rotor reflected through the gear)")


DRIVE_TYPES = ("dc_motor", "hydraulic")
_DC_FIELDS = ("gear_ratio", "torque_constant", "back_emf_constant", "resistance")
_DC_OPTIONAL = ("inductance", "supply_voltage", "current_limit", "rotor_inertia",
                "gear_efficiency")
_HYD_FIELDS = ("displacement", "valve_gain", "supply_pressure", "total_volume",
               "bulk_modulus", "rated_current")
_HYD_OPTIONAL = ("torque_efficiency", "leakage", "null_bias")


@dataclass(frozen=True, kw_only=True)
class Drive:
    """The actuator of a joint; its input is a voltage (dc_motor) or a valve current
    (hydraulic) program, and its output torque acts at the gearbox output.

    dc_motor (seed 000 Eq. 5.11, seed 001 Sec. 4): armature L di/dt + R i = V − K_b n θ̇,
    torque n K_t i at the output; with inductance 0 the current is quasi-static,
    i = (V − K_b n θ̇)/R. The gearbox/rotor inertia J_eq and viscous loss C_eq are the joint's
    ``drive_inertia`` and ``drive_damping``. hydraulic (seed 002 Appendix B): servovalve
    Q = K_v i √(P_s − sgn(i) P_L), actuator Q = D_m θ̇ + C_tm P_L + V_t/(4β_e) Ṗ_L,
    torque η_t D_m P_L, P_L within ±P_s.
    """
    type: str = param(choices=DRIVE_TYPES, doc="drive model")
    # dc_motor
    gear_ratio: Optional[float] = param(None, unit="", gt=0.0,
                                        doc="dc_motor: gear ratio n (motor turns per output turn)")
    torque_constant: Optional[float] = param(None, unit="N·m/A", gt=0.0,
                                             doc="dc_motor: motor torque constant K_t")
    back_emf_constant: Optional[float] = param(None, unit="V·s/rad", gt=0.0,
                                               doc="dc_motor: back-EMF constant K_b")
    resistance: Optional[float] = param(None, unit="Ω", gt=0.0,
                                        doc="dc_motor: armature resistance R")
    inductance: Optional[float] = param(None, unit="H", ge=0.0,
                                        doc="dc_motor: armature inductance L (0: current "
                                            "quasi-static)")
    supply_voltage: Optional[float] = param(None, unit="V", gt=0.0,
                                            doc="dc_motor: |V| is clipped to this (amplifier "
                                                "supply), and the ROS twin's motor driver "
                                                "rejects commands beyond it; none: the model "
                                                "does not clip and the driver accepts up to "
                                                "48 V (the stated default)")
    current_limit: Optional[float] = param(None, unit="A", gt=0.0,
                                           doc="dc_motor: |i| is limited to this; the ROS "
                                               "twin's simulator rejects efforts beyond "
                                               "n·K_t·current_limit; none: no limit in the "
                                               "model, the twin's torque limit is "
                                               "n·K_t·2·V_max/R (the plugging current from "
                                               "the no-load speed)")
    rotor_inertia: Optional[float] = param(None, unit="kg·m²", ge=0.0, le=1.0,
                                           doc="dc_motor: rotor inertia J_m on the motor "
                                               "shaft (datasheet); adds n²·J_m to the "
                                               "joint's drive_inertia")
    gear_efficiency: Optional[float] = param(None, unit="", gt=0.0, le=1.0,
                                             doc="dc_motor: gearbox efficiency η: output "
                                                 "torque η·n·K_t·i (default 1)")
    # hydraulic
    displacement: Optional[float] = param(None, unit="m³/rad", gt=0.0,
                                          doc="hydraulic: actuator displacement D_m")
    torque_efficiency: Optional[float] = param(None, unit="", gt=0.0, le=1.0,
                                               doc="hydraulic: torque efficiency η_t "
                                                   "(default 1)")
    leakage: Optional[float] = param(None, unit="m³/(s·Pa)", ge=0.0,
                                     doc="hydraulic: total leakage coefficient C_tm "
                                         "(default 0)")
    valve_gain: Optional[float] = param(None, unit="m³/(s·A·√Pa)", gt=0.0,
                                        doc="hydraulic: servovalve flow gain K_v")
    supply_pressure: Optional[float] = param(None, unit="Pa", gt=0.0,
                                             doc="hydraulic: supply pressure P_s")
    total_volume: Optional[float] = param(None, unit="m³", gt=0.0,
                                          doc="hydraulic: total compressed volume V_t")
    bulk_modulus: Optional[float] = param(None, unit="Pa", gt=0.0,
                                          doc="hydraulic: effective bulk modulus β_e")
    rated_current: Optional[float] = param(None, unit="A", gt=0.0,
                                           doc="hydraulic: valve current range ±i_max "
                                               "(programs beyond it are refused)")
    null_bias: Optional[bool] = param(None, doc="hydraulic: add the null current that holds "
                                                "the initial state at rest (default true)")

    @property
    def output_torque_constant(self) -> float:
        """η·K_t: output torque per ampere per gear ratio (dc_motor), N·m/A."""
        return (self.gear_efficiency or 1.0) * self.torque_constant

    @property
    def reflected_rotor_inertia(self) -> float:
        """n²·J_m on the gearbox output (dc_motor with rotor_inertia; else 0), kg·m²."""
        if self.type != "dc_motor" or not self.rotor_inertia:
            return 0.0
        return self.gear_ratio ** 2 * self.rotor_inertia

    def validate(self, where):
        own, optional = ((_DC_FIELDS, _DC_OPTIONAL) if self.type == "dc_motor"
                         else (_HYD_FIELDS, _HYD_OPTIONAL))
        for f in own:
            if getattr(self, f) is None:
                raise SceneError(f"{where}.{f}: missing, expected a value for a {self.type} "
                                 f"drive")
        for f in _DC_FIELDS + _DC_OPTIONAL + _HYD_FIELDS + _HYD_OPTIONAL:
            if f not in own + optional and getattr(self, f) is not None:
                raise SceneError(f"{where}.{f}: got {getattr(self, f)}, expected no {f} on a "
                                 f"{self.type} drive (it belongs to the other drive type)")


@dataclass(frozen=True, kw_only=True)
class Backlash:
    """Gear backlash: a motor-side angle (gearbox output side, inertia = the joint's
    ``drive_inertia``) coupled to the link through a dead zone of total ``width`` and a mesh
    contact spring/damper that only acts while the teeth touch:
    τ = k·(δ ∓ width/2) + c·δ̇ for |δ| > width/2, else 0 (δ = motor − link angle), never
    pulling."""
    width: float = param(unit="rad", ge=0.0, doc="total dead-zone width at the output")
    stiffness: float = param(unit="N·m/rad", gt=0.0, doc="mesh contact stiffness k")
    damping: float = param(0.0, unit="N·m·s/rad", ge=0.0, doc="mesh contact damping c")


@dataclass(frozen=True, kw_only=True)
class Joint:
    """A revolute joint: link-side angle relative to the previous link's tip frame."""
    initial_angle: float = param(0.0, unit="rad", doc="initial joint angle")
    initial_angle_deg: Optional[float] = param(None, unit="deg",
                                               doc="initial angle in degrees (edge unit)")
    initial_rate: float = param(0.0, unit="rad/s", doc="initial joint rate")
    drive_inertia: float = param(0.0, unit="kg·m²", ge=0.0,
                                 doc="reflected gearbox/rotor inertia J_eq on the drive "
                                     "coordinate (seed 000 Eq. 5.11)")
    drive_damping: float = param(0.0, unit="N·m·s/rad", ge=0.0,
                                 doc="viscous drive damping C_eq (seed 000 Eq. 5.11)")
    flexibility: Optional[JointFlexibility] = param(None, doc="joint flexibility, if any")
    backlash: Optional[Backlash] = param(None, doc="gear backlash (adds a motor-side "
                                                   "coordinate)")
    drive: Optional[Drive] = param(None, doc="actuator (dc_motor or hydraulic); none: the "
                                             "joint takes torque programs directly")
    torque_limit: Optional[float] = param(None, unit="N·m", gt=0.0,
                                          doc="joint without a drive: the ROS twin rejects "
                                              "torque commands and efforts beyond ±this; "
                                              "none: 1000 N·m (the stated default). A joint "
                                              "with a drive takes its limit from the drive "
                                              "(flexarm explain prints every limit)")
    position_limits: Optional[tuple[float, float]] = param(
        None, unit="rad", doc="lowest and highest joint angle a target may ask for: the "
                              "position controller refuses targets, moves and trajectories "
                              "beyond them (none: no limit)")

    def validate(self, where):
        if self.position_limits is not None and not (
                self.position_limits[0] < self.position_limits[1]):
            raise SceneError(f"{where}.position_limits: got {list(self.position_limits)}, "
                             f"expected [lowest, highest] with lowest < highest (rad)")
        if self.flexibility is not None and self.backlash is not None:
            raise SceneError(f"{where}.backlash: got both flexibility and backlash, expected "
                             f"one (backlash carries its own mesh stiffness)")
        if self.backlash is not None and self.total_drive_inertia == 0.0:
            raise SceneError(f"{where}.drive_inertia: got 0.0, expected > 0 kg·m² with "
                             f"backlash (the motor-side coordinate needs inertia)")
        if self.torque_limit is not None and self.drive is not None:
            raise SceneError(f"{where}.torque_limit: got {self.torque_limit}, expected no "
                             f"torque_limit on a joint with a {self.drive.type} drive (its "
                             f"limit follows from the drive: current_limit, supply_voltage "
                             f"or supply_pressure)")
        if self.initial_angle_deg is not None and self.initial_angle != 0.0:
            raise SceneError(f"{where}.initial_angle_deg: got {self.initial_angle_deg}, "
                             f"expected only one of initial_angle / initial_angle_deg")

    @property
    def total_drive_inertia(self) -> float:
        """drive_inertia + n²·J_m of the drive's rotor (``drive.rotor_inertia``), kg·m²:
        what the drive coordinate carries (seed 000 Eq. 5.11's J_eq)."""
        return self.drive_inertia + (self.drive.reflected_rotor_inertia
                                     if self.drive is not None else 0.0)

    @property
    def angle0(self) -> float:
        import math
        if self.initial_angle_deg is not None:
            return math.radians(self.initial_angle_deg)
        return self.initial_angle


@dataclass(frozen=True, kw_only=True)
class Link:
    """One link of the chain: joint → hub body → beam → tip body."""
    name: str = param(doc="link name (used in coordinate names)")
    beam: Beam = param(doc="the flexible beam")
    joint: Joint = param(default_factory=Joint, doc="the joint at the link's root")
    hub: RigidBody = param(default_factory=RigidBody, doc="hub body at the joint")
    tip: TipBody = param(default_factory=TipBody, doc="body at the beam tip")

    def validate(self, where):
        check_name(f"{where}.name", self.name)
        b = self.beam
        if b.hub_radius > HUB_RADIUS_PER_LENGTH * b.length:
            ratio = b.hub_radius / b.length
            raise SceneError(
                f"{where}.beam.hub_radius: got {b.hub_radius} m, expected at most "
                f"{HUB_RADIUS_PER_LENGTH:g} beam lengths ({HUB_RADIUS_PER_LENGTH * b.length:g} "
                f"m for {where}.beam.length = {b.length} m): the beam's mass sits at the hub "
                f"radius, so the "
                f"joint inertia (~ m·r²) outweighs the beam's bending inertia by ~{ratio**2:.0e} "
                f"and the mass matrix loses the elastic coordinates to round-off")
        for key, xy in (("hub.cg", self.hub.cg), ("tip.cg", self.tip.cg),
                        ("tip.joint_offset", self.tip.joint_offset)):
            if math.hypot(*xy) > HUB_RADIUS_PER_LENGTH * b.length:
                raise SceneError(
                    f"{where}.{key}: got {list(xy)} m, expected within "
                    f"{HUB_RADIUS_PER_LENGTH:g} beam lengths of its frame "
                    f"({HUB_RADIUS_PER_LENGTH * b.length:g} m for {where}.beam.length = "
                    f"{b.length} m): a body or joint that far out makes the mass matrix "
                    f"lose the beam's coordinates to round-off")

    @property
    def reach(self) -> float:
        """Joint axis to the next joint (or the tip) with the beam straight, m."""
        return (self.beam.hub_radius + self.beam.length
                + math.hypot(*self.tip.joint_offset))


@dataclass(frozen=True, kw_only=True)
class Program:
    """A time program u(t) for a joint torque (N·m) or a prescribed joint motion (rad).

    Input types (torque N·m, voltage V or valve current A): constant {value}; step
    {offset, amplitude, start} (offset before start, offset + amplitude from start); pulse
    {amplitude, start, width}; square {amplitude,
    frequency_hz, phase_deg, offset, start}; piecewise_constant {times, values} (value i
    holds from times[i]); piecewise_linear {times, values}. Motion types: spin_up
    {omega, ramp_time} (Kane, Ryan & Banerjee 1987 profile); smooth_step {amplitude, start,
    ramp_time} (cycloidal move by ``amplitude`` rad); hold (joint clamped at its initial
    angle).
    """
    type: str = param(doc="program type", choices=TORQUE_PROGRAMS + MOTION_PROGRAMS)
    value: float = param(0.0, doc="constant value")
    amplitude: float = param(0.0, doc="pulse / square / smooth_step amplitude")
    start: float = param(0.0, unit="s", ge=0.0, doc="start time")
    width: float = param(0.0, unit="s", ge=0.0, doc="pulse width")
    frequency_hz: float = param(1.0, unit="Hz", gt=0.0, doc="square-wave frequency")
    phase_deg: float = param(0.0, unit="deg", doc="square-wave phase")
    offset: float = param(0.0, doc="square-wave offset")
    times: tuple[float, ...] = param((), unit="s", doc="breakpoint times (ascending)")
    values: tuple[float, ...] = param((), doc="breakpoint values")
    omega: float = param(0.0, unit="rad/s", doc="spin_up final rate Ω")
    ramp_time: float = param(1.0, unit="s", gt=0.0, doc="spin_up / smooth_step ramp time")

    #: the keys each program type reads (:func:`flexarm_ros.model.programs.eval_torque`,
    #: ``eval_motion``); any other key of a program is refused naming these
    #: (:func:`flexarm_ros.scene.schema.accepted_keys`)
    KEYED_BY, NOUN = "type", "program"
    KEYS = {"constant": ("value",), "step": ("offset", "amplitude", "start"),
            "pulse": ("amplitude", "start", "width"),
            "square": ("amplitude", "frequency_hz", "phase_deg", "offset", "start"),
            "piecewise_constant": ("times", "values"), "piecewise_linear": ("times", "values"),
            "spin_up": ("omega", "ramp_time"), "smooth_step": ("amplitude", "start", "ramp_time"),
            "hold": ()}

    def validate(self, where):
        if self.type in ("piecewise_constant", "piecewise_linear"):
            if len(self.times) == 0 or len(self.times) != len(self.values):
                raise SceneError(f"{where}.times: got {len(self.times)} times and "
                                 f"{len(self.values)} values, expected equal non-zero lengths")
            if any(b <= a for a, b in zip(self.times, self.times[1:])):
                raise SceneError(f"{where}.times: got {list(self.times)}, expected strictly "
                                 f"ascending times")


@dataclass(frozen=True, kw_only=True)
class Input:
    """Drives one joint (1-based index): a torque program (joint without a drive), a voltage
    program (dc_motor drive), a valve-current program (hydraulic drive) or a prescribed
    motion."""
    joint: int = param(unit="", ge=1, doc="joint number, 1-based")
    torque: Optional[Program] = param(None, doc="joint torque program (N·m)")
    voltage: Optional[Program] = param(None, doc="motor voltage program (V), dc_motor drive")
    current: Optional[Program] = param(None, doc="servovalve current program (A), hydraulic "
                                                 "drive")
    motion: Optional[Program] = param(None, doc="prescribed joint motion (rad)")

    @property
    def kind(self) -> str:
        return next(k for k in INPUT_KINDS if getattr(self, k) is not None)

    @property
    def program(self) -> Program:
        return getattr(self, self.kind)

    def validate(self, where):
        given = [k for k in INPUT_KINDS if getattr(self, k) is not None]
        if len(given) != 1:
            raise SceneError(f"{where}: got {', '.join(given) if given else 'none'} of "
                             f"{'/'.join(INPUT_KINDS)}, expected exactly one")
        kind = given[0]
        allowed = MOTION_PROGRAMS if kind == "motion" else TORQUE_PROGRAMS
        if self.program.type not in allowed:
            raise SceneError(f"{where}.{kind}.type: got {self.program.type!r}, expected one "
                             f"of {', '.join(allowed)}")


@dataclass(frozen=True, kw_only=True)
class Sensor:
    """A sensor read from the model at its own sample rate (docs/physics.md §9).

    encoder: counts = ⌊n·(θ − θ₀)·lines·quadrature/2π⌋ of the drive coordinate θ (gearbox
    output side; n the drive's gear ratio when ``on_motor_shaft``), integer.
    accelerometer: specific force (r̈ − g)·ê along ``axis`` (in the frame of the body at
    ``position``, rotating with the beam slope on a beam), m/s², and volts via
    ``sensitivity``. strain: (t/2)·w″(x) at the gauge (beam ``thickness`` t), –.
    potentiometer: link-side joint angle, rad. tip_position: x, y of the last beam tip, m.
    Optional noise (Gaussian, std in output units, explicit seed) and ADC (range, bits)
    apply to the published value (volts when ``sensitivity`` is given).
    """
    name: str = param(doc="sensor name (column / channel name)")
    kind: str = param(choices=SENSOR_KINDS, doc="what it measures")
    rate_hz: float = param(unit="Hz", gt=0.0, le=1e6, doc="sample rate")
    joint: int = param(0, ge=0, doc="encoder / potentiometer: joint number, 1-based")
    link: str = param("", doc="accelerometer / strain: link name")
    body: str = param("beam", choices=("hub", "beam", "tip"),
                      doc="accelerometer: body carrying it")
    position: tuple[float, float] = param((0.0, 0.0), unit="m",
                                          doc="beam: (abscissa x from the beam root, 0); "
                                              "hub/tip: point in the body frame")
    axis: tuple[float, float] = param((0.0, 1.0), doc="accelerometer: sensing axis in the "
                                      "body frame (default transverse, b2)")
    frame_id: str = param("", doc="frame id on the wire (default: the sensor name)")
    sensitivity: Optional[float] = param(None, doc="output volts per SI unit (V/(m/s²), "
                                                   "V/strain, V/rad); none: SI output")
    lines_per_rev: int = param(500, ge=1, doc="encoder: lines per revolution")
    quadrature: int = param(4, ge=1, le=4, doc="encoder: counts per line (4: ×4 decoding)")
    on_motor_shaft: bool = param(True, doc="encoder: on the motor shaft (× gear ratio)")
    noise_std: float = param(0.0, ge=0.0, doc="Gaussian noise std in output units")
    seed: int = param(0, ge=0, doc="noise random seed")
    adc_range: Optional[tuple[float, float]] = param(None, doc="ADC input range (lo, hi) in "
                                                              "output units; clipped")
    adc_bits: Optional[int] = param(None, ge=1, le=32, doc="ADC resolution (needs adc_range)")

    #: the keys each sensor kind reads (:mod:`flexarm_ros.model.sensors`): encoder counts
    #: and the tip position take no noise, sensitivity or ADC
    #: (:func:`flexarm_ros.scene.schema.accepted_keys`)
    KEYED_BY, NOUN = "kind", "sensor"
    COMMON = ("name", "kind", "rate_hz", "frame_id")
    _ANALOG = ("sensitivity", "noise_std", "seed", "adc_range", "adc_bits")
    KEYS = {"encoder": ("joint", "lines_per_rev", "quadrature", "on_motor_shaft"),
            "accelerometer": ("link", "body", "position", "axis") + _ANALOG,
            "strain": ("link", "position") + _ANALOG,
            "potentiometer": ("joint",) + _ANALOG,
            "tip_position": ()}

    def validate(self, where):
        check_name(f"{where}.name", self.name)
        if self.kind in ("encoder", "potentiometer") and self.joint == 0:
            raise SceneError(f"{where}.joint: got 0 (none), expected the joint number "
                             f"(1-based) for {'an' if self.kind == 'encoder' else 'a'} "
                             f"{self.kind}")
        if self.kind in ("accelerometer", "strain") and not self.link:
            raise SceneError(f"{where}.link: missing, expected the link name for a "
                             f"{self.kind}")
        if self.adc_bits is not None and self.adc_range is None:
            raise SceneError(f"{where}.adc_bits: got {self.adc_bits} without adc_range, "
                             f"expected adc_range (lo, hi) too")
        if self.adc_range is not None and not self.adc_range[1] > self.adc_range[0]:
            raise SceneError(f"{where}.adc_range: got {list(self.adc_range)}, expected lo < hi")
        if self.kind == "accelerometer" and self.axis[0] ** 2 + self.axis[1] ** 2 == 0.0:
            raise SceneError(f"{where}.axis: got {list(self.axis)}, expected a non-zero "
                             f"direction")


@dataclass(frozen=True, kw_only=True)
class Wall:
    """A straight wall in the plane: the line through ``point`` with inward ``normal``
    (pointing into the free side); the gap of the tool point is g = n·(r_tool − point).

    friction/static_friction: Coulomb coefficients (seed 000: μ = 0.5 kinetic).
    stiffness/exponent/damping_ratio/slip_velocity are used by the compliant rung only:
    F_n = max(0, k δ^e + c δ̇) for penetration δ = −g > 0, c = 2ζ√(k m_eff) (a penalty
    spring–damper with a damping fixed at the start, see :mod:`flexarm_ros.model.contact`),
    friction −μ F_n v_t/√(v_t² + v_s²).
    """
    point: tuple[float, float] = param(unit="m", doc="a point on the wall line")
    normal: tuple[float, float] = param(doc="inward normal (into the free side)")
    friction: float = param(0.0, ge=0.0, doc="kinetic friction coefficient μ")
    static_friction: Optional[float] = param(None, ge=0.0, doc="static friction "
                                             "coefficient μ_s (default μ)")
    stiffness: float = param(1e6, unit="N/m^e", gt=0.0, doc="compliant rung: contact "
                                                          "stiffness k")
    exponent: float = param(1.0, ge=1.0, le=2.0, doc="compliant rung: force exponent e "
                                                    "(1 linear, 1.5 Hertz)")
    damping_ratio: float = param(3.0, ge=0.0, doc="compliant rung: damping c = 2ζ√(k m) "
                                 "of the contact, m the tool's effective mass at the start; "
                                 "the contact's own restitution is 0.135 / 0.048 / 0.024 / "
                                 "0.009 for ζ = 1 / 2 / 3 / 5 (measured), 1 for ζ = 0; "
                                 "the impulse rung has none")
    slip_velocity: float = param(1e-3, unit="m/s", gt=0.0,
                                 doc="compliant rung: friction regularization speed v_s")

    def validate(self, where):
        if self.normal[0] ** 2 + self.normal[1] ** 2 == 0.0:
            raise SceneError(f"{where}.normal: got {list(self.normal)}, expected a non-zero "
                             f"direction")
        if self.static_friction is not None and self.static_friction < self.friction:
            raise SceneError(f"{where}.static_friction: got {self.static_friction}, expected "
                             f">= friction ({self.friction})")

    @property
    def mu_static(self) -> float:
        return self.friction if self.static_friction is None else self.static_friction


#: standard gravity (m/s²) for the normal load of an air bearing on a horizontal table: the
#: scene's ``gravity`` is the in-plane vector (zero on a horizontal table), so the weight a
#: bearing carries comes from the body's mass and this value (docs/physics.md §8.5)
STANDARD_GRAVITY = 9.81


@dataclass(frozen=True, kw_only=True)
class HighSpot:
    """A high spot of the table where a bearing touches it: the friction coefficient grows
    by μ_i exp(−|r_b − c_i|²/ρ_i²) around the point c_i (seed 000 lines 3857-3859, 4000-4001:
    the bearings touch the table only at a few high spots)."""
    point: tuple[float, float] = param(unit="m", doc="c_i: the spot's centre on the table "
                                                     "(world frame)")
    radius: float = param(unit="m", gt=0.0, doc="ρ_i: its size (1/e radius)")
    friction: float = param(ge=0.0, le=1.0, doc="μ_i: the friction coefficient at its "
                                                "centre, added to the bearing's")


@dataclass(frozen=True, kw_only=True)
class Bearing:
    """An air bearing under a hub or tip body, rubbing the table it floats on.

    Regularized Coulomb friction at the bearing point r_b against its planar velocity v_b:
    F = −μ(r_b) N v_b/√(|v_b|² + v_s²), N = m g₀ + b |τ| (m the body's mass, g₀ = 9.81
    m/s², τ the torque of the drive housed on the body), μ(r_b) = μ + Σ_i μ_i
    exp(−|r_b − c_i|²/ρ_i²) over the high spots, entered as Q = J_bᵀF (docs/physics.md
    §8.5; seed 000 lines 3853-3860, 3936-3938, 3990-4003: the bearings touch the table at a
    few high spots, the middle one tips and binds under an uneven load).
    """
    link: str = param(doc="the link whose body stands on the bearing (a links[].name)")
    body: str = param("tip", choices=("hub", "tip"), doc="which body of that link")
    position: Optional[tuple[float, float]] = param(
        None, unit="m", doc="bearing point in the body's frame (none: the body's CG)")
    friction: float = param(0.0, ge=0.0, le=1.0,
                            doc="Coulomb coefficient μ between bearing and table (0: floats "
                                "free)")
    slip_velocity: float = param(1e-3, unit="m/s", gt=0.0,
                                 doc="regularization speed v_s: below it the friction "
                                     "grows linearly with the speed (the stick)")
    binding: float = param(0.0, unit="1/m", ge=0.0,
                           doc="b: extra normal load per N·m of the torque of the drive "
                               "housed on the body (the next joint's), N = m g₀ + b|τ|: a "
                               "bearing that tips and binds under the load the arm puts on "
                               "it (0: none)")
    high_spots: tuple[HighSpot, ...] = param((), doc="high spots of the table where this "
                                                     "bearing's friction grows (none: μ "
                                                     "everywhere)")


@dataclass(frozen=True, kw_only=True)
class Tool:
    """The tool point that touches walls, fixed in the last link's tip-body frame."""
    position: tuple[float, float] = param((0.0, 0.0), unit="m",
                                          doc="tool point in the last tip frame")


@dataclass(frozen=True, kw_only=True)
class Sanding:
    """Sanding task parameters (seed 000 Sec. 5.4 demo): approach the wall, press with a
    normal force, slide between two points along it, reverse, lift off
    (:class:`flexarm_ros.control.sanding.SandingTask`)."""
    wall_x: float = param(unit="m", doc="wall line x")
    y_start: float = param(unit="m", doc="stroke start along the wall")
    y_end: float = param(unit="m", doc="stroke end along the wall")
    speed: float = param(0.1, unit="m/s", gt=0.0, doc="sliding speed")
    normal_force: float = param(5.0, unit="N", gt=0.0, doc="normal force set point")
    approach_time: float = param(1.0, unit="s", gt=0.0, doc="time to reach the wall")
    kp_force: float = param(0.02, unit="m/(N·s)", gt=0.0,
                            doc="force-through-position gain")
    strokes: int = param(2, ge=1, doc="passes along the wall")
    offset_max: float = param(0.05, unit="m", gt=0.0,
                              doc="largest correction of the tool target beyond the wall line "
                                  "(±) the force loop may make")
    search_speed: float = param(0.02, unit="m/s", gt=0.0,
                                doc="speed of the search towards the wall when the approach "
                                    "ends without contact")
    search_timeout: float = param(2.0, unit="s", ge=0.0,
                                  doc="search time before the task stops with a status")
    press_time: float = param(0.2, unit="s", ge=0.0,
                              doc="time the force must stay within tolerance before sliding")
    press_timeout: float = param(10.0, unit="s", gt=0.0,
                                 doc="pressing time before the task stops with a status")
    force_tolerance: float = param(0.1, gt=0.0,
                                   doc="relative band around normal_force counted as reached")
    reverse_time: float = param(0.1, unit="s", ge=0.0, doc="dwell at each stroke end")
    lift_distance: float = param(0.05, unit="m", gt=0.0, doc="lift-off distance from the wall")
    lift_time: float = param(1.0, unit="s", gt=0.0, doc="time of the lift-off move")


#: a shaper's impulse amplitudes must sum to 1 within this (the move keeps its length)
SHAPER_SUM_TOLERANCE = 1e-9
MAX_SHAPER_IMPULSES = 256


@dataclass(frozen=True, kw_only=True)
class Shaper:
    """An input shaper on the position controller's joint targets (Singer & Seering 1990):
    the step from the start angles q₀ to the target q* becomes the staircase
    q_cmd(t) = q₀ + Σᵢ Aᵢ·H(t − tᵢ)·(q* − q₀), ΣAᵢ = 1. ``flexarm design --shaper`` writes
    one from the loop's own modes and records what it used."""
    times: tuple[float, ...] = param(unit="s", doc="impulse times, ascending, the first 0")
    amplitudes: tuple[float, ...] = param(doc="impulse amplitudes, summing to 1")
    design: str = param("", doc="what the shaper was designed on (written by flexarm "
                                "design: shaper, modes, pose, version)")
    frequencies_hz: tuple[float, ...] = param((), unit="Hz",
                                              doc="the shaped modes' natural frequencies")
    damping_ratios: tuple[float, ...] = param((), doc="the shaped modes' damping ratios")

    def validate(self, where):
        n = len(self.times)
        if n == 0 or n != len(self.amplitudes):
            raise SceneError(f"{where}.times: got {n} times and {len(self.amplitudes)} "
                             f"amplitudes, expected equal non-zero lengths")
        if n > MAX_SHAPER_IMPULSES:
            raise SceneError(f"{where}.times: got {n} impulses, expected at most "
                             f"{MAX_SHAPER_IMPULSES}")
        if self.times[0] != 0.0:
            raise SceneError(f"{where}.times[0]: got {self.times[0]}, expected 0 (the "
                             f"first impulse at the step)")
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise SceneError(f"{where}.times: got {list(self.times)}, expected strictly "
                             f"ascending times")
        total = math.fsum(self.amplitudes)
        if abs(total - 1.0) > SHAPER_SUM_TOLERANCE:
            raise SceneError(f"{where}.amplitudes: got a sum of {total!r}, expected 1 "
                             f"(within {SHAPER_SUM_TOLERANCE:g}: the shaped move keeps its "
                             f"length)")
        if len(self.frequencies_hz) != len(self.damping_ratios):
            raise SceneError(f"{where}.damping_ratios: got {len(self.damping_ratios)}, "
                             f"expected one per frequency ({len(self.frequencies_hz)})")

    def share(self, t: float) -> float:
        """Σ Aᵢ over the impulses at or before ``t`` (0 before the first); an impulse
        within 1 ns of ``t`` counts as reached (the batch run's tick times and the ROS
        clock's integer nanoseconds agree on every impulse)."""
        return math.fsum(a for ti, a in zip(self.times, self.amplitudes) if ti <= t + 1e-9)


@dataclass(frozen=True, kw_only=True)
class Move:
    """One point of a move program (``control.moves``): the joint targets to reach at
    ``time`` s after the start (joint_trajectory_controller's ``time_from_start``),
    optionally the joint rates there (then the path between points is cubic, else
    linear; :mod:`flexarm_ros.control.trajectory`)."""
    time: float = param(unit="s", gt=0.0, doc="time from the start of the run")
    joint_target: tuple[float, ...] = param(unit="rad", doc="joint angles, one per joint")
    joint_rate: tuple[float, ...] = param((), unit="rad/s",
                                          doc="joint rates there (all points or none)")


@dataclass(frozen=True, kw_only=True)
class Change:
    """One change of the position loop while it runs (``control.changes``): from the first
    control tick at or after ``time`` the joint PD uses these gains and tracks this
    target (each left empty keeps its value). A parameter set on the controller node
    (``ros2 param set /flexarm/controller kp "[8.0, 8.0]"``) is applied at the next tick
    and recorded on ``controller/parameter_changes`` as exactly such an entry, so the
    scene with the bag's entries reruns the live run."""
    time: float = param(unit="s", ge=0.0, doc="scene time from which it applies")
    kp: tuple[float, ...] = param((), unit="N·m/rad", ge=0.0,
                                  doc="PD stiffness per joint (empty: unchanged)")
    kd: tuple[float, ...] = param((), unit="N·m·s/rad", ge=0.0,
                                  doc="PD damping per joint (empty: unchanged)")
    joint_target: tuple[float, ...] = param((), unit="rad",
                                            doc="a new step target, one angle per joint "
                                                "(empty: unchanged); shaped by "
                                                "control.shaper from the current command")
    voltage_limit: tuple[float, ...] = param((), unit="V", gt=0.0,
                                             doc="the controller's output limit per joint, "
                                                 "at most the drive's (empty: unchanged)")
    shaper: Optional[Shaper] = param(None, doc="position mode: the shaper of the target "
                                               "steps from this change on (one impulse "
                                               "[0] of [1]: none); the step under way "
                                               "keeps its own")


@dataclass(frozen=True, kw_only=True)
class LqgWeights:
    """Bryson's-rule scales of an LQG design: the largest acceptable joint-angle error,
    tip deflection, joint rate and voltage (Q = 1/scale² on each, R = 1/voltage²)."""
    angle: float = param(unit="rad", gt=0.0, doc="joint angle error scale")
    deflection: float = param(unit="m", gt=0.0, doc="hub-frame tip deflection scale")
    rate: float = param(unit="rad/s", gt=0.0, doc="joint rate scale")
    voltage: float = param(unit="V", gt=0.0, doc="motor voltage scale")


@dataclass(frozen=True, kw_only=True)
class Lqg:
    """LQG position control (``flexarm design --lqg``, :mod:`flexarm_ros.control.lqg`):
    the regulator u = clip(−K x̂, ±V) on the current Kalman estimate x̂ of the arm's state
    (deviations from the target pose at rest), predicted by x̂⁻ = A x̂ + B u and corrected
    by the encoder angles y, x̂ = x̂⁻ + M (y − y* − C x̂⁻), every control period. The
    matrices are the controller's: the design writes them with what it used."""
    design: str = param("", doc="what the design used (plant, pose, weights, version)")
    weights: Optional[LqgWeights] = param(None, doc="the Bryson weights of the design")
    states: tuple[str, ...] = param((), doc="names of the model's states (x)")
    A: tuple[tuple[float, ...], ...] = param(doc="A_d, the sampled plant (n×n)")
    B: tuple[tuple[float, ...], ...] = param(unit="1/V", doc="B_d (n×joints), volts in")
    C: tuple[tuple[float, ...], ...] = param(doc="the measured encoder angles (joints×n)")
    K: tuple[tuple[float, ...], ...] = param(unit="V", doc="regulator gain (joints×n)")
    M: tuple[tuple[float, ...], ...] = param(doc="current-estimator gain (n×joints)")
    x_start: tuple[float, ...] = param(doc="the estimate at the start (n)")
    y_goal: tuple[float, ...] = param(unit="rad", doc="the encoder angles at the target")

    def validate(self, where):
        n = len(self.A)
        m = len(self.y_goal)
        shapes = {"A": (n, n), "B": (n, m), "C": (m, n), "K": (m, n), "M": (n, m)}
        if n == 0 or m == 0:
            raise SceneError(f"{where}.A: got {n} states and {m} joints, expected both > 0")
        for key, (r, c) in shapes.items():
            mat = getattr(self, key)
            if len(mat) != r or any(len(row) != c for row in mat):
                got = f"{len(mat)}×{len(mat[0]) if mat else 0}"
                raise SceneError(f"{where}.{key}: got a {got} matrix, expected {r}×{c} "
                                 f"({n} states, {m} joints)")
        if len(self.x_start) != n:
            raise SceneError(f"{where}.x_start: got {len(self.x_start)} values, expected "
                             f"{n} (one per state)")
        if self.states and len(self.states) != n:
            raise SceneError(f"{where}.states: got {len(self.states)} names, expected {n}")
        import numpy as np
        A, B, K = np.array(self.A), np.array(self.B), np.array(self.K)
        rho = float(np.max(np.abs(np.linalg.eigvals(A - B @ K))))
        if not rho < 1.0:
            raise SceneError(f"{where}.K: got a regulator with |z| = {rho:.6g}, expected "
                             f"a stable loop (every pole of A − B K inside the unit circle)")


@dataclass(frozen=True, kw_only=True)
class Control:
    """What the controller node runs (seed 000 Sec. 5.4). open_loop: the scene's input
    programs as commands; position: joint PD (Eq. 5.16) with voltages from the static motor
    equation (Eq. 5.17) towards ``tip_target`` (Newton–Raphson inverse kinematics) or
    ``joint_target``; sanding: the sanding task through the same loop."""
    mode: str = param("open_loop", choices=("open_loop", "position", "sanding"),
                      doc="control mode")
    rate_hz: float = param(1000.0, unit="Hz", gt=0.0, le=1e6, doc="control rate")
    kp: tuple[float, ...] = param((), unit="N·m/rad", ge=0.0, doc="PD stiffness per joint")
    kd: tuple[float, ...] = param((), unit="N·m·s/rad", ge=0.0, doc="PD damping per joint")
    tip_target: Optional[tuple[float, float]] = param(None, unit="m",
                                                      doc="position mode: tip target")
    joint_target: tuple[float, ...] = param((), unit="rad",
                                            doc="position mode: joint targets")
    velocity_filter_hz: float = param(20.0, unit="Hz", gt=0.0,
                                      doc="encoder velocity low-pass cutoff")
    sanding: Optional[Sanding] = param(None, doc="sanding mode parameters")
    shaper: Optional[Shaper] = param(None, doc="position mode: an input shaper on the "
                                               "target step (flexarm design --shaper)")
    lqg: Optional[Lqg] = param(None, doc="position mode: LQG on the encoder angles in "
                                         "place of the joint PD (flexarm design --lqg)")
    moves: tuple[Move, ...] = param((), doc="position mode: a move program, the joint "
                                            "targets and the times to reach them, in place "
                                            "of tip_target / joint_target")
    watchdog_s: float = param(0.05, unit="s", gt=0.0,
                              doc="motor driver: commands older than this → 0 V / closed "
                                  "valve")
    changes: tuple[Change, ...] = param((), doc="position and sanding modes: gains and "
                                                "targets changed while the loop runs, in "
                                                "time order (a live run's "
                                                "controller/parameter_changes)")


@dataclass(frozen=True, kw_only=True)
class Fidelity:
    """Model and integrator choice: the rung of the ladder and how finely it is refined."""
    rung: str = param("cubic", choices=RUNG_CHOICES,
                      doc="beam discretization; auto: the cheapest rung, refinement and RK4 "
                          "step estimated to meet fidelity.tolerance (docs/accuracy.md)")
    refine: int = param(0, ge=0, doc="modes / elements / FD segments (0 → rung default; "
                                     "0 with rung auto, which chooses it)")
    modal_basis: str = param("chain_loaded", choices=("chain_loaded", "tip_loaded",
                                                      "clamped_free", "free_hub"),
                             doc="modal rung: modes of the beam carrying its tip body and "
                                 "the links outboard of it (locked at their initial "
                                 "angles), its tip body only, or nothing; free_hub: as "
                                 "chain_loaded on a hub free to turn with its inertia "
                                 "(the one-link arm's own modes)")
    rod_points: int = param(0, ge=0, le=64,
                            doc="rod rung: Gauss points carrying each beam's mass (0 → "
                                "the curvature terms + 3, at least 6; else at least one "
                                "more than the bending coordinates). Fewer are "
                                "cheaper; measure the change against the top rung "
                                "(two_link_free: 4 for 3 terms, docs/accuracy.md). Another "
                                "rung or refinement goes back to 0 unless rod_points is "
                                "given with it (a --set beside --refine is kept)")
    rod_modes: int = param(0, ge=0, le=16,
                           doc="rod rung: keep the lowest rod_modes bending modes of the "
                               "rod with fidelity.refine curvature terms as its "
                               "coordinates (and the stretch, with EA); 0 → all. Fewer "
                               "modes of more terms: the accurate low shapes without the "
                               "high rates that shorten the explicit step (two_link_free: "
                               "4 modes of rod 8 meet 1e-6 m in both measures at 3.5 ms, "
                               "rod 5 needs 1.7 ms; docs/decisions/0033-rod-modes.md). "
                               "Another rung or refinement goes back to 0 unless rod_modes "
                               "is given with it (a --set beside --refine is kept)")
    foreshortening: bool = param(True, doc="keep the quadratic foreshortening "
                                           "(geometric stiffening) terms")
    integrator: str = param("rk4", choices=INTEGRATORS, doc="time integrator")
    dt: float = param(0.0, unit="s", ge=0.0, doc="fixed step (rk4, rkn4, trapezoid, lawson4) or max step (0 → auto)")
    rtol: float = param(1e-8, gt=0.0, lt=1.0, doc="relative tolerance (adaptive)")
    atol: float = param(1e-10, gt=0.0, doc="absolute tolerance (adaptive)")
    output_dt: float = param(1e-3, unit="s", gt=0.0, doc="sample period of the output")
    tolerance: float = param(0.0, unit="m", ge=0.0,
                             doc="tip-position error bound of a batch run. With a named "
                                 "rung: the step is chosen from a step-halving estimate (rk4; "
                                 "with a wall the contact stepper's) or the linearized "
                                 "model (trapezoid) (0: off; the step from dt). With "
                                 "rung auto: the bound the rung, refinement and step are "
                                 "chosen for (0: the default 1e-5 m)")
    tolerance_metric: str = param("both", choices=("position", "deflection", "both"),
                                  doc="what fidelity.tolerance bounds: the tip position in "
                                      "the world frame, the elastic tip deflection of every "
                                      "link in its hub frame, or both (docs/accuracy.md)")
    estimate: bool = param(False, doc="batch run with a named rung (rk4): estimate its tip "
                                      "error as rung auto does (the a-priori analysis "
                                      "before, the check on a finer model after; 0.1-1 s "
                                      "more) and report it in the run summary")
    motor_current: str = param("dynamic", choices=("dynamic", "quasi_static"),
                               doc="dc_motor with inductance: integrate the current as a "
                                   "state, or take it quasi-static (L/R far below the step)")
    contact: str = param("impulse", choices=("impulse", "compliant"),
                         doc="wall contact: impulse–constraint (seed 000) or compliant "
                             "(penalty F = kδ^e + cδ̇, c = 2ζ√(k m_eff))")
    contact_tolerance: float = param(1e-9, unit="m", gt=0.0,
                                     doc="impulse rung: largest allowed drift of the tool "
                                         "off the wall while in contact")
    max_deflection_ratio: float = param(0.5, gt=0.0, doc="stop when |w_tip|/L exceeds this "
                                        "(small-deflection model no longer valid)")
    max_steps: float = param(1.0e8, unit="steps", ge=1.0,
                             doc="work budget: a run whose integrator needs more steps than "
                                 "this (duration / step, estimated before integrating) is "
                                 "refused with the eigenvalue and coordinate that set the "
                                 "step and what to change (--max-steps)")


    def validate(self, where):
        if self.rung != "auto":
            return
        key = f"{where}." if where else ""
        if self.refine != 0:
            raise SceneError(f"{key}refine: got {self.refine} with {key}rung 'auto', expected "
                             f"0 (auto chooses the refinement; name a rung to set it, e.g. "
                             f"--rung modal --refine {self.refine})")
        if self.integrator != "rk4":
            raise SceneError(f"{key}integrator: got {self.integrator!r} with {key}rung "
                             f"'auto', expected rk4, the default (auto chooses the step and "
                             f"takes rkn4 itself where it steps further; for another "
                             f"integrator name the rung, e.g. --rung modal --refine 3)")


@dataclass(frozen=True, kw_only=True)
class Initial:
    """Initial condition options."""
    static_equilibrium: bool = param(False, doc="start from the static deflection under "
                                                "gravity with the joints held")


@dataclass(frozen=True, kw_only=True)
class Assumption:
    """A value not given in the source, chosen and documented."""
    key: str = param(doc="the scene key path")
    note: str = param(doc="why this value")


@dataclass(frozen=True, kw_only=True)
class Scene:
    """A rig and an experiment."""
    name: str = param(doc="scene name")
    links: tuple[Link, ...] = param(doc="the chain, base to tip")
    description: str = param("", doc="what this scene reproduces")
    source: str = param("", doc="where the numbers come from")
    gravity: tuple[float, float] = param((0.0, 0.0), unit="m/s²",
                                         doc="gravity vector in the plane (0,0: none)")
    base_angle: float = param(0.0, unit="rad", doc="angle of the base frame")
    inputs: tuple[Input, ...] = param((), doc="joint torque / voltage / current / motion "
                                              "programs")
    sensors: tuple[Sensor, ...] = param((), doc="sensors read from the model")
    walls: tuple[Wall, ...] = param((), doc="walls the tool can touch (none: no contact "
                                           "model)")
    tool: Tool = param(default_factory=Tool, doc="the tool point on the last body")
    bearings: tuple[Bearing, ...] = param((), doc="air bearings rubbing the table under hub "
                                                  "or tip bodies (none: the bodies float "
                                                  "free)")
    control: Optional[Control] = param(
        None, doc="the bench's controller and motor driver. Declared: every run of the scene "
                  "— the ROS twin and every batch command — runs them in the loop at "
                  "control.rate_hz with the efforts held over each period (--open-loop: the "
                  "input programs alone). Left out: batch runs apply the input programs "
                  "continuously, and the twin samples them at the default 1 kHz")
    fidelity: Fidelity = param(default_factory=Fidelity, doc="model and integrator")
    initial: Initial = param(default_factory=Initial, doc="initial condition")
    duration: float = param(1.0, unit="s", gt=0.0, doc="default simulated duration")
    assumptions: tuple[Assumption, ...] = param((), doc="values not given in the source")

    @property
    def twin_control(self) -> Control:
        """The control section the ROS twin runs: the scene's, or the default (open loop at
        1 kHz) when it declares none."""
        return self.control if self.control is not None else Control()

    def validate(self, where):
        if not self.links:
            raise SceneError("links: got [], expected at least one link")
        names = [lk.name for lk in self.links]
        if len(set(names)) != len(names):
            raise SceneError(f"links: got names {names}, expected unique names")
        seen = set()
        for k, inp in enumerate(self.inputs):
            if inp.joint > len(self.links):
                raise SceneError(f"inputs[{k}].joint: got {inp.joint}, expected 1.."
                                 f"{len(self.links)} (number of links)")
            if inp.joint in seen:
                raise SceneError(f"inputs[{k}].joint: got {inp.joint}, expected one input "
                                 f"per joint")
            seen.add(inp.joint)
            jt = self.links[inp.joint - 1].joint
            if inp.motion is not None and (jt.flexibility or jt.backlash):
                raise SceneError(f"inputs[{k}].motion: got a prescribed motion on flexible "
                                 f"joint {inp.joint}, expected a torque program")
            want = {None: ("torque", "motion"), "dc_motor": ("voltage", "motion"),
                    "hydraulic": ("current", "motion")}[jt.drive.type if jt.drive else None]
            if inp.kind not in want:
                raise SceneError(f"inputs[{k}].{inp.kind}: joint {inp.joint} has "
                                 f"{'a ' + jt.drive.type if jt.drive else 'no'} drive "
                                 f"(links[{inp.joint - 1}].joint.drive), expected "
                                 f"{' or '.join(want)}")
            if inp.kind == "current":
                lo, hi = program_range(inp.current)
                imax = jt.drive.rated_current
                if max(abs(lo), abs(hi)) > imax * (1 + 1e-12):
                    raise SceneError(f"inputs[{k}].current: got a program reaching "
                                     f"{max(abs(lo), abs(hi)):.6g} A ("
                                     f"{program_fields(inp.current, f'inputs[{k}].current')}), "
                                     f"expected within the valve's rated current ±{imax:.6g} "
                                     f"A (links[{inp.joint - 1}].joint.drive.rated_current)")
        ctl = self.twin_control
        nj = len(self.links)
        for key in ("kp", "kd", "joint_target"):
            val = getattr(ctl, key)
            if val and len(val) != nj:
                raise SceneError(f"control.{key}: got {len(val)} values, expected {nj} (one "
                                 f"per joint)")
        if ctl.mode in ("position", "sanding") and not (ctl.kp and ctl.kd):
            raise SceneError(f"control.kp: missing, expected PD gains for mode {ctl.mode!r}")
        if ctl.mode == "position" and (
                (ctl.tip_target is not None) + bool(ctl.joint_target) + bool(ctl.moves)) != 1:
            raise SceneError("control.tip_target: expected exactly one of tip_target / "
                             "joint_target / moves for mode 'position'")
        if ctl.moves:
            from flexarm_ros.scene.trajectory_points import check_points
            if ctl.mode != "position" or ctl.lqg is not None:
                raise SceneError(f"control.moves: got a move program with control.mode "
                                 f"{ctl.mode!r}{' and an LQG' if ctl.lqg else ''}, expected "
                                 f"mode 'position' with the joint PD (the LQG regulates to "
                                 f"the one target it was designed at)")
            names = [lk.name for lk in self.links]
            rates = [m.joint_rate for m in ctl.moves]
            try:
                check_points(names, names, [m.time for m in ctl.moves],
                             [m.joint_target for m in ctl.moves],
                             rates if any(rates) else None,
                             [lk.joint.position_limits for lk in self.links],
                             fields={"points": "control.moves", "positions": "joint_target",
                                     "velocities": "joint_rate",
                                     "time_from_start": "control.moves.time"})
            except ValueError as exc:
                raise SceneError(str(exc)) from None
        if ctl.joint_target:
            self._check_target("control.joint_target", ctl.joint_target)
        if ctl.shaper is not None and ctl.mode != "position":
            raise SceneError(f"control.shaper: got a shaper with control.mode "
                             f"{ctl.mode!r}, expected mode 'position' (it shapes the target "
                             f"step)")
        if ctl.lqg is not None:
            if ctl.mode != "position" or ctl.shaper is not None:
                raise SceneError(f"control.lqg: got an LQG with control.mode {ctl.mode!r}"
                                 f"{' and a shaper' if ctl.shaper is not None else ''}, "
                                 f"expected mode 'position' without a shaper (it replaces "
                                 f"the joint PD's move)")
            if len(ctl.lqg.y_goal) != nj:
                raise SceneError(f"control.lqg.y_goal: got {len(ctl.lqg.y_goal)} joints, "
                                 f"expected {nj} (one per joint)")
        self._check_changes(ctl, nj)
        if ctl.mode == "sanding" and ctl.sanding is None:
            raise SceneError("control.sanding: missing, expected the sanding parameters "
                             "for mode 'sanding'")
        if len(self.walls) > 1:
            raise SceneError(f"walls: got {len(self.walls)} walls, expected at most one "
                             f"(one contact constraint at a time)")
        names = [lk.name for lk in self.links]
        self._check_bearings(names)
        sensor_names = set()
        for k, sn in enumerate(self.sensors):
            where = f"sensors[{k}]"
            if sn.name in sensor_names:
                raise SceneError(f"{where}.name: got {sn.name!r} twice, expected unique names")
            sensor_names.add(sn.name)
            if sn.kind in ("encoder", "potentiometer") and sn.joint > len(self.links):
                raise SceneError(f"{where}.joint: got {sn.joint}, expected 1..{len(self.links)}")
            if sn.kind in ("accelerometer", "strain"):
                if sn.link not in names:
                    raise SceneError(f"{where}.link: got {sn.link!r}, expected one of "
                                     f"{', '.join(names)}")
                beam = self.links[names.index(sn.link)].beam
                if (sn.kind == "strain" or sn.body == "beam") and not (
                        0.0 <= sn.position[0] <= beam.length and sn.position[1] == 0.0):
                    raise SceneError(f"{where}.position: got {list(sn.position)}, expected "
                                     f"(x, 0) with 0 <= x <= {beam.length} m on the beam "
                                     f"(links[{names.index(sn.link)}].beam.length)")
                if sn.kind == "strain" and beam.thickness is None:
                    raise SceneError(f"links[{names.index(sn.link)}].beam.thickness: missing, "
                                     f"expected the section depth for strain sensor "
                                     f"{sn.name!r}")
            drive = self.links[sn.joint - 1].joint.drive if sn.joint else None
            if (sn.kind == "encoder" and sn.on_motor_shaft
                    and (drive is None or drive.type != "dc_motor")):
                raise SceneError(f"{where}.on_motor_shaft: got true on joint {sn.joint} "
                                 f"without a dc_motor drive (no gear ratio), expected false "
                                 f"or a dc_motor drive")
            if sn.kind == "encoder":
                self._check_encoder_range(k, sn, drive)
        self._check_sensor_columns()
        for k, sn in enumerate(self.sensors):
            if 1.0 / sn.rate_hz > self.duration:
                raise SceneError(f"sensors[{k}].rate_hz: got {sn.rate_hz} Hz, a period "
                                 f"{1.0 / sn.rate_hz:.6g} s longer than the duration "
                                 f"{self.duration} s, expected at least "
                                 f"{1.0 / self.duration:.6g} Hz (a sample after the start)")
        self._check_reach()
        if self.fidelity.output_dt > self.duration:
            raise SceneError(f"fidelity.output_dt: got {self.fidelity.output_dt} s, expected "
                             f"at most the duration {self.duration} s (the output would hold "
                             f"the start sample only)")

    def _check_target(self, key: str, target) -> None:
        """A step target (rad per joint) within the joints' ``position_limits``, refused
        in one line naming ``key`` and the joint otherwise."""
        import numpy as np
        from flexarm_ros.scene.trajectory_points import beyond_limits
        out = beyond_limits(np.array([target], float),
                            [lk.joint.position_limits for lk in self.links])
        if out is not None:
            _, k, lo, hi = out
            raise SceneError(f"{key}[{k}]: got {target[k]:g} rad, expected within "
                             f"links[{k}].joint.position_limits [{lo:g}, {hi:g}] rad")

    def _check_changes(self, ctl, nj):
        """``control.changes``: in time order, one value per joint, PD modes only, a
        target only for the joint PD in position mode and within the joint limits."""
        last = -1.0
        for k, ch in enumerate(ctl.changes):
            where = f"control.changes[{k}]"
            if ctl.mode == "open_loop" or ctl.lqg is not None:
                raise SceneError(f"{where}: got a change with control.mode {ctl.mode!r}"
                                 f"{' and an LQG' if ctl.lqg else ''}, expected the joint PD "
                                 f"of mode 'position' or 'sanding' (the LQG's gains are its "
                                 f"design's: flexarm design --lqg)")
            if ch.time <= last:
                raise SceneError(f"{where}.time: got {ch.time:g} s, expected after the "
                                 f"previous change's {last:g} s")
            last = ch.time
            for key in ("kp", "kd", "joint_target", "voltage_limit"):
                val = getattr(ch, key)
                if val and len(val) != nj:
                    raise SceneError(f"{where}.{key}: got {len(val)} values, expected {nj} "
                                     f"(one per joint)")
            if not (ch.kp or ch.kd or ch.joint_target or ch.voltage_limit or ch.shaper):
                raise SceneError(f"{where}: got no kp, kd, joint_target, voltage_limit or "
                                 f"shaper, expected at least one to change")
            if ch.shaper is not None and ctl.mode != "position":
                raise SceneError(f"{where}.shaper: got a shaper with control.mode "
                                 f"{ctl.mode!r}, expected mode 'position' (it shapes the "
                                 f"target steps)")
            if ch.joint_target:
                if ctl.mode != "position":
                    raise SceneError(f"{where}.joint_target: got a target with control.mode "
                                     f"{ctl.mode!r}, expected mode 'position' (the sanding "
                                     f"task sets its own)")
                self._check_target(f"{where}.joint_target", ch.joint_target)
                bad = [v for v in ch.joint_target if not math.isfinite(v)]
                if bad:
                    raise SceneError(f"{where}.joint_target: got {bad[0]}, expected finite "
                                     f"angles (rad)")

    def _check_bearings(self, names):
        """Each bearing on an existing link's body with mass (its weight is the normal
        load), one bearing per body; binding only where a drive is housed on the body."""
        seen = {}
        for k, br in enumerate(self.bearings):
            where = f"bearings[{k}]"
            if br.link not in names:
                raise SceneError(f"{where}.link: got {br.link!r}, expected one of "
                                 f"{', '.join(names)}")
            i = names.index(br.link)
            body = getattr(self.links[i], br.body)
            if body.mass <= 0.0:
                raise SceneError(f"{where}.body: got {br.body!r} on link {br.link!r}, whose "
                                 f"mass is 0 (links[{i}].{br.body}.mass); expected a body "
                                 f"with mass (its weight is the bearing's normal load)")
            if (i, br.body) in seen:
                raise SceneError(f"{where}.link: got {br.link!r} {br.body} again (also "
                                 f"bearings[{seen[(i, br.body)]}]), expected one bearing "
                                 f"per body")
            seen[(i, br.body)] = k
            if br.binding > 0.0 and housed_drive(self, i, br.body) is None:
                raise SceneError(f"{where}.binding: got {br.binding} on link {br.link!r} "
                                 f"{br.body}, which houses no drive (the next joint's); "
                                 f"expected 0 or a tip body carrying the next link's drive")

    def _check_encoder_range(self, k, sn, drive):
        """Counts per output revolution × ENCODER_REVOLUTIONS must fit int32."""
        per_rev = sn.lines_per_rev * sn.quadrature
        ratio = drive.gear_ratio if sn.on_motor_shaft else 1.0
        if ratio * per_rev * ENCODER_REVOLUTIONS <= INT32_MAX:
            return
        limit = INT32_MAX / ENCODER_REVOLUTIONS
        if sn.on_motor_shaft and per_rev <= limit:          # the gear ratio is too large
            key = f"links[{sn.joint - 1}].joint.drive.gear_ratio"
            got = (f"got {ratio} with encoder sensors[{k}] ({sn.name!r}: "
                   f"{sn.lines_per_rev} lines × {sn.quadrature} on the motor shaft)")
        else:
            key = f"sensors[{k}].lines_per_rev"
            got = f"got {sn.lines_per_rev} (× {sn.quadrature} counts per line" + (
                f" × gear ratio {ratio:g})" if ratio != 1.0 else ")")
        raise SceneError(f"{key}: {got}: {ratio * per_rev:.6g} counts per output revolution, "
                         f"expected at most {limit:.6g} so that ±{ENCODER_REVOLUTIONS} "
                         f"revolutions fit the int32 counts of the encoder_counts message")

    def _check_sensor_columns(self):
        """The sensor tables' columns (``t``, ``<name>``/``<name>_true``, ``<name>_x``/
        ``_y``) must be unique."""
        seen = {"t": None}
        for k, sn in enumerate(self.sensors):
            cols = ([f"{sn.name}_x", f"{sn.name}_y"] if sn.kind == "tip_position"
                    else [sn.name, f"{sn.name}_true"])
            for c in cols:
                if c in seen:
                    other = ("the time column" if seen[c] is None
                             else f"a column of sensors[{seen[c]}]")
                    raise SceneError(f"sensors[{k}].name: got {sn.name!r}, whose column "
                                     f"{c!r} is also {other}; expected names whose table "
                                     f"columns are unique")
                seen[c] = k

    def _check_reach(self):
        """The tool point and the wall must be within reach of the arm (a tool 5 m off a
        1 m arm, or a wall 1 km away, is a typo, and the tool's lever arm collapses the
        integration step)."""
        reach = sum(lk.reach for lk in self.links)
        tool = math.hypot(*self.tool.position)
        if tool > reach:
            raise SceneError(f"tool.position: got {list(self.tool.position)} m "
                             f"({tool:.6g} m from the last tip frame), expected at most the "
                             f"arm's reach {reach:.6g} m (sum of hub radii, beam lengths and "
                             f"joint offsets)")
        for k, w in enumerate(self.walls):
            # the base's distance on the free side (a base inside the wall: the tool starts
            # inside it, which the contact model reports with the start gap)
            d = -(w.normal[0] * w.point[0] + w.normal[1] * w.point[1]) / math.hypot(*w.normal)
            if d > 2.0 * (reach + tool):
                raise SceneError(f"walls[{k}].point: got {list(w.point)} m, a wall line "
                                 f"{d:.6g} m from the base, expected at most twice the reach "
                                 f"of arm and tool ({2.0 * (reach + tool):.6g} m): a wall "
                                 f"the tool can never touch")

    def with_fidelity(self, **overrides) -> "Scene":
        """A copy with fidelity fields replaced (None values are ignored), validated.

        A scene's ``dt`` and (with rung auto) ``refine`` and ``integrator`` go with the
        model the scene names: another rung, refinement or modal basis, a tolerance, or
        rung auto step at their own (automatic or chosen) step unless ``dt`` is given too.
        """
        changes = {k: v for k, v in overrides.items() if v is not None}
        if not changes:
            return self
        data = dataclasses.asdict(self.fidelity)
        if changes.get("rung") == "auto":
            # the scene's refinement belonged to its own rung; auto chooses the step and
            # the integrator (rk4, or rkn4 where it steps further)
            changes.setdefault("refine", 0)
            changes.setdefault("dt", 0.0)
            changes.setdefault("integrator", "rk4")
        model = ("rung", "refine", "modal_basis")
        if any(changes.get(k, data[k]) != data[k] for k in ("rung", "refine")):
            # the quadrature and the modes kept were measured for the scene's rod
            changes.setdefault("rod_points", 0)
            changes.setdefault("rod_modes", 0)
        if (changes.get("tolerance") and "integrator" not in changes
                and data["integrator"] == "lawson4"):
            # lawson4 (the seed 001 scenes') steps at the output period with no step
            # chosen for an error; a tolerance asked of such a scene steps RK4 at the step
            # chosen for it (an explicit --integrator lawson4 with it is refused)
            changes["integrator"] = "rk4"
        if any(changes.get(k, data[k]) != data[k] for k in model) or changes.get("tolerance"):
            # a scene's fixed step was chosen for the model it names (two_link_free: 7.5 ms
            # for modal 3, above that model's automatic step): another model, or a
            # tolerance, chooses its own step unless one is given with it
            changes.setdefault("dt", 0.0)
        data.update(changes)
        fid = from_mapping(Fidelity, data, "fidelity")
        return dataclasses.replace(self, fidelity=fid)


def housed_drive(scene, link: int, body: str):
    """The 0-based joint whose drive's housing the body carries — the next joint's for a
    tip body (the gearbox stands on it and turns the next link), none for a hub (it turns
    with its own joint's output) or the last tip — or None when that joint has no drive
    and no input."""
    if body != "tip" or link + 1 >= len(scene.links):
        return None
    j = link + 1
    has_input = any(inp.joint == j + 1 and inp.motion is None for inp in scene.inputs)
    return j if (scene.links[j].joint.drive is not None or has_input) else None


def program_fields(prog: Program, where: str) -> str:
    """The fields that set a program's range, as ``key = value`` text."""
    keys = {"constant": ("value",), "step": ("offset", "amplitude"), "pulse": ("amplitude",),
            "square": ("offset", "amplitude")}.get(prog.type, ("values",))
    return ", ".join(f"{where}.{k} = "
                     + str(list(prog.values) if k == "values" else getattr(prog, k))
                     for k in keys)


def program_range(prog: Program) -> tuple[float, float]:
    """(min, max) a torque/voltage/current program can take."""
    kind = prog.type
    if kind == "constant":
        vals = [prog.value]
    elif kind == "step":
        vals = [prog.offset, prog.offset + prog.amplitude]
    elif kind == "pulse":
        vals = [0.0, prog.amplitude]
    elif kind == "square":
        vals = [0.0, prog.offset + prog.amplitude, prog.offset - prog.amplitude]
    else:
        vals = list(prog.values) + ([0.0] if kind == "piecewise_constant" else [])
    return min(vals), max(vals)










