"""Measures of one simulated run (a ``SimResult``: its ``columns``, ``contact``, ``run``
and ``chain``) shared by the studies (:mod:`flexarm_ros.studies`) and the ensemble's
metrics (:mod:`flexarm_ros.ensemble.metrics`): the first touch of a wall and the energy
drift of a conservative scene."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np


def first_touch(res) -> float:
    """The located impact (impulse rung), or, for the compliant rung, the touch time
    extrapolated from the last sample before penetration with the tool's normal speed
    (t = t_k + g_k / (−ġ_k); interpolating to the first penetrating sample would be biased
    late, that sample's gap being held back by the contact)."""
    gap = res.columns["gap"]
    t = res.columns["t"]
    if res.contact is not None and res.contact.impacts:
        return float(res.contact.impacts[0].time)
    idx = np.nonzero(gap <= 0.0)[0]
    if not len(idx):
        return math.nan
    k = idx[0]
    if k == 0:
        return float(t[0])
    n = np.asarray(res.chain.scene.walls[0].normal, float)
    n = n / np.linalg.norm(n)
    gdot = n[0] * res.columns["tool_vx"][k - 1] + n[1] * res.columns["tool_vy"][k - 1]
    if gdot >= 0.0:
        return float(t[k])
    return float(t[k - 1] + min(gap[k - 1] / -gdot, t[k] - t[k - 1]))


def conservative(chain) -> bool:
    """No inputs of any kind and no damping anywhere: total energy must be conserved."""
    return not chain.scene.inputs and not np.any(chain.D)


def energy_drift(res) -> Optional[float]:
    """``max_t |E − E(0)| / max_t T`` for a conservative scene, else None (see
    :mod:`flexarm_ros.studies.ladder`)."""
    chain = res.chain
    if not conservative(chain):
        return None
    E = np.asarray(res.columns["energy"], float)
    q, qd = res.run.q, res.run.qd
    T = np.array([0.5 * qd[k] @ chain.kinematics(q[k], qd[k]).M @ qd[k]
                  for k in range(len(q))])
    change = float(np.max(np.abs(E - E[0])))
    scale = float(np.max(T))
    if scale <= 0.0:
        return 0.0 if change == 0.0 else float("inf")
    return change / scale
