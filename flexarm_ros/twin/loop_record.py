"""What a closed-loop batch run records besides the plant's states (both lanes of
:mod:`flexarm_ros.twin.batch` fill it): the loop's record per control tick, and the
output grid of the plant."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import SceneError


@dataclass
class LoopRecord:
    """What the bench computer and the driver did, one row per control tick k (t_k =
    k·T): the command taken (V, A above a valve's null bias, or N·m for a joint without a
    drive), the effort held over (t_k, t_k+1] (N·m, or the valve current), the armature
    current at t_k (A; 0 for a joint without a DC motor) and the controller's targets
    (joint angles, rad; the tool point, m) where it has them."""
    t: np.ndarray
    command: np.ndarray
    effort: np.ndarray
    current: np.ndarray
    joint_target: np.ndarray | None = None
    tip_target: np.ndarray | None = None
    rejected: int = 0
    held: int = 0
    status: str = "ok"



def output_every(plant) -> int:
    """Grid intervals per output period (the plant's grid holds the output period)."""
    dt = plant.chain.fidelity.output_dt
    every = dt * 1e9 / plant.grid_ns
    if abs(every - round(every)) > 1e-6:
        raise SceneError(f"fidelity.output_dt: got {dt:g} s, expected a multiple of the "
                         f"plant's grid {plant.grid_ns * 1e-9:g} s")
    return int(round(every))
