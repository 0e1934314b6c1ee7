"""Scenes: the typed, validated description of a rig and an experiment.

``schema`` is the generic machinery (frozen dataclasses whose fields carry type, unit,
bounds and description; one loader; the generated config reference), ``sections`` the scene's
sections (links, joints, drives, inputs, sensors, walls, fidelity, …) and ``loading`` reads
YAML files and finds the shipped scenes. Nothing here imports the rest of the project except
:mod:`flexarm_ros.errors`.
"""

from flexarm_ros.scene.loading import (DEFAULT_SCENE, config_dir, load_scene, load_scene_dict,
                                       resolve_scene_path, shipped_scenes)
from flexarm_ros.scene.sections import (DRIVE_TYPES, INPUT_KINDS, INTEGRATORS, MOTION_PROGRAMS,
                                        RUNG_CHOICES, RUNGS, SENSOR_KINDS, STANDARD_GRAVITY,
                                        TORQUE_PROGRAMS, Assumption, Backlash, Beam,
                                        BeamDamping, Bearing, Control, Drive, Fidelity,
                                        HighSpot, Initial, Input, Joint, JointFlexibility,
                                        Link, Program, RigidBody, Sanding, Scene, Sensor,
                                        TipBody, Tool, Wall, housed_drive, program_range)

__all__ = [
    "DEFAULT_SCENE", "config_dir", "load_scene", "load_scene_dict", "resolve_scene_path",
    "shipped_scenes", "DRIVE_TYPES", "INPUT_KINDS", "INTEGRATORS", "MOTION_PROGRAMS", "RUNGS",
    "RUNG_CHOICES", "SENSOR_KINDS", "STANDARD_GRAVITY", "TORQUE_PROGRAMS", "Assumption",
    "Backlash", "Beam", "BeamDamping", "Bearing", "Control", "Drive", "Fidelity", "HighSpot",
    "Initial", "Input", "Joint", "JointFlexibility", "Link", "Program", "RigidBody",
    "Sanding", "Scene", "Sensor", "TipBody", "Tool", "Wall", "housed_drive",
    "program_range",
]
