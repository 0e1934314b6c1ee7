"""Scene files: one YAML file describes a rig and an experiment (SI units).

A scene is loaded into frozen, typed objects (:class:`Scene` and its sections). Anything the
loader cannot place is an error naming the key path, the value and the expectation
(see :mod:`flexarm_ros.model.schema`). Components absent from a scene are absent from the
model built from it (no gravity → no gravity forces; no joint flexibility → no motor-side
coordinate).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import yaml

from .errors import SceneError
from .schema import from_mapping, param

RUNGS = ("rigid", "cubic", "modal", "fem", "fd")
INTEGRATORS = ("rk4", "trapezoid", "rk45", "dop853", "radau", "bdf", "lsoda")
TORQUE_PROGRAMS = ("constant", "pulse", "square", "piecewise_constant", "piecewise_linear")
MOTION_PROGRAMS = ("spin_up", "smooth_step", "hold")


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


@dataclass(frozen=True, kw_only=True)
class Beam:
    """A uniform Euler–Bernoulli beam clamped to its hub at ``hub_radius`` from the joint."""
    length: float = param(unit="m", gt=0.0, doc="beam length L")
    EI: float = param(unit="N·m²", gt=0.0, doc="bending stiffness E·I (in the plane)")
    mass_per_length: float = param(unit="kg/m", gt=0.0, doc="ρ·A")
    hub_radius: float = param(0.0, unit="m", ge=0.0, doc="distance joint axis → beam root")
    thickness: Optional[float] = param(None, unit="m", gt=0.0,
                                       doc="section depth in the bending plane (for strain)")
    damping: BeamDamping = param(default_factory=BeamDamping, doc="beam damping")


@dataclass(frozen=True, kw_only=True)
class JointFlexibility:
    """Joint flexibility: a motor-side angle coupled to the link by a spring and damper."""
    stiffness: float = param(unit="N·m/rad", gt=0.0, doc="joint spring k")
    damping: float = param(0.0, unit="N·m·s/rad", ge=0.0, doc="joint damper c")
    motor_inertia: float = param(unit="kg·m²", gt=0.0,
                                 doc="motor-side inertia (rotor reflected through the gear)")


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

    def validate(self, where):
        if self.initial_angle_deg is not None and self.initial_angle != 0.0:
            raise SceneError(f"{where}.initial_angle_deg: got {self.initial_angle_deg}, "
                             f"expected only one of initial_angle / initial_angle_deg")

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


@dataclass(frozen=True, kw_only=True)
class Program:
    """A time program u(t) for a joint torque (N·m) or a prescribed joint motion (rad).

    Torque types: constant {value}; pulse {amplitude, start, width}; square {amplitude,
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
    """Drives one joint (1-based index) by a torque program or a prescribed motion."""
    joint: int = param(unit="", ge=1, doc="joint number, 1-based")
    torque: Optional[Program] = param(None, doc="joint torque program (N·m)")
    motion: Optional[Program] = param(None, doc="prescribed joint motion (rad)")

    def validate(self, where):
        if (self.torque is None) == (self.motion is None):
            raise SceneError(f"{where}: got {'both' if self.torque else 'neither'} of "
                             f"torque/motion, expected exactly one")
        if self.torque is not None and self.torque.type not in TORQUE_PROGRAMS:
            raise SceneError(f"{where}.torque.type: got {self.torque.type!r}, expected one of "
                             f"{', '.join(TORQUE_PROGRAMS)}")
        if self.motion is not None and self.motion.type not in MOTION_PROGRAMS:
            raise SceneError(f"{where}.motion.type: got {self.motion.type!r}, expected one of "
                             f"{', '.join(MOTION_PROGRAMS)}")


@dataclass(frozen=True, kw_only=True)
class Fidelity:
    """Model and integrator choice: the rung of the ladder and how finely it is refined."""
    rung: str = param("cubic", choices=RUNGS, doc="beam discretization")
    refine: int = param(0, ge=0, doc="modes / elements / FD segments (0 → rung default)")
    modal_basis: str = param("tip_loaded", choices=("tip_loaded", "clamped_free"),
                             doc="modal rung: modes of the beam with or without its tip body")
    foreshortening: bool = param(True, doc="keep the quadratic foreshortening "
                                           "(geometric stiffening) terms")
    integrator: str = param("rk4", choices=INTEGRATORS, doc="time integrator")
    dt: float = param(0.0, unit="s", ge=0.0, doc="fixed step (rk4) or max step (0 → auto)")
    rtol: float = param(1e-8, gt=0.0, lt=1.0, doc="relative tolerance (adaptive)")
    atol: float = param(1e-10, gt=0.0, doc="absolute tolerance (adaptive)")
    output_dt: float = param(1e-3, unit="s", gt=0.0, doc="sample period of the output")
    max_deflection_ratio: float = param(0.5, gt=0.0, doc="stop when |w_tip|/L exceeds this "
                                        "(small-deflection model no longer valid)")


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
    inputs: tuple[Input, ...] = param((), doc="joint torque / motion programs")
    fidelity: Fidelity = param(default_factory=Fidelity, doc="model and integrator")
    initial: Initial = param(default_factory=Initial, doc="initial condition")
    duration: float = param(1.0, unit="s", gt=0.0, doc="default simulated duration")
    assumptions: tuple[Assumption, ...] = param((), doc="values not given in the source")

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
            if inp.motion is not None and self.links[inp.joint - 1].joint.flexibility:
                raise SceneError(f"inputs[{k}].motion: got a prescribed motion on flexible "
                                 f"joint {inp.joint}, expected a torque program")

    def with_fidelity(self, **overrides) -> "Scene":
        """A copy with fidelity fields replaced (None values are ignored), validated."""
        changes = {k: v for k, v in overrides.items() if v is not None}
        if not changes:
            return self
        data = dataclasses.asdict(self.fidelity)
        data.update(changes)
        fid = from_mapping(Fidelity, data, "fidelity")
        return dataclasses.replace(self, fidelity=fid)


def load_scene_dict(data) -> Scene:
    """Validate a parsed mapping into a :class:`Scene`."""
    return from_mapping(Scene, data, "")


def load_scene(path) -> Scene:
    """Load and validate a scene YAML file (a path, or a name of a shipped scene)."""
    p = resolve_scene_path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f"{p}: not valid YAML: {exc}") from None
    try:
        return load_scene_dict(data)
    except SceneError as exc:
        raise SceneError(f"{p.name}: {exc}") from None


def config_dir() -> Path:
    """The shipped ``config/`` folder (source tree, or ``share/flexarm_ros/config``)."""
    import os
    import sys
    here = Path(__file__).resolve()
    share = Path("share") / "flexarm_ros" / "config"
    candidates = [here.parents[2] / "config",              # source tree / editable install
                  Path(sys.prefix) / share]                 # pip install (data_files)
    # colcon / ament: <prefix>/share/flexarm_ros/config, prefixes from AMENT_PREFIX_PATH,
    # and the install prefix above lib/pythonX.Y/site-packages/flexarm_ros/model/
    candidates += [Path(p) / share for p in os.environ.get("AMENT_PREFIX_PATH", "").split(
        os.pathsep) if p]
    if len(here.parents) > 5:
        candidates.append(here.parents[5] / share)
    for c in candidates:
        if c.is_dir():
            return c
    raise SceneError("cannot find the shipped config/ folder (looked in "
                     + ", ".join(str(c) for c in candidates) + ")")


def resolve_scene_path(path) -> Path:
    """A scene path as given, or the shipped scene of that name (``link`` → config/link.yaml)."""
    p = Path(path)
    if p.is_file():
        return p
    for cand in (config_dir() / p.name, config_dir() / f"{p.name}.yaml"):
        if cand.is_file():
            return cand
    raise SceneError(f"scene: got {str(path)!r}, expected an existing YAML file or the name of "
                     f"a shipped scene ({', '.join(shipped_scenes())})")


def shipped_scenes() -> list[str]:
    return sorted(p.stem for p in config_dir().glob("*.yaml"))
