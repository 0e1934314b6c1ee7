"""Models with known sensitivity answers, run through the ensemble runner in place of a
simulation (the same designs, tasks, table and analyses), to check the sensitivity
machinery before it is trusted on the arm.

Ishigami function (Ishigami & Homma 1990), inputs independent uniform on [−π, π]:

    y = sin x1 + a sin² x2 + b x3⁴ sin x1

with variance D = a²/8 + b π⁴/5 + b² π⁸/18 + 1/2 and partial variances
D1 = (1 + b π⁴/5)²/2, D2 = a²/8, D3 = 0, D13 = b² π⁸ (1/18 − 1/50) (Sobol' & Levitan
1999; Saltelli et al. 2008, Sec. 4.9): S1 = (D1, D2, 0)/D, ST = (D1 + D13, D2, D13)/D.

Linear model y = Σ cᵢ xᵢ, xᵢ uniform on [loᵢ, hiᵢ]: every elementary effect on the unit
cube of quantiles is cᵢ (hiᵢ − loᵢ), so Morris μ* = |cᵢ| (hiᵢ − loᵢ), σ = 0; Sobol
Sᵢ = STᵢ = cᵢ² (hiᵢ − loᵢ)² / Σⱼ cⱼ² (hiⱼ − loⱼ)².
"""

from __future__ import annotations

import math


class Ishigami:
    """The task ``{"x1", "x2", "x3"} → {"y"}`` (picklable, for any executor)."""

    columns = ["y"]

    def __init__(self, a: float = 7.0, b: float = 0.1):
        self.a, self.b = a, b

    def __call__(self, assignment: dict) -> dict:
        x1, x2, x3 = (float(assignment[k]) for k in ("x1", "x2", "x3"))
        y = math.sin(x1) + self.a * math.sin(x2) ** 2 + self.b * x3 ** 4 * math.sin(x1)
        return {"status": "ok", "message": "", "metrics": {"y": y}}

    def indices(self) -> dict:
        """Analytic S1 and ST (module doc)."""
        a, b, pi = self.a, self.b, math.pi
        d = a ** 2 / 8 + b * pi ** 4 / 5 + b ** 2 * pi ** 8 / 18 + 0.5
        d1 = 0.5 * (1 + b * pi ** 4 / 5) ** 2
        d2 = a ** 2 / 8
        d13 = b ** 2 * pi ** 8 * (1 / 18 - 1 / 50)
        return {"S1": [d1 / d, d2 / d, 0.0], "ST": [(d1 + d13) / d, d2 / d, d13 / d]}


class Linear:
    """The task ``{name: x} → {"y": Σ cᵢ xᵢ}``."""

    columns = ["y"]

    def __init__(self, coefficients: dict):
        self.c = dict(coefficients)

    def __call__(self, assignment: dict) -> dict:
        y = sum(c * float(assignment[k]) for k, c in self.c.items())
        return {"status": "ok", "message": "", "metrics": {"y": y}}
