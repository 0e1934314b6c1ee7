"""A Kalman filter on the twin's own model, fed the bench's measurements as the bench
delivers them (``flexarm estimate``).

The model is the scene linearized about its initial state
(:func:`flexarm_ros.model.statespace.linearize`: ẋ = A x + B u, y = C x + D u in deviations
from x₀, voltages or valve currents in), on the scene's own rung. Between two measurement
instants t_a < t_b the command u (held from the instant the controller sent it) is
constant, and the filter propagates exactly:

    x̂⁻(t_b) = Φ x̂(t_a) + Γ u,   Φ = e^{A Δ},  Γ = ∫₀^Δ e^{A s} ds B,   Δ = t_b − t_a,
    P⁻ = Φ P Φᵀ + Q_Δ,           Q_Δ ≈ ∫₀^Δ e^{A s} W e^{Aᵀ s} ds (Van Loan's method)

with the model's error as an unknown generalized acceleration d in the state (q̈ gains
d), which the accelerometers
see directly (their reading gains e·J d) and the encoders through the motion; d is a
random walk whose variance grows by (share·|B u_limit|)² every 1/:data:`DISTURBANCE_RATE`
s. Measured against a first-order Gauss–Markov d (ḋ = −d/τ + w, τ from 10 ms to 10 s,
share 0.1–1): link 2's RMSE 3.0–4.2 % and largest error 10.5–12.7 % of its peak, against
2.4 % and 9.7 % for the random walk — which leaves a direction the sensors do not observe
growing in P, so its gains never settle (:meth:`ModelFilter.update`). Without
accelerometers d is not observable: the filter then takes white noise of the same
density on the accelerations instead. Measured on two_link_case1 (1.5 s, the estimator's
tip mass 10 % above the rig's): the accelerometers' tip-deflection RMSE 4–5 % of the peak
without d, 1.4 % (link 1) and 2.4 % (link 2) with it. At each instant it corrects with what was
measured there — each accelerometer sample at its own time (a batch's samples are
1/fs apart, the last at the message's time), the encoder counts at the tick:

    S = H P⁻ Hᵀ + R,  K = P⁻ Hᵀ S⁻¹,  x̂ = x̂⁻ + K (z − H x̂⁻ − D_z u),  P = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ

(Joseph form). Measurement noise from the scene's sensor models: an encoder's counts
are floor(gain·δq), read as counts + ½ with variance 1/12; an accelerometer's
noise_std and ADC step (volts) over its sensitivity, variance σ² + lsb²/12 in (m/s²)²,
with :data:`ACCEL_NOISE_FLOOR` where the scene declares an ideal one. The normalized
innovation squared ν = Σ innovationᵀ S⁻¹ innovation over a tick's updates, divided by their
count of scalar measurements, has mean 1 while the rig behaves like the model; a window's
mean above the χ² quantile of :data:`FALSE_ALARM` flags a departure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError

#: the accelerometer noise the filter assumes where the scene declares none, m/s²
ACCEL_NOISE_FLOOR = 1e-3
#: process noise: the std of the unknown generalized acceleration of each coordinate, as a
#: share of the acceleration the full command gives it (|B u_limit|)
PROCESS_SHARE = 0.1
#: the window of the departure test (ticks) and its false-alarm probability per window
WINDOW_TICKS = 100
#: P settled: its largest change between two encoder ticks below this share of itself
SETTLED = 1e-9
#: the most measurement patterns whose gains are kept
MAX_PATTERNS = 256
#: the disturbance's random walk: its variance grows by (share·|B u_limit|)² per 1/this s
DISTURBANCE_RATE = 2 * math.pi * 20.0
FALSE_ALARM = 1e-6


@dataclass
class Measurement:
    """What arrived at one instant: ``kind`` "encoder" (counts, one per encoder in scene
    order) or "accelerometer" (values in the instrument's unit, one per accelerometer of
    that rate in scene order, ``names`` saying which)."""
    t_ns: int
    kind: str
    names: tuple
    values: np.ndarray


class ModelFilter:
    """The filter of the module doc for ``scene`` (its sensors, drives and rung)."""

    def __init__(self, scene, process_share: float = PROCESS_SHARE, disturbance: bool = True):
        from flexarm_ros.model.chain import Chain
        from flexarm_ros.model.limits import joint_limits
        from flexarm_ros.model.statespace import linearize
        if not (math.isfinite(process_share) and process_share > 0):
            raise InputError(f"--process-noise: got {process_share!r}, expected a finite "
                             f"share > 0 of the full command's acceleration")
        self.scene = scene
        self.chain = Chain(scene)
        ss = linearize(self.chain)
        self.ss = ss
        self.n = ss.A.shape[0]
        self.nf = len(self.chain.free)
        specs = {s.name: s for s in scene.sensors}
        self.rows = {name: ss.outputs.index(name) for name in specs}
        self.specs = specs
        lim = np.array([jl.command_limit for jl in joint_limits(scene)], float)
        lim = lim[:ss.B.shape[1]] if len(lim) >= ss.B.shape[1] else np.ones(ss.B.shape[1])
        acc = np.sqrt(((ss.B[self.nf:2 * self.nf] * lim) ** 2).sum(axis=1))
        floor = 1e-6 * max(float(np.max(acc)), 1e-12)
        # the augmented state [x, d]: d the unknown generalized acceleration (a random
        # walk), which the accelerometers see directly and the encoders through x
        nf, n = self.nf, self.n
        self.N = n + nf
        self.A = np.zeros((self.N, self.N))
        self.A[:n, :n] = ss.A
        self.A[nf + np.arange(nf), n + np.arange(nf)] = 1.0
        self.B = np.vstack([ss.B, np.zeros((nf, ss.B.shape[1]))])
        self.W = np.zeros((self.N, self.N))
        sd = process_share * np.maximum(acc, floor)
        if disturbance:                 # a random walk (module doc)
            self.W[n + np.arange(nf), n + np.arange(nf)] = sd ** 2 * DISTURBANCE_RATE
        else:                           # white acceleration noise; d stays zero
            self.W[nf + np.arange(nf), nf + np.arange(nf)] = sd ** 2
            self.A[nf + np.arange(nf), n + np.arange(nf)] = 0.0
        self.H = {}
        for name in specs:
            row = np.zeros(self.N)
            row[:n] = ss.C[self.rows[name]]
            if specs[name].kind == "accelerometer":
                row[n:] = self._accel_jacobian(name)
            self.H[name] = row
        self._disc: dict = {}
        self.x = np.zeros(self.N)
        self.P = np.diag(np.concatenate([np.full(nf, 1e-8), np.full(nf, 1e-6),
                                         np.full(n - 2 * nf, 1e-6),
                                         sd ** 2 if disturbance else np.zeros(nf)]))
        self.u = np.zeros(ss.B.shape[1])
        self.t_ns = None
        self.frozen, self.gains, self._dts, self._prev, self._p_tick = False, {}, [], None, None
        self._models: dict = {}

    def _accel_jacobian(self, name) -> np.ndarray:
        """e·J of the accelerometer ``name`` at the operating point, free coordinates: what a
        generalized acceleration adds to its reading (m/s² per unit)."""
        from flexarm_ros.model.sensors import build_sensors
        from flexarm_ros.model.statics import initial_state
        sm = next(s for s in build_sensors(self.chain) if s.name == name)
        q0 = np.asarray(initial_state(self.chain)[0], float)
        _, J, _, psi = self.chain.point_kinematics(q0, np.zeros(self.chain.n), sm.link,
                                                   sm.spec.body, sm.spec.position,
                                                   basis=sm.basis)
        cs, sn = math.cos(psi), math.sin(psi)
        e = np.array([cs * sm.axis[0] - sn * sm.axis[1], sn * sm.axis[0] + cs * sm.axis[1]])
        return (e @ J)[list(self.chain.free)]

    def _discrete(self, dt_ns: int):
        """(Φ, Γ, Q_Δ) for an interval of ``dt_ns`` (Van Loan; kept per interval)."""
        got = self._disc.get(dt_ns)
        if got is None:
            from scipy.linalg import expm
            from flexarm_ros.model.statespace import zoh
            n = self.N
            d = dt_ns * 1e-9
            Phi, Gam = zoh(self.A, self.B, d)
            V = np.zeros((2 * n, 2 * n))
            V[:n, :n], V[:n, n:], V[n:, n:] = -self.A, self.W, self.A.T
            G = expm(V * d)
            Q = Phi @ G[:n, n:]
            got = (Phi, Gam, 0.5 * (Q + Q.T))
            if len(self._disc) < 64:
                self._disc[dt_ns] = got
        return got

    def command(self, u) -> None:
        """The command from now on (V per joint; A for a valve)."""
        self.u = np.asarray(u, float)

    def predict_to(self, t_ns: int) -> None:
        """x̂⁻, P⁻ at ``t_ns`` (P only while its gains are still settling, see
        :meth:`update`)."""
        if self.t_ns is None:
            self.t_ns = t_ns
            return
        dt = int(t_ns - self.t_ns)
        if dt <= 0:
            return
        Phi, Gam, Q = self._discrete(dt)
        self.x = Phi @ self.x + Gam @ self.u
        if not self.frozen:
            self.P = Phi @ self.P @ Phi.T + Q
        self._dts.append(dt)
        self.t_ns = t_ns

    def _rows(self, m: Measurement):
        """(H, D_z, z, R) of ``m``: the rows, noise and instrument scaling of its sensors
        (module doc) are the same for every measurement of those sensors, kept per set."""
        model = self._models.get(m.names)
        if model is None:
            H = np.array([self.H[nm] for nm in m.names])
            Dz = np.array([self.ss.D[self.rows[nm]] for nm in m.names])
            if m.kind == "encoder":
                scale, offset = np.ones(len(m.names)), 0.5
                R = np.full(len(m.names), 1.0 / 12.0)
            else:
                scale, offset, R = [], 0.0, []
                for nm in m.names:
                    sp = self.specs[nm]
                    s = sp.sensitivity or 1.0
                    var = sp.noise_std ** 2
                    if sp.adc_range is not None and sp.adc_bits is not None:
                        lsb = (sp.adc_range[1] - sp.adc_range[0]) / (2 ** sp.adc_bits - 1)
                        var += lsb ** 2 / 12.0
                    scale.append(s)
                    R.append(max(var / s ** 2, ACCEL_NOISE_FLOOR ** 2))
                scale, R = np.array(scale), np.array(R)
            model = self._models[m.names] = (H, Dz, scale, offset, np.diag(R))
        H, Dz, scale, offset, R = model
        return H, Dz, np.asarray(m.values, float) / scale + offset, R

    def update(self, m: Measurement) -> tuple[float, int]:
        """Correct with ``m`` (after :meth:`predict_to` its time): (NIS, its dof).

        The gains depend only on the pattern of intervals and measurements, which repeats
        every tick on a bench; once P at an encoder tick changes by less than
        :data:`SETTLED` of itself, the gains of each pattern met are reused and P is no
        longer propagated (the time-varying filter's own gains, to round-off); a pattern
        not met before (a lost sample, a gap) resumes the full update."""
        H, Dz, z, R = self._rows(m)
        key = (self._prev, m.names, tuple(self._dts))
        self._dts, self._prev = [], m.names
        e = z - H @ self.x - Dz @ self.u
        got = self.gains.get(key) if self.frozen else None
        if got is None and self.frozen:            # a new pattern: P from where it was
            self.frozen = False
            for dt in key[2]:
                Phi, _, Q = self._discrete(dt)
                self.P = Phi @ self.P @ Phi.T + Q
        if got is not None:
            K, Si, self.P = got
            self.x = self.x + K @ e
            return float(e @ Si @ e), len(e)
        S = H @ self.P @ H.T + R
        Si = np.linalg.inv(S)
        K = self.P @ H.T @ Si
        self.x = self.x + K @ e
        IKH = np.eye(self.N) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        if len(self.gains) > MAX_PATTERNS:
            self.gains.clear()
        self.gains[key] = (K, Si, self.P)
        if m.kind == "encoder":
            last = self._p_tick
            self._p_tick = self.P
            if last is not None and np.max(np.abs(self.P - last)) <= SETTLED * np.max(
                    np.abs(self.P)):
                self.frozen = True
        return float(e @ Si @ e), len(e)

    def full_q(self) -> np.ndarray:
        """The estimated generalized coordinates (x₀ + x̂, full vector)."""
        q, _ = self.chain.full_state(0.0, self.ss.x0 + self.x[:self.n])
        return q

    def departure_threshold(self, dof: int) -> float:
        """The window mean of ν (per dof) above which a departure is flagged."""
        from scipy.stats import chi2
        k = max(1, dof * WINDOW_TICKS)
        return float(chi2.ppf(1.0 - FALSE_ALARM, k) / k)
