"""What the fit determines: standard errors, 95 % intervals, correlations and the
parameter combinations the data cannot fix (in words).

From the weighted residuals r (m) and their Jacobian J (m × n) in box coordinates z at
the solution (:mod:`flexarm_ros.calibration.parameters`), with the singular value
decomposition J = U S Vᵀ (Seber & Wild, *Nonlinear Regression*, 1989, Sec. 2.1 and 3.4;
Bates & Watts 1988, Sec. 2.3):

* the noise variance of a residual is 1 when it is in units of a stated σ (a feature with
  its σ, a channel with its noise given), else its channel's own level s_c² =
  Σr_c²/(m_c − n m_c/m) (the time-series convention of ``scipy.optimize.curve_fit``, per
  channel: channels scaled by their spread carry very different noise shares);
* the covariance of z is the sandwich (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹ = V S⁻¹ (Uᵀ Σ U) S⁻¹ Vᵀ
  over the *determined* directions (s² V S⁻² Vᵀ when Σ = s² I), mapped to the
  parameters' units by the chain rule (dp/dz); the standard errors are its diagonal's
  roots and the 95 % intervals z ± q se(z) mapped back (asymmetric in p on a log scale),
  q the Student-t 97.5 % quantile with m − n degrees of freedom (normal when absolute);
* a direction v_i of Vᵀ is **not determined** when the 95 % interval along it
  (± q s / S_i for Σ = s² I) is wider than the box itself (its width is 1 in every direction), or S_i
  is zero to round-off: moving the parameters along v_i by the whole box changes the fit
  by less than the noise. Every parameter with a share |v_ij| ≥ 0.1 in such a direction is
  reported as not identifiable (no standard error or interval: any value along the
  direction fits as well), and the direction is named in words — for two parameters on a
  log scale the product or ratio (p_a · p_b^c) the data do fix.
"""

from __future__ import annotations

import math

import numpy as np

SHARE = 0.1           # a parameter belongs to an undetermined direction from this share on
ROUND_OFF = 1e-10     # S_i / S_max below this: zero


def _quantile(dof: int, absolute: bool) -> float:
    from scipy import stats
    if absolute or dof <= 0:
        return float(stats.norm.ppf(0.975))
    return float(stats.t.ppf(0.975, dof))


def _exponent(c: float) -> str:
    if abs(c - 1) < 0.05:
        return ""
    if abs(c - round(c)) < 0.05:
        return f"^{int(round(c))}"
    return f"^{c:.2f}"


def name_direction(params, v) -> dict:
    """Words for an undetermined direction ``v`` (unit vector in z)."""
    idx = [j for j in range(len(params)) if abs(v[j]) >= SHARE * np.max(np.abs(v))]
    keys = [params[j].name for j in idx]
    moves = []
    for j in idx:
        p = params[j]
        if p.log:
            moves.append(f"{p.name} ×{math.exp(0.1 * v[j] * math.log(p.high / p.low)):.3g}")
        else:
            moves.append(f"{p.name} {0.1 * v[j] * (p.high - p.low):+.3g}")
    if len(idx) == 1:
        text = (f"{keys[0]} has no effect on the record that the data can measure within "
                f"its bounds")
        fixed = None
    else:
        a, b = idx[0], idx[1]
        pa, pb = params[a], params[b]
        fixed = None
        if len(idx) == 2 and pa.log and pb.log:
            da = v[a] * math.log(pa.high / pa.low)
            db = v[b] * math.log(pb.high / pb.low)
            c = -da / db
            if c > 0:
                fixed = f"{pa.name} · {pb.name}{_exponent(c)}"
            else:
                fixed = f"{pa.name} / {pb.name}{_exponent(-c)}"
        elif len(idx) == 2 and not pa.log and not pb.log:
            da, db = v[a] * (pa.high - pa.low), v[b] * (pb.high - pb.low)
            c = -da / db
            fixed = f"{pa.name} {'+' if c > 0 else '-'} {abs(c):.3g} · {pb.name}"
        text = (f"{' and '.join(keys) if len(keys) == 2 else ', '.join(keys)} are not "
                f"separately identifiable"
                + (f": the data determine only {fixed}" if fixed else "")
                + f" (moving together as {', '.join(moves)} leaves the fit unchanged "
                  f"within the noise)")
    return {"keys": keys, "direction": {params[j].name: float(v[j]) for j in idx},
            "determined": fixed, "text": text}


def noise_variances(r, blocks, n: int) -> np.ndarray:
    """Per residual, the variance of its noise in its own (weighted) units: 1 for a block
    with a stated σ, else the block's own level Σr_c²/(m_c − n m_c/m) (each channel its
    own: channels scaled by their spread carry very different noise shares)."""
    m = len(r)
    var = np.ones(m)
    for a, b, given in blocks:
        if given or b <= a:
            continue
        dof = (b - a) * (1.0 - n / m) if m > n else 0.0
        var[a:b] = float(r[a:b] @ r[a:b]) / dof if dof > 0 else math.nan
    return var


def analyse(J, r, params, z, absolute: bool, blocks=None) -> dict:
    """Standard errors, intervals, correlation, singular values and undetermined
    directions at the solution (see the module doc). ``blocks``: (start, stop, σ given)
    per observable (default: one block, given when ``absolute``). The covariance is the
    sandwich (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹ = V S⁻¹ (Uᵀ Σ U) S⁻¹ Vᵀ with Σ the diagonal of
    :func:`noise_variances` (s² I for one block)."""
    J = np.asarray(J, float)
    r = np.asarray(r, float)
    m, n = J.shape
    dof = m - n
    if blocks is None:
        blocks = [(0, m, absolute)]
    var = noise_variances(r, blocks, n)
    s2 = 1.0 if absolute else float(np.mean(var))
    q = _quantile(dof, absolute)
    U, S, Vt = np.linalg.svd(J, full_matrices=False)
    smax = S[0] if S.size and S[0] > 0 else 1.0
    live = S > ROUND_OFF * smax
    Sinv = np.where(live, 1.0 / np.where(live, S, 1.0), 0.0)
    M = (U.T * var) @ U                                   # Uᵀ Σ U
    C = Sinv[:, None] * M * Sinv[None, :]                 # cov in the V basis
    with np.errstate(invalid="ignore"):
        half = np.where(live, q * np.sqrt(np.maximum(np.diag(C), 0.0)), math.inf)
    undetermined = [i for i in range(len(S)) if not half[i] <= 1.0]
    unident = set()
    for i in undetermined:
        for j in range(n):
            if abs(Vt[i, j]) >= SHARE * np.max(np.abs(Vt[i])):
                unident.add(j)
    keep = [i for i in range(len(S)) if i not in undetermined]
    cov_z = np.zeros((n, n))
    if keep:
        Vk = Vt[keep]
        cov_z = Vk.T @ C[np.ix_(keep, keep)] @ Vk
    p = np.array([prm.from_z(zz) for prm, zz in zip(params, z)], float)
    D = np.array([prm.dp_dz(pp) for prm, pp in zip(params, p)])
    cov_p = cov_z * np.outer(D, D)
    out = []
    for j, prm in enumerate(params):
        se_z = math.sqrt(max(cov_z[j, j], 0.0))
        ok = j not in unident
        lo_hi = None
        if ok:
            lo_hi = [float(prm.from_z(z[j] - q * se_z)), float(prm.from_z(z[j] + q * se_z))]
        at_bound = bool(z[j] <= 1e-6 or z[j] >= 1 - 1e-6)
        out.append({"key": prm.name, "keys": list(prm.keys), "value": float(p[j]),
                    "sets": prm.assignment(float(p[j])),
                    "start": prm.start, "low": prm.low, "high": prm.high,
                    "unit": prm.unit, "scale": "log" if prm.log else "linear",
                    "stderr": float(math.sqrt(max(cov_p[j, j], 0.0))) if ok else None,
                    "ci95": lo_hi, "identifiable": ok, "at_bound": at_bound})
    corr = np.full((n, n), math.nan)
    for a in range(n):
        for b in range(n):
            if a not in unident and b not in unident:
                d = math.sqrt(cov_z[a, a] * cov_z[b, b])
                corr[a, b] = cov_z[a, b] / d if d > 0 else (1.0 if a == b else 0.0)
    return {"parameters": out,
            "correlation": [[None if math.isnan(x) else float(x) for x in row]
                            for row in corr],
            "singular_values": [float(x) for x in S],
            "directions": [{params[j].name: float(Vt[i, j]) for j in range(n)}
                           for i in range(len(S))],
            "interval_along_direction": [float(h) for h in half],
            "unidentifiable": [name_direction(params, Vt[i]) for i in undetermined],
            "noise_variance": s2, "absolute_sigma": bool(absolute),
            "noise_variance_per_block": [float(var[a]) if b > a else None
                                         for a, b, _ in blocks],
            "degrees_of_freedom": int(dof), "quantile": q}
