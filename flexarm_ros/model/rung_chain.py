"""General planar chain of joints, rigid bodies and flexible beams (Kane's method, numeric).

Coordinates q, per link in chain order: [motor angle (only with joint flexibility or
backlash)],
joint angle (link side, relative to the previous tip frame), the beam's elastic
coordinates η. A material point of beam j at abscissa x has local position
s = (r + x − ½ηᵀS(x)η, φ(x)ᵀη) in its hub frame and absolute position r = o + A(ψ)s.
The tip frame sits at the beam tip and turns with the tip slope φ′(L)ᵀη; the next joint
is at the tip frame's ``joint_offset``.

For every mass point the Jacobian J = ∂r/∂q (2×n) and the velocity-product acceleration
c (r̈ = J q̈ + c) are propagated down the chain (E = [[0, −1], [1, 0]]):

    ṙ = ȯ + ψ̇ E A s + A ṡ,    r̈ = ö + ψ̈ E A s − ψ̇² A s + 2ψ̇ E A ṡ + A s̈.

Equations of motion (docs/physics.md §4):

    M(q) q̈ = Q_input + Q_grav − h(q, q̇) − K q − D q̇,
    M = M_drive + Σ_p m_p J_pᵀJ_p + Σ_bodies (m J_cgᵀJ_cg + I J_ψᵀJ_ψ),
    h = Σ_p m_p J_pᵀ c_p,   Q_grav = Σ_p m_p J_pᵀ g.

Actuators (:mod:`drives`) add their torque to Q_input on the drive coordinate and may carry
first-order states z (armature currents, load pressures): the first-order state is
x = [q_free, q̇_free, z]. Backlash couplings add their dead-zone mesh torque.

Because every term comes from the same point kinematics, the model is a consistent
Lagrangian system: with no damping and no input its total energy is conserved to the
integrator's accuracy (the check that catches an inconsistent term).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import os

import numpy as np

from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled.layout import Model
from flexarm_ros.model import bearings, beams, drives
from flexarm_ros.errors import SceneError
from flexarm_ros.model.programs import encode, eval_motion, eval_torque

E2 = np.array([[0.0, -1.0], [1.0, 0.0]])


def _rot(psi):
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s], [s, c]])


@dataclass
class _LinkModel:
    name: str
    link: object
    beam: beams.BeamDiscretization
    i_joint: int
    i_motor: int          # -1 without joint flexibility / backlash
    eta: slice


@dataclass
class Actuator:
    """One driven joint: its program, drive model and (optional) first-order state."""
    link: int             # 0-based link index
    coord: int            # drive coordinate (motor angle if present, else joint angle)
    kind: int             # drives.IDEAL / DC_QUASI_STATIC / DC_CURRENT / HYDRAULIC
    par: np.ndarray       # drives parameter vector (mutable: the hydraulic null bias)
    program: object       # scene.Program of the input (u in N·m, V or A)
    enc: tuple            # programs.encode(program)
    state: int            # index in z, -1 without a state
    input_kind: str       # torque / voltage / current


@dataclass
class Frame:
    """A body frame: origin o, angle ψ, their Jacobians and velocity-product terms."""
    o: np.ndarray
    Jo: np.ndarray
    co: np.ndarray
    psi: float
    Jpsi: np.ndarray
    psid: float


@dataclass
class Kinematics:
    """Everything the chain computes at one (q, q̇): mass matrix, forces, frames, points."""
    M: np.ndarray
    h: np.ndarray
    Qg: np.ndarray
    hub_frames: list
    tip_frames: list
    points: list = field(default_factory=list)  # per link (r (P,2), J (P,2,n), c (P,2))


def _inertia_keys(scene, k0: int) -> str:
    """The masses, inertias and lengths of link ``k0`` and the links it carries (non-zero
    ones), as ``key = value`` text: what sets the inertia on its coordinates."""
    parts = []
    for k in range(k0, len(scene.links)):
        lk, w = scene.links[k], f"links[{k}]"
        vals = [("beam.length", lk.beam.length, "m"),
                ("beam.mass_per_length", lk.beam.mass_per_length, "kg/m"),
                ("beam.hub_radius", lk.beam.hub_radius, "m"),
                ("hub.mass", lk.hub.mass, "kg"), ("hub.inertia", lk.hub.inertia, "kg·m²"),
                ("hub.cg", list(lk.hub.cg), "m"), ("tip.mass", lk.tip.mass, "kg"),
                ("tip.inertia", lk.tip.inertia, "kg·m²"), ("tip.cg", list(lk.tip.cg), "m"),
                ("tip.joint_offset", list(lk.tip.joint_offset), "m"),
                ("joint.drive_inertia", lk.joint.drive_inertia, "kg·m²")]
        if lk.joint.flexibility is not None:
            vals.append(("joint.flexibility.motor_inertia",
                         lk.joint.flexibility.motor_inertia, "kg·m²"))
        parts += [f"{w}.{key} = {v if isinstance(v, list) else format(v, 'g')} {unit}"
                  for key, v, unit in vals if (any(v) if isinstance(v, list) else v)]
    return ", ".join(parts)


def check_backend(backend: str) -> str:
    """The backend a chain computes with: ``numba`` or ``numpy`` (``auto``: numba when
    installed); SceneError for any other."""
    if backend not in ("auto", "numpy", "numba"):
        raise SceneError(f"backend: got {backend!r}, expected auto, numpy or numba")
    if backend == "numba" and not kchain.HAVE_NUMBA:
        raise SceneError("backend: got 'numba', but numba is not installed "
                         "(pip install -e .[fast]) or FLEXARM_NO_NUMBA is set")
    return "numba" if backend == "auto" and kchain.HAVE_NUMBA else (
        "numpy" if backend == "auto" else backend)


class RungChain:
    """The planar flexible chain built from a scene at one named rung of the ladder. Rung
    auto is resolved by :class:`~flexarm_ros.model.chain.Chain`, the class to build a
    scene's model with; the automatic choice (:mod:`~flexarm_ros.model.autofidelity`)
    builds its candidates, named rungs, with this one."""

    def __init__(self, scene, fidelity=None, backend: str = "auto"):
        self.backend = check_backend(backend)
        self.auto = None            # autofidelity.AutoChoice when the scene said rung auto
        if (fidelity or scene.fidelity).rung == "auto":
            raise SceneError("fidelity.rung: got 'auto' for a RungChain, expected a named "
                             "rung (flexarm_ros.model.chain.Chain resolves auto)")
        self.scene = scene
        self.fidelity = fidelity or scene.fidelity
        beams.check_model_size(len(scene.links), self.fidelity)   # before a minutes-long build
        self.links: list[_LinkModel] = []
        names: list[str] = []
        units: list[str] = []                     # SI unit of each coordinate
        for k, lk in enumerate(scene.links):
            i_motor = -1
            if lk.joint.flexibility is not None or lk.joint.backlash is not None:
                i_motor = len(names)
                names.append(f"{lk.name}_motor")
                units.append("rad")
            i_joint = len(names)
            names.append(f"{lk.name}_joint")
            units.append("rad")
            basis = self.fidelity.modal_basis
            disc = beams.discretize(lk.beam, beams.modal_load(scene.links, k, basis),
                                    self.fidelity, beams.hub_load(scene.links, k, basis))
            start = len(names)
            names.extend(f"{lk.name}_{s}" for s in disc.coord_suffixes)
            units.extend(disc.coord_units)
            self.links.append(_LinkModel(lk.name, lk, disc, i_joint, i_motor,
                                         slice(start, len(names))))
        self.names = names
        self.units = units
        self.n = n = len(names)
        self.gravity = np.asarray(scene.gravity, float)
        self.has_gravity = bool(np.any(self.gravity != 0.0))
        self.foreshortening = self.fidelity.foreshortening
        # constant matrices: drive inertia, stiffness, damping
        self.M_drive = np.zeros((n, n))
        self.K = np.zeros((n, n))
        self.D = np.zeros((n, n))
        for lm in self.links:
            jt = lm.link.joint
            drive = lm.i_motor if lm.i_motor >= 0 else lm.i_joint
            self.M_drive[drive, drive] += jt.total_drive_inertia
            self.D[drive, drive] += jt.drive_damping
            if jt.flexibility is not None:
                fx = jt.flexibility
                self.M_drive[lm.i_motor, lm.i_motor] += fx.motor_inertia
                idx = np.array([lm.i_motor, lm.i_joint])
                blk = np.array([[1.0, -1.0], [-1.0, 1.0]])
                self.K[np.ix_(idx, idx)] += fx.stiffness * blk
                self.D[np.ix_(idx, idx)] += fx.damping * blk
            self.K[lm.eta, lm.eta] += lm.beam.K
            self.D[lm.eta, lm.eta] += lm.beam.D
        # backlash couplings: (motor index, joint index, half width, k, c)
        self.backlash = [(lm.i_motor, lm.i_joint, 0.5 * lm.link.joint.backlash.width,
                          lm.link.joint.backlash.stiffness, lm.link.joint.backlash.damping)
                         for lm in self.links if lm.link.joint.backlash is not None]
        # inputs: programs through the joint's drive act on the drive coordinate; motions
        # prescribe the joint angle
        from flexarm_ros.scene import Program
        by_joint = {inp.joint: inp for inp in scene.inputs}
        self.actuators: list[Actuator] = []
        self.prescribed = []          # (coordinate index, program, theta0)
        self.state_names: list[str] = []
        self.state_name_units: list[str] = []     # actuator states: current A, pressure Pa
        for k, lm in enumerate(self.links):
            jt = lm.link.joint
            inp = by_joint.get(k + 1)
            if inp is not None and inp.motion is not None:
                self.prescribed.append((lm.i_joint, inp.motion, jt.angle0))
                continue
            if inp is None and jt.drive is None:
                continue
            kind, par, has_state = drives.encode(jt.drive, self.fidelity.motor_current)
            prog = inp.program if inp is not None else Program(type="constant", value=0.0)
            state = -1
            if has_state:
                state = len(self.state_names)
                self.state_names.append(
                    f"{lm.name}_{'pressure' if kind == drives.HYDRAULIC else 'current'}")
                self.state_name_units.append("Pa" if kind == drives.HYDRAULIC else "A")
            drive = lm.i_motor if lm.i_motor >= 0 else lm.i_joint
            ikind = {None: "torque", "dc_motor": "voltage", "hydraulic": "current"}[
                jt.drive.type if jt.drive else None]
            self.actuators.append(Actuator(k, drive, kind, par, prog, encode(prog), state,
                                           ikind))
        self.nz = len(self.state_names)
        presc = [p[0] for p in self.prescribed]
        self.free = np.array([i for i in range(n) if i not in presc], dtype=int)
        self.presc_idx = np.array(presc, dtype=int)
        self._motion_enc = [encode(prog, th0) for _, prog, th0 in self.prescribed]
        # air bearings rubbing the table (model/bearings.py): link, body, loading actuator
        self.bearing_idx, self.bearing_par, self.bearing_spots = bearings.encode(
            scene, self.actuators)
        self.model = self._pack()                   # the compiled kernel's data, by name
        self.kernel_args = tuple(self.model)        # ... as its entry points take it
        self._ws = kchain.workspace(self.model)

    def _pack(self) -> Model:
        """The model as flat arrays for the compiled kernel (:mod:`compiled.chain`), by
        name (:class:`compiled.layout.Model`)."""
        nl = len(self.links)
        nemax = max(lm.beam.n for lm in self.links)
        pmax = max(len(lm.beam.x) for lm in self.links)
        ij = np.array([lm.i_joint for lm in self.links], dtype=np.int64)
        e0 = np.array([lm.eta.start for lm in self.links], dtype=np.int64)
        ne = np.array([lm.beam.n for lm in self.links], dtype=np.int64)
        npt = np.array([len(lm.beam.x) for lm in self.links], dtype=np.int64)
        bodies = np.zeros((nl, 2, 4))
        joff = np.zeros((nl, 2))
        rh = np.zeros(nl)
        X = np.zeros((nl, pmax + 1))
        MP = np.zeros((nl, pmax + 1))
        PHI = np.zeros((nl, pmax + 1, nemax))
        SS = np.zeros((nl, pmax + 1, nemax, nemax))
        SLOPE = np.zeros((nl, nemax))
        ROD = np.zeros(nl, dtype=np.bool_)
        RT = np.zeros((nl, pmax + 1, nemax))
        RC = np.zeros((nl, pmax + 1, nemax))
        RW = np.zeros((nl, pmax + 1, pmax))
        for k, lm in enumerate(self.links):
            b, lk = lm.beam, lm.link
            for j, body in enumerate((lk.hub, lk.tip)):
                bodies[k, j] = (body.mass, body.inertia, body.cg[0], body.cg[1])
            joff[k] = lk.tip.joint_offset
            rh[k] = b.hub_radius
            P = len(b.x)
            X[k, :P], X[k, P] = b.x, b.length
            MP[k, :P] = b.mass
            SLOPE[k, :b.n] = b.slope_tip
            if b.rod is not None:       # its own kinematics; φ, S zero (the guard skips it)
                ROD[k] = True
                RT[k, :P + 1, :b.n], RC[k, :P + 1, :b.n] = b.rod.T, b.rod.C
                RW[k, :P, :P], RW[k, P, :P] = b.rod.W[:P], b.rod.W[P]
                continue
            PHI[k, :P, :b.n], PHI[k, P, :b.n] = b.phi, b.phi_tip
            SS[k, :P, :b.n, :b.n], SS[k, P, :b.n, :b.n] = b.S, b.S_tip
        acts = self.actuators
        nt = len(acts)
        tl = max([len(a.enc[3]) for a in acts] + [1])
        tidx = np.array([a.coord for a in acts], dtype=np.int64)
        tcode = np.array([a.enc[0] for a in acts], dtype=np.int64)
        tpar = np.zeros((nt, 8))
        ttimes = np.zeros((nt, tl))
        tvalues = np.zeros((nt, tl))
        tlen = np.zeros(nt, dtype=np.int64)
        akind = np.array([a.kind for a in acts], dtype=np.int64)
        apar = np.zeros((nt, drives.N_PAR))
        azi = np.array([a.state for a in acts], dtype=np.int64)
        for j, a in enumerate(acts):
            apar[j] = a.par
            a.par = apar[j]           # one array: a later null-bias update reaches the kernel
        bidx = np.array([(b[0], b[1]) for b in self.backlash], dtype=np.int64).reshape(-1, 2)
        bpar = np.array([b[2:] for b in self.backlash], float).reshape(-1, 3)
        zlo = np.full(max(self.nz, 1), -np.inf)
        zhi = np.full(max(self.nz, 1), np.inf)
        for a in acts:
            if a.state >= 0:
                zlo[a.state], zhi[a.state] = drives.state_bounds(a.kind, a.par)
        self.z_bounds = (zlo[:self.nz], zhi[:self.nz])
        for j, (_, p, tt, vv) in enumerate(a.enc for a in acts):
            tpar[j] = p
            ttimes[j, :len(tt)] = tt
            tvalues[j, :len(vv)] = vv
            tlen[j] = len(tt)
        # per point: leading elastic coordinates that can be non-zero in φ(x_p), S(x_p)
        EXT = np.zeros((nl, pmax + 1), dtype=np.int64)
        for k, lm in enumerate(self.links):
            nz = (np.abs(PHI[k]) > 0) | np.any(np.abs(SS[k]) > 0, axis=1)
            for p in range(len(lm.beam.x)):
                idx = np.nonzero(nz[p])[0]
                EXT[k, p] = idx[-1] + 1 if len(idx) else 0
            EXT[k, len(lm.beam.x)] = lm.beam.n
        inv = np.array([lm.beam.rod is None and by_invariants(lm.beam.n, len(lm.beam.x),
                                                              self.foreshortening)
                        for lm in self.links], dtype=np.bool_)
        sums = _invariants([lm.beam for lm in self.links], inv, nemax, self.foreshortening)
        mcode = np.array([e[0] for e in self._motion_enc], dtype=np.int64)
        mpar = np.array([e[1] for e in self._motion_enc]).reshape(-1, 8)
        return Model(
            n=self.n, nl=nl, nz=self.nz, i_joint=ij, e0=e0, ne=ne, bodies=bodies,
            joint_offset=joff, hub_radius=rh, slope_tip=SLOPE, npt=npt, abscissa=X,
            point_mass=MP, phi=PHI, S=SS, ext=EXT, invariant=inv, inv_mass=sums[0],
            inv_phi=sums[1], inv_mat=sums[2], inv_G=sums[3], inv_H=sums[4], gravity=self.gravity,
            foreshortening=self.foreshortening, base_angle=float(self.scene.base_angle),
            M_drive=self.M_drive, K=self.K, D=self.D, free=self.free.astype(np.int64),
            presc=self.presc_idx.astype(np.int64), motion_code=mcode, motion_par=mpar,
            act_coord=tidx, prog_code=tcode, prog_par=tpar, prog_times=ttimes,
            prog_values=tvalues, prog_len=tlen, act_kind=akind, act_par=apar, act_state=azi,
            z_lo=zlo, z_hi=zhi, backlash_idx=bidx, backlash_par=bpar, rod=ROD, rod_T=RT,
            rod_C=RC, rod_W=RW, bearing_idx=self.bearing_idx, bearing_par=self.bearing_par,
            bearing_spots=self.bearing_spots)

    # ----------------------------------------------------------------------------- state
    def initial_q(self) -> tuple[np.ndarray, np.ndarray]:
        """Initial (q, q̇) from the scene: joint angles and rates, beams undeformed."""
        q = np.zeros(self.n)
        qd = np.zeros(self.n)
        for lm in self.links:
            jt = lm.link.joint
            q[lm.i_joint] = jt.angle0
            qd[lm.i_joint] = jt.initial_rate
            if lm.i_motor >= 0:
                q[lm.i_motor] = jt.angle0
                qd[lm.i_motor] = jt.initial_rate
        return q, qd

    def prescribed_state(self, t):
        """(q_p, q̇_p, q̈_p) of the prescribed coordinates at time t."""
        out = np.zeros((3, len(self._motion_enc)))
        for j, (code, p, _, _) in enumerate(self._motion_enc):
            out[:, j] = eval_motion(code, p, t)
        return out

    def prescribed_series(self, ts) -> np.ndarray:
        """:meth:`prescribed_state` at every time of ``ts``: (len(ts), 3, prescribed),
        the same floats (one compiled loop per prescribed coordinate)."""
        ts = np.ascontiguousarray(ts, dtype=float)
        out = np.empty((len(ts), 3, len(self._motion_enc)))
        col = np.empty((len(ts), 3))
        for j, (code, p, _, _) in enumerate(self._motion_enc):
            kchain.motion_series(code, np.asarray(p, dtype=float), ts, col)
            out[:, :, j] = col
        return out

    def actuator_inputs(self, t) -> np.ndarray:
        """Program values u(t) of the actuators (N·m, V or A)."""
        return np.array([eval_torque(a.enc[0], a.enc[1], a.enc[2], a.enc[3], t)
                         for a in self.actuators])

    def actuator_input_series(self, ts) -> np.ndarray:
        """:meth:`actuator_inputs` at every time of ``ts``: (len(ts), actuators), the same
        floats (one compiled loop per actuator: a Python call per sample was 8 % of a 1 s
        two_link_free's whole call)."""
        ts = np.ascontiguousarray(ts, dtype=float)
        u = np.empty((len(ts), len(self.actuators)))
        col = np.empty(len(ts))
        for j, a in enumerate(self.actuators):
            code, p, times, values = a.enc
            kchain.torque_series(code, p, times, values, ts, col)
            u[:, j] = col
        return u

    def input_forces(self, t, qd, z) -> tuple[np.ndarray, np.ndarray]:
        """Generalized actuator and backlash forces Q_input (n,) and the actuator state
        rates ż at (t, q̇, z); backlash needs q too, see :meth:`coupling_forces`."""
        Q = np.zeros(self.n)
        zd = np.zeros(self.nz)
        for a, u in zip(self.actuators, self.actuator_inputs(t)):
            zj = z[a.state] if a.state >= 0 else 0.0
            w = qd[a.coord]
            Q[a.coord] += drives.actuator_torque(a.kind, a.par, u, w, zj)
            if a.state >= 0:
                zd[a.state] = drives.actuator_rate(a.kind, a.par, u, w, zj)
        return Q, zd

    def actuator_torques(self, t, qd, z) -> np.ndarray:
        """Each actuator's torque on its drive coordinate (N·m) at (t, q̇, z)."""
        z = np.zeros(self.nz) if z is None else z
        return np.array([drives.actuator_torque(a.kind, a.par, u, qd[a.coord],
                                                z[a.state] if a.state >= 0 else 0.0)
                         for a, u in zip(self.actuators, self.actuator_inputs(t))])

    def bearing_forces(self, t, qd, z, kin) -> np.ndarray:
        """Generalized friction forces of the air bearings on the table (n,) at the frames
        ``kin`` (model/bearings.py; zero without bearings)."""
        if not len(self.bearing_idx):
            return np.zeros(self.n)
        return bearings.generalized_forces(self, kin, qd, self.actuator_torques(t, qd, z))

    def static_forces(self, q) -> np.ndarray:
        """Generalized forces at rest without inputs, Q_grav − h − K q + Q_coupling (n,):
        minus the torque each drive coordinate needs to hold configuration q."""
        zero = np.zeros(self.n)
        kin = self.kinematics(q, zero)
        return kin.Qg - kin.h - self.K @ q + self.coupling_forces(q, zero)

    def coupling_forces(self, q, qd) -> np.ndarray:
        """Backlash mesh torques as generalized forces (motor side −τ, link side +τ)."""
        Q = np.zeros(self.n)
        for im, ij, b, k, c in self.backlash:
            tau = drives.backlash_torque(b, k, c, q[im] - q[ij], qd[im] - qd[ij])
            Q[im] -= tau
            Q[ij] += tau
        return Q

    # ------------------------------------------------------------------------ kinematics
    def kinematics(self, q, qd, want_points=False, frames_only=False) -> Kinematics:
        """Mass matrix M(q), velocity terms h(q, q̇) and gravity forces at (q, q̇)
        (``frames_only``: only the hub/tip frames, M, h, Q_grav left empty)."""
        n = self.n
        M = self.M_drive.copy()
        h = np.zeros(n)
        Qg = np.zeros(n)
        g = self.gravity
        hubs, tips, pts = [], [], []
        base = self.scene.base_angle
        frame = Frame(np.zeros(2), np.zeros((2, n)), np.zeros(2), base, np.zeros(n), 0.0)
        for k, lm in enumerate(self.links):
            lk = lm.link
            # joint position on the previous tip frame
            if k > 0:
                frame = _offset_frame(frame, np.asarray(self.scene.links[k - 1].tip.joint_offset))
            # a flexible joint's motor inertia sits in M_drive on its relative coordinate
            Jpsi = frame.Jpsi.copy()
            Jpsi[lm.i_joint] += 1.0
            hub = Frame(frame.o, frame.Jo, frame.co, frame.psi + q[lm.i_joint], Jpsi,
                        frame.psid + qd[lm.i_joint])
            hubs.append(hub)
            if not frames_only:
                _add_body(M, h, Qg, hub, lk.hub, g)
            # beam points
            r, J, c, tip = self._beam(lm, hub, q, qd)
            m = lm.beam.mass
            if not frames_only:
                M += np.einsum("p,pin,pim->nm", m, J, J)
                h += np.einsum("p,pin,pi->n", m, J, c)
            if self.has_gravity and not frames_only:
                Qg += np.einsum("p,pin,i->n", m, J, g)
            if want_points:
                pts.append((r, J, c))
            tips.append(tip)
            if not frames_only:
                _add_body(M, h, Qg, tip, lk.tip, g)
            frame = tip
        return Kinematics(M, h, Qg, hubs, tips, pts)

    def _local(self, lm, eta, etad):
        """A beam's local kinematics in its hub frame at its mass points and tip (last row):
        s (P1, 2), ∂s/∂η (P1, 2, ne) and the velocity-product acceleration a (P1, 2),
        s̈ = (∂s/∂η)η̈ + a. The floating-frame rungs: s = (r + x − ½ηᵀSη, φᵀη),
        a = −(η̇ᵀSη̇) ê₁; the rod its exact kinematics (:mod:`flexarm_ros.model.rod`)."""
        b = lm.beam
        if b.rod is not None:
            return b.rod.local(eta, etad)
        phi = np.vstack([b.phi, b.phi_tip])
        x = np.append(b.x, b.length)
        P1 = len(x)
        a = np.zeros((P1, 2))
        if self.foreshortening:
            S = np.concatenate([b.S, b.S_tip[None]])
            Seta = S @ eta                          # (P1, ne)
            uf = -0.5 * Seta @ eta                  # (P1,)
            a[:, 0] = -np.einsum("pij,i,j->p", S, etad, etad)
        else:
            Seta = np.zeros((P1, b.n))
            uf = np.zeros(P1)
        s = np.empty((P1, 2))
        s[:, 0] = b.hub_radius + x + uf
        s[:, 1] = phi @ eta
        ds = np.empty((P1, 2, b.n))                 # ∂s/∂η
        ds[:, 0, :] = -Seta
        ds[:, 1, :] = phi
        return s, ds, a

    def _beam(self, lm, hub, q, qd):
        """Beam mass points (r, J, c) and the tip frame, from the hub frame."""
        b = lm.beam
        eta = q[lm.eta]
        etad = qd[lm.eta]
        A = _rot(hub.psi)
        s, ds, a = self._local(lm, eta, etad)
        P1 = len(s)
        sd = ds @ etad                              # (P1, 2)
        As = s @ A.T
        EAs = As @ E2.T
        J = np.broadcast_to(hub.Jo, (P1, 2, self.n)).copy()
        J += EAs[:, :, None] * hub.Jpsi[None, None, :]
        J[:, :, lm.eta] += np.einsum("ij,pjk->pik", A, ds)
        Asd = sd @ A.T
        c = (hub.co[None, :] - hub.psid**2 * As + 2.0 * hub.psid * (Asd @ E2.T)
             + a @ A.T)
        r = hub.o[None, :] + As
        Jpsi_t = hub.Jpsi.copy()
        Jpsi_t[lm.eta] += b.slope_tip
        tip = Frame(r[-1], J[-1], c[-1], hub.psi + b.slope_tip @ eta, Jpsi_t, Jpsi_t @ qd)
        return r[:-1], J[:-1], c[:-1], tip

    def point_kinematics(self, q, qd, link: int, body: str, position, kin=None,
                         basis=None) -> tuple:
        """(r, J, c, ψ) of a material point: position (2,), Jacobian ∂r/∂q (2, n),
        velocity-product acceleration c (r̈ = J q̈ + c) and the angle of the local frame.

        ``body`` hub / tip: ``position`` (x, y) in that body's frame; beam: abscissa
        x = position[0] from the beam root, the frame turning with the slope φ′(x)ᵀη.
        ``kin`` (frames at (q, q̇)) and ``basis`` (the beam's ``point(x)``) may be passed in
        when many points are read at one instant.
        """
        kin = kin or self.kinematics(q, qd, frames_only=True)
        lm = self.links[link]
        p = np.asarray(position, float)
        if body in ("hub", "tip"):
            fr = _offset_frame((kin.hub_frames if body == "hub" else kin.tip_frames)[link], p)
            return fr.o, fr.Jo, fr.co, fr.psi
        hub = kin.hub_frames[link]
        b = lm.beam
        eta, etad = q[lm.eta], qd[lm.eta]
        A = _rot(hub.psi)
        if b.rod is not None:                       # the rod's exact kinematics at x
            s_loc, ds, a_loc, theta = b.rod.local_at(p[0], eta, etad)
        else:
            phi, slope, S = basis if basis is not None else b.point(p[0])
            Seta = S @ eta if self.foreshortening else np.zeros(b.n)
            acc_ax = -etad @ S @ etad if self.foreshortening else 0.0
            s_loc = np.array([b.hub_radius + p[0] - 0.5 * Seta @ eta, phi @ eta])
            ds = np.vstack([-Seta, phi])            # ∂s/∂η (2, ne)
            a_loc = np.array([acc_ax, 0.0])
            theta = slope @ eta
        sd = ds @ etad
        As = A @ s_loc
        J = hub.Jo + np.outer(E2 @ As, hub.Jpsi)
        J[:, lm.eta] += A @ ds
        c = hub.co - hub.psid**2 * As + 2.0 * hub.psid * (E2 @ (A @ sd)) + A @ a_loc
        return hub.o + As, J, c, hub.psi + theta

    # -------------------------------------------------------------------------- dynamics
    def dynamics(self, t, q, qd, z=None) -> tuple[np.ndarray, np.ndarray]:
        """(q̈, ż) at (t, q, q̇, z): the equations of motion and the actuator states."""
        z = np.zeros(self.nz) if z is None else z
        kin = self.kinematics(q, qd)
        Qin, zd = self.input_forces(t, qd, z)
        f = (Qin + self.coupling_forces(q, qd) + kin.Qg - kin.h - self.K @ q
             - self.D @ qd)
        if len(self.bearing_idx):
            f = f + self.bearing_forces(t, qd, z, kin)
        qdd = np.zeros(self.n)
        fr = self.free
        if len(self.presc_idx):
            pdd = self.prescribed_state(t)[2]
            qdd[self.presc_idx] = pdd
            f = f - kin.M[:, self.presc_idx] @ pdd
        qdd[fr] = np.linalg.solve(kin.M[np.ix_(fr, fr)], f[fr])
        return qdd, zd

    def check_mass_matrix(self, q) -> None:
        """Raise SceneError when M(q) of the free coordinates is not positive definite
        (a coordinate without inertia), naming the coordinate and what to give it. The
        last q that passed is remembered: a run checks its initial state up to three
        times (statics, the integrator, the output), each a Python kinematics pass."""
        key = np.asarray(q, float).tobytes()
        if key == getattr(self, "_mass_ok", None):
            return
        M = self.kinematics(q, np.zeros(self.n)).M[np.ix_(self.free, self.free)]
        w, V = np.linalg.eigh(M)
        if w[0] > 1e-12 * max(w[-1], 1e-300):
            self._mass_ok = key
            return
        d = np.abs(np.diag(M))
        if d.min() > 0 and d.max() > 1e8 * d.min():
            # inertias orders of magnitude apart: what double precision cannot hold together
            # in one matrix (every coordinate has inertia)
            hi, lo = int(np.argmax(d)), int(np.argmin(d))
            k0 = min(self._link_of(self.free[hi]), self._link_of(self.free[lo]))
            raise SceneError(
                f"mass matrix: not positive definite to double precision (smallest "
                f"eigenvalue {w[0]:.3g}, largest {w[-1]:.3g}; the inertia on "
                f"{self.names[self.free[hi]]} is {d[hi] / d[lo]:.2g} times that on "
                f"{self.names[self.free[lo]]}); expected masses, inertias and lengths of "
                f"consistent scale: check {_inertia_keys(self.scene, k0)}")
        i = self.free[int(np.argmax(np.abs(V[:, 0])))]
        k = self._link_of(i)
        lm = self.links[k]
        if lm.eta.start <= i < lm.eta.stop:
            give = (f"the beam of links[{k}] has almost no mass, or it is lost to round-off "
                    f"beside what the beam carries: check {_inertia_keys(self.scene, k)}")
        elif i == lm.i_motor:
            give = (f"give links[{k}].joint.drive_inertia or its motor_inertia a value > 0")
        else:
            give = (f"give links[{k}].hub.inertia or links[{k}].joint.drive_inertia a value "
                    f"> 0, or use a flexible rung (the rigid rung's spring angle and the joint "
                    f"angle turn the same body)")
        raise SceneError(
            f"mass matrix: coordinate {self.names[i]} has no inertia (smallest eigenvalue "
            f"{w[0]:.3g} of M); expected a positive-definite mass matrix: {give}")

    def _link_of(self, i: int) -> int:
        """The link a coordinate belongs to."""
        return next(k for k, lm in enumerate(self.links)
                    if i in (lm.i_joint, lm.i_motor) or lm.eta.start <= i < lm.eta.stop)

    def full_state(self, t, x):
        """Assemble (q, q̇) from the first-order state x = [q_free, q̇_free, z] at time t."""
        nf = len(self.free)
        q = np.empty(self.n)
        qd = np.empty(self.n)
        q[self.free] = x[:nf]
        qd[self.free] = x[nf:2 * nf]
        if len(self.presc_idx):
            p = self.prescribed_state(t)
            q[self.presc_idx] = p[0]
            qd[self.presc_idx] = p[1]
        return q, qd

    def rhs(self, t, x):
        """First-order right-hand side ẋ = f(t, x), x = [q_free, q̇_free] (compiled kernel
        when the backend is numba, else the numpy reference below). ``x`` is copied to
        a contiguous array when it is a strided view (a column of a history): the kernel
        is compiled for contiguous ``x`` only, each other layout would be a second compile
        of the whole kernel (~25 s of CPU on a cold cache)."""
        if self.backend == "numba":
            return kchain.rhs(float(t), np.ascontiguousarray(x, float), self.kernel_args,
                              self._ws)
        return self.rhs_numpy(t, x)

    def rhs_numpy(self, t, x):
        """The numpy reference right-hand side."""
        q, qd = self.full_state(t, x)
        qdd, zd = self.dynamics(t, q, qd, x[2 * len(self.free):])
        return np.concatenate([qd[self.free], qdd[self.free], zd])

    def full_qdd(self, t, x) -> np.ndarray:
        """q̈ of all coordinates (n,) at state x: the free ones from the right-hand side
        (compiled when available), the prescribed ones from their programs."""
        nf = len(self.free)
        qdd = np.empty(self.n)
        qdd[self.free] = self.rhs(t, x)[nf:2 * nf]
        if len(self.presc_idx):
            qdd[self.presc_idx] = self.prescribed_state(t)[2]
        return qdd

    def clamp_states(self, x) -> np.ndarray:
        """x with its actuator states clamped into their bounds (in place; returned)."""
        if self.nz:
            nf2 = 2 * len(self.free)
            np.clip(x[nf2:], self.z_bounds[0], self.z_bounds[1], out=x[nf2:])
        return x

    def state_labels(self) -> list[str]:
        """Names of the first-order state x = [q_free, q̇_free, z]."""
        fr = [self.names[i] for i in self.free]
        return fr + [f"{nm}_rate" for nm in fr] + list(self.state_names)

    def state_units(self) -> list[str]:
        """SI units of :meth:`state_labels`, in the same order."""
        fr = [self.units[i] for i in self.free]
        return fr + [f"{u}/s" for u in fr] + list(self.state_name_units)

    # --------------------------------------------------------------------------- outputs
    def energy(self, q, qd) -> dict:
        """Kinetic, elastic (beams, joint springs, engaged backlash) and gravitational energy
        (J), their sum, and the tip position (m), from one kinematics pass. Energy stored in
        the actuators (½Li², oil compression) is not included."""
        kin = self.kinematics(q, qd, want_points=self.has_gravity)
        T = 0.5 * qd @ kin.M @ qd
        V = self._elastic_energy(q)
        Vg = -self._gravity_work(q, kin) if self.has_gravity else 0.0
        return {"kinetic": T, "elastic": V, "gravity": Vg, "total": T + V + Vg,
                "tip": kin.tip_frames[-1].o.copy()}

    def _elastic_energy(self, q) -> float:
        V = 0.5 * q @ self.K @ q
        for im, ij, b, k, _ in self.backlash:
            d = q[im] - q[ij]
            V += 0.5 * k * max(abs(d) - b, 0.0) ** 2
        return V

    def energies(self, t, q, qd, z) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`energy`'s ``total`` (J, (N,)) and ``tip`` (m, (N, 2)) at N samples (rows
        of q, q̇, z at the times t; q, q̇ full, prescribed coordinates included). With the
        numba backend and no gravity, one compiled pass over all samples
        (:func:`kchain.energies`: the kernel's mass matrix and tip frame, equal to the
        numpy reference to round-off, ~200× faster: the output columns of a 1 s run took
        ~0.4 s of its process); else :meth:`energy` per sample."""
        total, tip, _ = self.energies_and_frames(t, q, qd, z)
        return total, tip

    def energies_and_frames(self, t, q, qd, z):
        """:meth:`energies` and the last tip frame's angle ψ (rad, (N,)) at the samples."""
        n_s = len(q)
        total, tip, psi = np.empty(n_s), np.empty((n_s, 2)), np.empty(n_s)
        if self.backend != "numba" or self.has_gravity:
            for k in range(n_s):
                e = self.energy(q[k], qd[k])
                total[k], tip[k] = e["total"], e["tip"]
                psi[k] = self.kinematics(q[k], qd[k], frames_only=True).tip_frames[-1].psi
            return total, tip, psi
        kchain.energies(np.ascontiguousarray(q, float), np.ascontiguousarray(qd, float),
                        self.kernel_args, kchain.workspace(self.kernel_args), total, tip,
                        psi)
        return total, tip, psi

    def tool_points(self, t, q, qd, z) -> np.ndarray:
        """The tool point o + A(ψ)·tool.position of the last tip frame at the samples (m,
        (N, 2)): the point a tool-point target (control.tip_target) and a wall refer to."""
        _, tip, psi = self.energies_and_frames(t, q, qd, z)
        px, py = self.scene.tool.position
        c, s = np.cos(psi), np.sin(psi)
        return np.column_stack([tip[:, 0] + c * px - s * py, tip[:, 1] + s * px + c * py])

    def _gravity_work(self, q, kin):
        g = self.gravity
        W = 0.0
        for lm, (r, _, _), hub, tip in zip(self.links, kin.points, kin.hub_frames,
                                           kin.tip_frames):
            W += lm.beam.mass @ (r @ g)
            for fr, body in ((hub, lm.link.hub), (tip, lm.link.tip)):
                W += body.mass * (fr.o + _rot(fr.psi) @ np.asarray(body.cg)) @ g
        return W

    def tip_position(self, q) -> np.ndarray:
        """Position (x, y) of the last beam's tip (m)."""
        return self.kinematics(q, np.zeros(self.n), frames_only=True).tip_frames[-1].o.copy()

    def centerlines(self, q, samples: int = 21, kin=None) -> list[np.ndarray]:
        """Deformed beam centerlines in the world frame, one (samples, 2) array per link
        from the beam root to its tip: r(x) = o_hub + A(ψ)·[r_h + x − ½ηᵀS(x)η, φ(x)ᵀη]
        (the foreshortening term where the chain has it; a rod: its exact kinematics),
        the position of :meth:`point_kinematics` for all the points of a link at once,
        for views. ``kin``: the frames at ``q``, when at hand."""
        if samples < 2:
            raise ValueError(f"samples: got {samples}, expected at least 2")
        q = np.asarray(q, float)
        qd = np.zeros(self.n)
        kin = kin or self.kinematics(q, qd, frames_only=True)
        out = []
        for k, lm in enumerate(self.links):
            xs, basis = self._centerline_basis(k, samples)
            hub, eta = kin.hub_frames[k], q[lm.eta]
            if lm.beam.rod is not None:             # the rod's exact kinematics
                local = lm.beam.rod.positions_at(basis, eta)
            else:
                phi, S = basis
                axial = lm.beam.hub_radius + xs
                if self.foreshortening:
                    axial = axial - 0.5 * ((S @ eta) @ eta)
                local = np.stack([axial, phi @ eta], axis=1)     # (samples, 2)
            out.append(hub.o + local @ _rot(hub.psi).T)
        return out

    def _centerline_basis(self, link: int, samples: int) -> tuple:
        """(abscissae, (φ(x) stacked (samples, ne), S(x) stacked (samples, ne, ne)), a
        rod's :meth:`~flexarm_ros.model.rod.RodBasis.rows_at`) of :meth:`centerlines`: the
        beam's ``point(x)``, computed once per link and sample count (a live view draws
        the arm many times)."""
        cache = self.__dict__.setdefault("_centerline_bases", {})
        got = cache.get((link, samples))
        if got is None:
            b = self.links[link].beam
            xs = np.linspace(0.0, b.length, samples)
            if b.rod is not None:
                basis = b.rod.rows_at(xs)
            else:
                pts = [b.point(x) for x in xs]
                basis = (np.array([p[0] for p in pts], float).reshape(samples, -1),
                         np.array([p[2] for p in pts], float).reshape(
                             samples, b.n, b.n))
            got = cache[(link, samples)] = (xs, basis)
        return got

    def tip_deflections(self, q) -> np.ndarray:
        """Transverse tip deflection w(L) of every beam in its hub frame (m; rigid rung:
        L·β; the rod rung: its exact tip, :meth:`BeamDiscretization.tip_deflections`)."""
        return np.array([float(lm.beam.tip_deflections(q[lm.eta])[0]) for lm in self.links])

    def small_deflection_ratios(self, q) -> np.ndarray:
        """|w(L)|/L of every beam whose model holds for small deflections only (0 for the
        rod rung, exact at any deflection): what fidelity.max_deflection_ratio bounds."""
        return np.array([0.0 if lm.beam.rod is not None else
                         abs(float(lm.beam.phi_tip @ q[lm.eta])) / lm.beam.length
                         for lm in self.links])

    def drive_index(self) -> list[int]:
        return [lm.i_motor if lm.i_motor >= 0 else lm.i_joint for lm in self.links]


#: how the compiled kernel sums the beams: "invariants" where they are cheaper (default)
#: or "points" everywhere (``FLEXARM_BEAM_SUMS=points``; bench/bench_kernel.py compares them)
BEAM_SUMS = os.environ.get("FLEXARM_BEAM_SUMS", "invariants")
if BEAM_SUMS not in ("invariants", "points"):
    raise ValueError(f"environment variable FLEXARM_BEAM_SUMS: got {BEAM_SUMS!r}, expected "
                     f"'invariants' (the default) or 'points'")


def by_invariants(ne: int, points: int, foreshortening: bool) -> bool:
    """True when the compiled kernel sums a beam's inertia through its invariants
    (:func:`compiled.chain.beam_invariants`, O(ne⁴) per evaluation with foreshortening,
    O(ne²) without) rather than over its mass points (O(P·n²)): the modal rungs and the
    single cubic, not the finite elements and differences, whose many coordinates make the
    fourth-order tensor dearer than their points (and sparse S per point cheap)."""
    return BEAM_SUMS == "invariants" and ne > 0 and (not foreshortening or ne * ne <= points)


def _invariants(beams, use, nemax: int, foreshortening: bool):
    """(Σm, Σm x₀, Σm x₀²), (Σm φ, Σm x₀ φ), (Σm φφᵀ, Σm S, Σm x₀ S), Σm φ_a S_bc and
    Σm S_ab S_cd of each beam's mass points (x₀ = r_h + x), for the links ``use`` marks
    (:class:`compiled.layout.Model`'s inv_* fields; the tensors are 1-wide when no link
    uses them). Without foreshortening the S terms stay zero."""
    nl = len(beams)
    n = nemax if any(use) else 1
    m0 = np.zeros((nl, 3))
    m1 = np.zeros((nl, 2, n))
    m2 = np.zeros((nl, 3, n, n))
    G = np.zeros((nl, n, n, n))
    H = np.zeros((nl, n, n, n, n))
    for k, b in enumerate(beams):
        if not use[k]:
            continue
        m, x0, phi, e = b.mass, b.hub_radius + b.x, b.phi, b.n
        # einsum's own loops, not BLAS: the same bits in every process (BLAS's small
        # products came out differently between processes, so a run differed in its last
        # bits between a process that compiled the kernel and one that loaded it)
        m0[k] = m.sum(), np.einsum("p,p->", m, x0), np.einsum("p,p,p->", m, x0, x0)
        m1[k, 0, :e] = np.einsum("p,pa->a", m, phi)
        m1[k, 1, :e] = np.einsum("p,p,pa->a", m, x0, phi)
        m2[k, 0, :e, :e] = np.einsum("p,pa,pb->ab", m, phi, phi)
        if foreshortening:
            S = b.S
            m2[k, 1, :e, :e] = np.einsum("p,pab->ab", m, S)
            m2[k, 2, :e, :e] = np.einsum("p,pab->ab", m * x0, S)
            G[k, :e, :e, :e] = np.einsum("p,pa,pbc->abc", m, phi, S)
            H[k, :e, :e, :e, :e] = np.einsum("p,pab,pcd->abcd", m, S, S)
    return m0, m1, m2, G, H


def _offset_frame(fr: Frame, p) -> Frame:
    """The frame translated by the constant offset p (expressed in fr)."""
    if not np.any(p):
        return fr
    Ap = _rot(fr.psi) @ p
    return Frame(fr.o + Ap, fr.Jo + np.outer(E2 @ Ap, fr.Jpsi), fr.co - fr.psid**2 * Ap,
                 fr.psi, fr.Jpsi, fr.psid)


def _add_body(M, h, Qg, fr: Frame, body, g):
    """Add a rigid body (mass, inertia about CG, CG offset in ``fr``) to M, h and Q_grav."""
    if body.mass == 0.0 and body.inertia == 0.0:
        return
    Ap = _rot(fr.psi) @ np.asarray(body.cg, float)
    J = fr.Jo + np.outer(E2 @ Ap, fr.Jpsi)
    c = fr.co - fr.psid**2 * Ap
    M += body.mass * (J.T @ J) + body.inertia * np.outer(fr.Jpsi, fr.Jpsi)
    h += body.mass * (J.T @ c)
    if np.any(g):
        Qg += body.mass * (J.T @ g)
