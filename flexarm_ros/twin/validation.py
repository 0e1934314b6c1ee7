"""What a command must be to enter the twin: one check, used where commands enter (the
motor driver's ``motor_driver/commands``, the simulator's ``effort_controller/commands``)
and by the recorder, which thereby knows exactly what the nodes rejected.

A command is a sequence of one number per joint (joint order), each finite and within the
joint's wire limit (:mod:`flexarm_ros.model.limits`). Anything else is rejected with a
reason and changes nothing: no clipping, no partial use.
"""

from __future__ import annotations

import math
from collections import Counter

from flexarm_ros.model.limits import joint_limits

#: rejection reasons (also the keys of :attr:`Validator.counts`)
NOT_NUMBERS = "not numbers"
LENGTH = "wrong length"
NON_FINITE = "non-finite"
BEYOND = "beyond the limit"
FOREIGN = "second publisher"
ANOTHER_RUN = "another run"
NOT_CDR = "not a CDR message of its type"


class Validator:
    """Checks the commands of one topic against the scene's limits and counts rejections
    (by reason).

    ``kind``: ``"command"`` (motor_driver/commands: V, A or N·m by joint) or ``"effort"``
    (effort_controller/commands: N·m, or for a hydraulic joint the servovalve current in A,
    whose actuator the plant integrates: :mod:`flexarm_ros.sim.plant`)."""

    def __init__(self, scene, kind: str):
        if kind not in ("command", "effort"):
            raise ValueError(f"kind: got {kind!r}, expected 'command' or 'effort'")
        self.kind = kind
        lims = joint_limits(scene)
        self.n = len(lims)
        if kind == "command":
            self.limits = [lim.command_limit for lim in lims]
            self.units = [lim.command_unit for lim in lims]
        else:           # a servovalve's current passes the driver to the plant's actuator
            valve = [lim.command_unit == "A" for lim in lims]
            self.limits = [lim.command_limit if v else lim.torque_limit
                           for lim, v in zip(lims, valve)]
            self.units = ["A" if v else "N·m" for v in valve]
        self.counts: Counter = Counter()

    @property
    def rejected(self) -> int:
        return sum(self.counts.values())

    def reason(self, data) -> str | None:
        """None when ``data`` is an acceptable command, else why not (not counted)."""
        try:
            values = [float(v) for v in data]
        except (TypeError, ValueError):
            return NOT_NUMBERS
        if len(values) != self.n:
            return LENGTH
        for v, lim in zip(values, self.limits):
            if not math.isfinite(v):
                return NON_FINITE
            if abs(v) > lim:
                return BEYOND
        return None

    def check(self, data) -> str | None:
        """:meth:`reason`, counting a rejection."""
        why = self.reason(data)
        if why is not None:
            self.counts[why] += 1
        return why

    def refuse(self, why: str) -> None:
        """Count a rejection decided elsewhere (a message from a second publisher)."""
        self.counts[why] += 1

    def expectation(self) -> str:
        """What an acceptable command is, for log lines."""
        lims = ", ".join(f"±{lim:.4g} {u}" for lim, u in zip(self.limits, self.units))
        return f"{self.n} finite values within {lims}"

    def summary(self) -> str:
        """``N rejected (a wrong length, b non-finite, …)`` or ``none rejected``."""
        if not self.counts:
            return "none rejected"
        parts = ", ".join(f"{n} {why}" for why, n in sorted(self.counts.items()))
        return f"{self.rejected} rejected ({parts})"
