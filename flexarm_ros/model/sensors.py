"""Sensors read from the model, exactly (docs/physics.md §9; seed 000 Sec. 5 test bed,
seed 002 Sec. 4 instrumentation).

Every value comes from the state and the accelerations q̈ solved at that instant — never
from finite differences of sampled positions:

* accelerometer: specific force f = r̈ − g projected on the sensing axis ê of the body frame
  at the sensor (on a beam the frame turns with the local slope φ′(x)ᵀη), with
  r̈ = J q̈ + c from :meth:`Chain.point_kinematics`. At rest in gravity it reads −g·ê (an
  accelerometer pointing up reads +9.81 m/s²). Volts = sensitivity × f (seed 000: PCB 352B68
  100 mV/g, 309A 5 mV/g).
* strain: ε = (t/2)·w″(x) at the gauge, t the beam thickness (seed 002 mid-length gauges).
* encoder: counts = ⌊n·(θ − θ₀)·lines·quadrature/2π⌋ of the drive coordinate θ (gearbox
  output side), n the gear ratio when the encoder is on the motor shaft (seed 000: HEDS
  5540/5500, 500 lines, ×4 decoding, base ratio 156, middle 236). Integer.
* potentiometer: the link-side joint angle (rad; volts via sensitivity).
* tip_position: (x, y) of the last beam tip (m).

The measured value adds Gaussian noise (std in output units, a generator seeded by the
sensor's ``seed``) and an ADC (clip to the range, quantize to ``adc_bits``); the true SI
value is kept beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.errors import SceneError

#: sample times are integer multiples of this grid (ns) so every rate falls on it
TIME_QUANTUM_NS = 1


@dataclass
class SensorModel:
    """One declared sensor bound to a chain."""
    spec: object              # scene.Sensor
    link: int                 # 0-based link (accelerometer / strain) or joint index
    coord: int                # coordinate read by encoder / potentiometer
    gain: float               # encoder: counts per rad of the coordinate
    axis: np.ndarray          # accelerometer unit axis in its frame
    curvature: np.ndarray     # strain: (t/2)·φ″(x) row
    basis: tuple = None       # accelerometer on a beam: (φ(x), φ′(x), S(x))

    @property
    def name(self) -> str:
        return self.spec.name

    def columns(self) -> list[str]:
        """Output column names: measured value(s), then the true SI value(s)."""
        if self.spec.kind == "tip_position":
            return [f"{self.name}_x", f"{self.name}_y"]
        return [self.name, f"{self.name}_true"]


def build_sensors(chain, scene=None) -> list[SensorModel]:
    """SensorModels for the scene's sensors (validated against the built chain); ``scene``
    (default the chain's) supplies the drives' gear ratios when the chain was built
    without its drives (the co-simulation plant)."""
    scene = scene or chain.scene
    names = [lm.name for lm in chain.links]
    out = []
    for sn in scene.sensors:
        link = names.index(sn.link) if sn.link else sn.joint - 1
        lm = chain.links[link]
        coord, gain = -1, 0.0
        axis = np.asarray(sn.axis, float)
        axis = axis / np.linalg.norm(axis) if np.any(axis) else axis
        curv = np.zeros(0)
        if sn.kind == "encoder":
            coord = lm.i_motor if lm.i_motor >= 0 else lm.i_joint
            drive = scene.links[link].joint.drive
            ratio = (drive.gear_ratio if drive is not None else None) if sn.on_motor_shaft \
                else 1.0
            if sn.on_motor_shaft and ratio is None:
                raise SceneError(f"sensors: encoder {sn.name!r} on_motor_shaft needs a "
                                 f"dc_motor drive with gear_ratio on joint {sn.joint}")
            gain = ratio * sn.lines_per_rev * sn.quadrature / (2.0 * math.pi)
        elif sn.kind == "potentiometer":
            coord = lm.i_joint
        elif sn.kind == "strain":
            curv = 0.5 * lm.link.beam.thickness * lm.beam.curvature([sn.position[0]])[0]
        basis = (lm.beam.point(sn.position[0])
                 if sn.kind == "accelerometer" and sn.body == "beam" else None)
        out.append(SensorModel(sn, link, coord, gain, axis, curv, basis))
    return out


def true_value(sm: SensorModel, chain, q, qd, qdd, q_initial, kin=None):
    """The noise-free SI value (tuple of 2 for tip_position) at one instant (``kin``: the
    chain's frames at (q, q̇), shared by the sensors read at that instant)."""
    sn = sm.spec
    if sn.kind == "encoder":
        return float(np.floor(sm.gain * (q[sm.coord] - q_initial[sm.coord]) + 1e-9))
    if sn.kind == "potentiometer":
        return float(q[sm.coord])
    if sn.kind == "strain":
        return float(sm.curvature @ q[chain.links[sm.link].eta])
    if sn.kind == "tip_position":
        return tuple(chain.tip_position(q))
    r, J, c, psi = chain.point_kinematics(q, qd, sm.link, sn.body, sn.position, kin,
                                          sm.basis)
    f = J @ qdd + c - chain.gravity
    cs, sn_ = math.cos(psi), math.sin(psi)
    e = np.array([cs * sm.axis[0] - sn_ * sm.axis[1], sn_ * sm.axis[0] + cs * sm.axis[1]])
    return float(f @ e)


def measure(sm: SensorModel, values: np.ndarray, rng=None) -> np.ndarray:
    """Instrument output from true SI values: × sensitivity, + noise, ADC (clip, quantize).
    Encoder counts stay integers (noise and ADC do not apply). The noise is drawn from
    ``rng`` (default: a fresh generator seeded with the sensor's seed), one value per
    sample in time order, so sample-by-sample and whole-table readings agree."""
    sn = sm.spec
    v = np.asarray(values, float).copy()
    if sn.kind in ("encoder", "tip_position"):
        return v
    if sn.sensitivity is not None:
        v = v * sn.sensitivity
    if sn.noise_std > 0:
        rng = np.random.default_rng(sn.seed) if rng is None else rng
        v = v + rng.normal(0.0, sn.noise_std, v.shape)
    if sn.adc_range is not None:
        lo, hi = sn.adc_range
        v = np.clip(v, lo, hi)
        if sn.adc_bits is not None:
            lsb = (hi - lo) / (2 ** sn.adc_bits - 1)
            v = lo + np.round((v - lo) / lsb) * lsb
    return v


def sample_grid_ns(periods_s) -> int:
    """The common sample grid (ns): the gcd of all periods, each rounded to 1 ns."""
    g = 0
    for p in periods_s:
        g = math.gcd(g, int(round(p * 1e9)))
    return g


def output_period(scene) -> float:
    """A batch run's sample period: fidelity.output_dt, or the common grid of it and the
    declared sensors' periods (``flexarm simulate`` refuses a grid finer than 1 µs; here
    fidelity.output_dt stands in for it)."""
    fid = scene.fidelity
    if not scene.sensors:
        return fid.output_dt
    ns = sample_grid_ns([fid.output_dt] + [1.0 / s.rate_hz for s in scene.sensors])
    return ns * 1e-9 if ns >= 1000 else fid.output_dt


def sensor_tables(chain, run, sensors: list[SensorModel], q_initial, qdd_free=None,
                  acc_given=None) -> dict:
    """Per sample rate: a table {'t': …, column: …} of every sensor at that rate, from the
    run's samples (the run's grid must contain every sensor's sample times). ``qdd_free``
    (N, nf): q̈ of the free coordinates at the run's samples when the dynamics are not the
    chain's alone (contact); ``acc_given`` (N, n_acc): the accelerometers' readings at
    the run's samples, in the order of ``sensors``, when the integration took them."""
    acc_col = {}
    if acc_given is not None:
        acc_col = {sm.name: r for r, sm in enumerate(
            s for s in sensors if s.spec.kind == "accelerometer")}
    t_ns = np.round(run.t * 1e9).astype(np.int64)
    by_rate: dict = {}
    for sm in sensors:
        by_rate.setdefault(sm.spec.rate_hz, []).append(sm)
    tables = {}
    for rate, group in sorted(by_rate.items()):
        period_ns = int(round(1e9 / rate))
        # a period beyond the run (or int64): the start sample only
        idx = (np.zeros(1, dtype=int) if period_ns > t_ns[-1]
               else np.nonzero(t_ns % period_ns == 0)[0])
        table = {"t": run.t[idx]}
        acc = [sm for sm in group if sm.spec.kind == "accelerometer"]
        acc_vals = {}
        if acc and acc_given is not None:
            acc_vals = {sm.name: acc_given[idx, acc_col[sm.name]] for sm in acc}
            acc = []
        if acc:
            # C order whatever the run's arrays are (a history transposed from the
            # kernel's is Fortran): the read-out kernel is compiled for one layout
            X = np.ascontiguousarray(np.concatenate(
                [run.q[idx][:, chain.free], run.qd[idx][:, chain.free], run.z[idx]],
                axis=1))
            QDD = (np.ascontiguousarray(qdd_free[idx]) if qdd_free is not None
                   else np.zeros((len(idx), len(chain.free))))
        if acc and chain.backend == "numba":     # read-out from the kernel's frames
            from flexarm_ros.model.compiled import sensors as ksensors
            _, *arrs = ksensors.pack(chain, acc)
            vals = np.empty((len(idx), len(acc)))
            ksensors.table(run.t[idx], X, QDD, qdd_free is not None, chain.kernel_args,
                           kchain.workspace(chain.kernel_args), *arrs, vals)
            acc_vals = {sm.name: vals[:, r] for r, sm in enumerate(acc)}
        elif acc:
            acc_vals = {sm.name: np.empty(len(idx)) for sm in acc}
            for j, k in enumerate(idx):
                qdd = chain.full_qdd(float(run.t[k]), X[j])
                if qdd_free is not None:
                    qdd[chain.free] = QDD[j]
                kin = chain.kinematics(run.q[k], run.qd[k], frames_only=True)
                for sm in acc:
                    acc_vals[sm.name][j] = true_value(sm, chain, run.q[k], run.qd[k], qdd,
                                                      q_initial, kin)
        tips = None
        if any(sm.spec.kind == "tip_position" for sm in group):
            # the tip frame of all samples in one pass (compiled without gravity), equal
            # to Chain.tip_position per sample (the output columns' tip_x/tip_y)
            _, tips = chain.energies(run.t[idx], run.q[idx], run.qd[idx], run.z[idx])
        for sm in group:
            if sm.spec.kind == "accelerometer":
                vals = acc_vals[sm.name]
            elif sm.spec.kind == "tip_position":
                vals = tips
            elif sm.spec.kind == "encoder":   # true_value's floor, all samples at once
                vals = np.floor(sm.gain * (run.q[idx, sm.coord] - q_initial[sm.coord])
                                + 1e-9)
            else:
                vals = [true_value(sm, chain, run.q[k], run.qd[k], None, q_initial)
                        for k in idx]
            if sm.spec.kind == "tip_position":
                arr = np.array(vals).reshape(-1, 2)
                table[f"{sm.name}_x"], table[f"{sm.name}_y"] = arr[:, 0], arr[:, 1]
                continue
            true = np.array(vals, float)
            table[sm.name] = measure(sm, true)
            table[f"{sm.name}_true"] = true
        tables[rate] = table
    return tables
