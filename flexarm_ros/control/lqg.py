"""LQG position control designed on the model: state feedback on a discrete Kalman
estimate built only from the joint angles the bench's encoders give
(``flexarm design --lqg``, ``control.lqg``).

The plant is the scene linearized at rest at the move's target pose q*
(:func:`flexarm_ros.model.statespace.linearize`, voltages in; a quasi-static DC motor on
every joint, the same plant the shaper design uses, :mod:`flexarm_ros.control.design`),
sampled with a zero-order hold at the control period T_s:

    A_d = e^{A T_s},   B_d = ∫₀^{T_s} e^{A s} ds B      (the exact ZOH, one matrix exponential
                                                          of [[A, B], [0, 0]] T_s)

in deviations δx = x − x* from the target at rest. The bench measures the encoder
coordinate of each joint, y = C δx + v (C selects them; v the encoder's quantization,
variance Δ²/12 for a quantum Δ = 1/gain rad, or :data:`ANGLE_NOISE_FLOOR` where a joint has
no encoder). The gains come from python-control, not from code of ours:

* the regulator: K = ``control.dlqr(A_d, B_d, Q, R)``, Q = Σ_j e_jᵀe_j/θ² (every joint's
  encoder coordinate) + Σ_k c_kᵀc_k/δ² (every link's hub-frame tip deflection row) +
  Σ_j ė_jᵀė_j/ω² (the joint rates), R = I/V² — Bryson's rule with the largest acceptable
  angle error θ, tip deflection δ, joint rate ω and voltage V (``--weights``);
* the estimator: the prior covariance P of ``control.dlqe(A_d, I, C, W, V_n)`` (process
  noise W on every state, :data:`PROCESS_NOISE` of each state's scale), and the *current*
  estimator gain M = P Cᵀ (C P Cᵀ + V_n)⁻¹ (Franklin, Powell & Workman, Digital Control
  of Dynamic Systems, 3rd ed., §8.2.2; python-control's predictor gain is L = A_d M).

Each control period k, with the encoder angles y_k:

    x̂⁻_k = A_d x̂_{k−1} + B_d u_{k−1}        (x̂⁻_0 = the start pose at rest, δ from q*)
    x̂_k  = x̂⁻_k + M (y_k − y* − C x̂⁻_k)
    u_k  = clip(−K x̂_k, ±V_limit)            (the clipped voltage is what the prediction uses)

The voltage weight V is, unless given, the largest for which the regulator's first
command on the move, |K δx̂_0|, stays within the joint PD's first command on each joint
(found by bisection on log V): the LQG moves at no higher peak voltage than the PD it
replaces, measured by ``bench/bench_vibration.py``. A scene with gravity in its plane is
refused: about a loaded pose the law needs the holding voltage and the static deflection
as its set point, which this design does not compute.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from flexarm_ros.errors import InputError

#: the encoder-less joint's angle noise in the estimator's design, rad (the model's angle
#: is exact there; a floor keeps the Riccati equation well posed)
ANGLE_NOISE_FLOOR = 1e-6
#: process noise standard deviation of each state per period, as a fraction of its scale
#: (the angle weight θ for the coordinates, the rate weight ω for the rates)
PROCESS_NOISE = 1e-3
#: the weights a design takes (``--weights key=value,...``), with their units
WEIGHT_KEYS = {"angle": "rad", "deflection": "m", "rate": "rad/s", "voltage": "V"}
#: the bisection on log V: iterations and the bracket around the PD's first command
_BISECT_STEPS = 40


@dataclasses.dataclass
class LqgDesign:
    """The matrices the controller runs and what they were designed with."""
    A: np.ndarray              # A_d (n, n)
    B: np.ndarray              # B_d (n, m)
    C: np.ndarray              # measured rows (m, n)
    K: np.ndarray              # regulator gain (m, n)
    M: np.ndarray              # current-estimator gain (n, m)
    x_start: np.ndarray        # δx̂_0: the start pose at rest relative to the target
    y_goal: np.ndarray         # the encoder coordinates at the target (rad)
    weights: dict              # angle, deflection, rate, voltage actually used
    states: list
    W: np.ndarray              # the estimator's process noise covariance (n, n)
    V: np.ndarray              # its measurement noise covariance (joints, joints), rad²
    poles_regulator: np.ndarray
    poles_estimator: np.ndarray
    continuous: object         # the continuous StateSpace it was sampled from


def parse_weights(text: str | None) -> dict:
    """``--weights angle=0.01,deflection=1e-3,voltage=2``: a mapping of the keys in
    :data:`WEIGHT_KEYS` to positive finite numbers; InputError naming the key otherwise."""
    out: dict = {}
    if not text:
        return out
    for part in str(text).split(","):
        if "=" not in part:
            raise InputError(f"--weights: got {part!r}, expected key=value with a key of "
                             f"{', '.join(WEIGHT_KEYS)}")
        key, _, val = (s.strip() for s in part.partition("="))
        if key not in WEIGHT_KEYS:
            raise InputError(f"--weights: got key {key!r}, expected one of "
                             f"{', '.join(WEIGHT_KEYS)}")
        try:
            v = float(val)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"--weights: got {key}={val!r}, expected a finite number > 0 "
                             f"({WEIGHT_KEYS[key]}, the largest acceptable {key})")
        out[key] = v
    return out


def _measured(scene, chain):
    """(state indices of the encoder coordinates, their noise std, rad): per joint, the
    coordinate the controller reads (an encoder's own, else the link-side joint angle)."""
    from flexarm_ros.model.sensors import build_sensors
    enc = {sm.link: sm for sm in build_sensors(chain) if sm.spec.kind == "encoder"}
    free = list(chain.free)
    idx, std = [], []
    for k, lm in enumerate(chain.links):
        if k in enc:
            coord, quantum = enc[k].coord, 1.0 / enc[k].gain
            s = quantum / math.sqrt(12.0)
        else:
            coord, s = lm.i_joint, ANGLE_NOISE_FLOOR
        if coord not in free:
            raise InputError(f"links[{k}].joint: an LQG design needs every joint free "
                             f"(driven), got a prescribed one")
        idx.append(free.index(coord))
        std.append(s)
    return idx, np.array(std)


def _regulator(Ad, Bd, Cw, w):
    import control
    n = Ad.shape[0]
    Q = Cw["angle"].T @ Cw["angle"] / w["angle"] ** 2 \
        + Cw["deflection"].T @ Cw["deflection"] / w["deflection"] ** 2 \
        + Cw["rate"].T @ Cw["rate"] / w["rate"] ** 2
    Q = 0.5 * (Q + Q.T) + 1e-12 * np.trace(Q) / n * np.eye(n)
    R = np.eye(Bd.shape[1]) / w["voltage"] ** 2
    K, _, _ = control.dlqr(Ad, Bd, Q, R)
    return np.asarray(K)


def design_lqg(scene, q_goal, q_start, weights: dict | None = None,
               pd_first_voltage=None) -> LqgDesign:
    """The LQG of the module doc for the move of ``scene`` from ``q_start`` to ``q_goal``
    (joint angles, rad). ``weights``: any of :data:`WEIGHT_KEYS` (the rest chosen here);
    ``pd_first_voltage``: the PD's first command per joint (V), the bound on the
    regulator's when ``voltage`` is not given."""
    import control
    from flexarm_ros.control.design import plant_at, require_position
    from flexarm_ros.model.statespace import zoh
    require_position(scene)
    if any(abs(g) > 0.0 for g in scene.gravity):
        raise InputError(f"gravity: got {list(scene.gravity)} m/s², expected [0, 0] for an "
                         f"LQG design (about a loaded pose the law needs the holding voltage "
                         f"and static deflection as its set point; shape the PD's move with "
                         f"--shaper instead)")
    chain, ss = plant_at(scene, q_goal)
    rate = scene.control.rate_hz
    Ts = 1.0 / rate
    nf = len(chain.free)
    n, m = ss.A.shape[0], ss.B.shape[1]
    if m != len(scene.links):
        raise InputError(f"links: an LQG design needs a drive on every joint, got {m} "
                         f"inputs for {len(scene.links)} joints")
    idx, noise = _measured(scene, chain)
    Ad, Bd = zoh(ss.A, ss.B, Ts)
    C = np.zeros((len(idx), n))
    C[np.arange(len(idx)), idx] = 1.0
    Crate = np.zeros_like(C)
    Crate[np.arange(len(idx)), [nf + i for i in idx]] = 1.0
    rows = [ss.outputs.index(f"{lk.name}_tip_deflection") for lk in scene.links]
    Cw = {"angle": C, "rate": Crate, "deflection": ss.C[rows]}
    move = np.abs(np.asarray(q_goal, float) - np.asarray(q_start, float))
    w = dict(weights or {})
    w.setdefault("angle", max(float(np.max(move)) * 0.02, 1e-3))
    w.setdefault("deflection", 1e-3)
    w.setdefault("rate", 10.0)
    x0 = np.zeros(n)
    x0[idx] = np.asarray(q_start, float) - np.asarray(q_goal, float)
    if "voltage" not in w:
        if pd_first_voltage is None:
            raise InputError("--weights: got no voltage, expected voltage=V (or the PD's "
                             "first command to match)")
        cap = np.maximum(np.abs(np.asarray(pd_first_voltage, float)), 1e-6)
        lo, hi = math.log(1e-4 * float(np.max(cap))), math.log(1e3 * float(np.max(cap)))
        best = None
        for _ in range(_BISECT_STEPS):
            mid = 0.5 * (lo + hi)
            K = _regulator(Ad, Bd, Cw, dict(w, voltage=math.exp(mid)))
            if np.all(np.abs(K @ x0) <= cap * (1 + 1e-9)):
                best, lo = (math.exp(mid), K), mid
            else:
                hi = mid
        if best is None:
            raise InputError(f"--weights: no voltage weight keeps the first command within "
                             f"the PD's {cap.tolist()} V, expected a move the LQG can start "
                             f"as gently (give voltage=V)")
        w["voltage"], K = best
    else:
        K = _regulator(Ad, Bd, Cw, w)
    # the estimator: process noise on every state at its scale, encoder noise on y
    scale = np.ones(n)
    scale[:nf] = w["angle"]
    scale[nf:] = w["rate"]
    W = np.diag((PROCESS_NOISE * scale) ** 2)
    Vn = np.diag(noise ** 2)
    try:
        _, P, _ = control.dlqe(Ad, np.eye(n), C, W, Vn)
    except Exception as exc:  # noqa: BLE001 — python-control's own refusal, said as ours
        raise InputError(f"control.lqg: the Kalman design failed ({exc}), expected an arm "
                         f"whose bending the encoders observe") from None
    P = np.asarray(P)
    M = P @ C.T @ np.linalg.inv(C @ P @ C.T + Vn)
    pr = np.linalg.eigvals(Ad - Bd @ K)
    pe = np.linalg.eigvals(Ad - Ad @ M @ C)
    for what, poles in (("regulator", pr), ("estimator", pe)):
        if np.max(np.abs(poles)) >= 1.0:
            raise InputError(f"control.lqg: the {what}'s largest pole has |z| = "
                             f"{np.max(np.abs(poles)):.6g}, expected < 1 (a stable design); "
                             f"change --weights")
    q_goal = np.asarray(q_goal, float)
    return LqgDesign(Ad, Bd, C, K, M, x0, q_goal.copy(), w, list(ss.states), W, Vn, pr, pe,
                     ss)


def lqg_record(scene, q_goal, q_start, weights=None, pd_first_voltage=None,
               version: str = "") -> tuple[dict, LqgDesign]:
    """(the ``control.lqg`` mapping, the design): the matrices the controller runs and the
    ``design`` line recording what they were designed on."""
    d = design_lqg(scene, q_goal, q_start, weights, pd_first_voltage)
    pose = ", ".join(f"{q:.6g}" for q in q_goal)
    wtxt = ", ".join(f"{k} {d.weights[k]:.4g} {WEIGHT_KEYS[k]}" for k in WEIGHT_KEYS)
    slow = float(np.max(np.abs(d.poles_regulator)))
    design = (f"LQG on the plant linearized at the target joint angles [{pose}] rad "
              f"({len(d.states)} states, ZOH at {scene.control.rate_hz:g} Hz): "
              f"control.dlqr with Bryson weights {wtxt}; control.dlqe on the encoder "
              f"angles, current-estimator form; slowest regulator pole |z| {slow:.6f}; "
              f"flexarm design {version}")
    rows = lambda a: [[float(v) for v in r] for r in np.atleast_2d(a)]  # noqa: E731
    return {"design": design, "weights": {k: float(d.weights[k]) for k in WEIGHT_KEYS},
            "states": list(d.states), "A": rows(d.A), "B": rows(d.B), "C": rows(d.C),
            "K": rows(d.K), "M": rows(d.M), "x_start": [float(v) for v in d.x_start],
            "y_goal": [float(v) for v in d.y_goal]}, d


def lqg_for_core(scene, ctl, weights_text, version):
    """(the ``control.lqg`` mapping, the LqgDesign) for ``scene`` whose controller core is
    ``ctl``: the move from its start to its target, the PD's first command as the bound on
    the LQG's unless ``--weights`` gives the voltage (``flexarm design`` and ``fx.design``)."""
    if weights_text is not None and not isinstance(weights_text, str):
        weights_text = ",".join(f"{k}={v}" for k, v in dict(weights_text).items())
    weights = parse_weights(weights_text)
    n = len(ctl.q_start)
    first = ctl.pd.motor.voltage(ctl.pd.torque(ctl.q_start, np.zeros(n), ctl.q_goal),
                                 np.zeros(n))
    return lqg_record(scene, ctl.q_goal, ctl.q_start, weights, first, version)


class LqgLaw:
    """The law of the module doc on the matrices of a ``control.lqg`` section, with the
    joint voltage limits ``limit`` (V). ``update(y)`` → the voltages for this period."""

    def __init__(self, lqg, limit):
        self.A, self.B = np.array(lqg.A), np.array(lqg.B)
        self.C, self.K, self.M = np.array(lqg.C), np.array(lqg.K), np.array(lqg.M)
        self.y_goal = np.array(lqg.y_goal)
        self.limit = np.asarray(limit, float)
        self.x = np.array(lqg.x_start, float)
        self.u = np.zeros(self.B.shape[1])
        self.first = True

    def update(self, y) -> np.ndarray:
        """One period: predict, correct with the encoder angles ``y`` (rad), regulate."""
        if not self.first:
            self.x = self.A @ self.x + self.B @ self.u
        self.first = False
        e = np.asarray(y, float) - self.y_goal - self.C @ self.x
        self.x = self.x + self.M @ e
        self.u = np.clip(-self.K @ self.x, -self.limit, self.limit)
        return self.u.copy()
