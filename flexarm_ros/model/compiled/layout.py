"""The data of the compiled chain, by name: the model (:class:`Model`, built once per chain
by :meth:`chain.Chain._pack`) and the scratch arrays of one evaluation (:class:`Workspace`,
:func:`workspace`).

Both are ``typing.NamedTuple``: compiled code reads ``model.phi`` as cheaply as a plain
tuple's element, arrays stay mutable (the plant writes held torques into
``model.prog_par``; the kernel fills the workspace), and a field added anywhere cannot
shift another.

Across the Python boundary they travel as plain tuples (``tuple(model)``,
:func:`workspace`'s result): numba's dispatcher types a plain tuple from its elements, a
named one also from its class and field names, on every call — which costs about as much
as the whole call. So Python holds and passes the plain tuples (``Chain.kernel_args``,
its workspace), and every compiled entry point names them on the way in with
:func:`named` (which compiles to nothing); ``Workspace._make(ws)`` names a workspace in
Python.

Shapes: n coordinates, nl links, nf free coordinates, nz actuator states, P the largest
number of beam mass points (row P of the per-point arrays is the tip), ne the largest
number of elastic coordinates of a link.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from flexarm_ros.model.compiled import jit_inline


class Model(NamedTuple):
    """The chain as flat arrays for the compiled kernel (:mod:`chain` for the equations)."""
    n: int                      # coordinates
    nl: int                     # links
    nz: int                     # actuator states
    # per link k
    i_joint: np.ndarray         # (nl,) int: joint-angle coordinate
    e0: np.ndarray              # (nl,) int: first elastic coordinate
    ne: np.ndarray              # (nl,) int: elastic coordinates
    bodies: np.ndarray          # (nl, 2, 4): hub, tip body (mass, inertia about cg, cg x, y)
    joint_offset: np.ndarray    # (nl, 2): the next joint on the tip frame (m)
    hub_radius: np.ndarray      # (nl,) m
    slope_tip: np.ndarray       # (nl, ne): φ′(L), the tip frame's turn per η
    # per beam point p of link k (p < npt[k] mass points, p = npt[k] the tip)
    npt: np.ndarray             # (nl,) int: mass points
    abscissa: np.ndarray        # (nl, P+1) m: x_p (the tip row: the beam length)
    point_mass: np.ndarray      # (nl, P+1) kg
    phi: np.ndarray             # (nl, P+1, ne): φ(x_p)
    S: np.ndarray               # (nl, P+1, ne, ne): foreshortening S(x_p)
    ext: np.ndarray             # (nl, P+1) int: leading η that can be non-zero in φ, S
    # per link k whose mass points are summed once (inertia invariants, chain.beam_invariants):
    # ne_i = ne where any link uses them, else 1
    invariant: np.ndarray       # (nl,) bool: link k's beam by its invariants, not its points
    inv_mass: np.ndarray        # (nl, 3): Σm, Σm x₀, Σm x₀² (x₀ = r_h + x)
    inv_phi: np.ndarray         # (nl, 2, ne_i): Σm φ, Σm x₀ φ
    inv_mat: np.ndarray         # (nl, 3, ne_i, ne_i): Σm φφᵀ, Σm S, Σm x₀ S
    inv_G: np.ndarray           # (nl, ne_i, ne_i, ne_i): Σm φ_a S_bc
    inv_H: np.ndarray           # (nl, ne_i, ne_i, ne_i, ne_i): Σm S_ab S_cd
    # environment and constant matrices
    gravity: np.ndarray         # (2,) m/s²
    foreshortening: bool
    base_angle: float           # rad
    M_drive: np.ndarray         # (n, n) drive inertia
    K: np.ndarray               # (n, n) stiffness
    D: np.ndarray               # (n, n) damping
    # coordinates
    free: np.ndarray            # (nf,) int
    presc: np.ndarray           # (np,) int: prescribed coordinates
    motion_code: np.ndarray     # (np,) int: programs.encode of each prescribed motion
    motion_par: np.ndarray      # (np, 8)
    # actuators j (programs.encode of the input, drives.encode of the drive)
    act_coord: np.ndarray       # (na,) int: drive coordinate
    prog_code: np.ndarray       # (na,) int
    prog_par: np.ndarray        # (na, 8)
    prog_times: np.ndarray      # (na, T) breakpoints
    prog_values: np.ndarray     # (na, T)
    prog_len: np.ndarray        # (na,) int: used breakpoints
    act_kind: np.ndarray        # (na,) int: drives.IDEAL ... HYDRAULIC
    act_par: np.ndarray         # (na, drives.N_PAR)
    act_state: np.ndarray       # (na,) int: index in z, −1 without a state
    z_lo: np.ndarray            # (max(nz, 1),) state bounds
    z_hi: np.ndarray
    # backlash couplings
    backlash_idx: np.ndarray    # (nb, 2) int: motor, joint coordinate
    backlash_par: np.ndarray    # (nb, 3): half width (rad), stiffness, damping
    # the rod rung's links (model/rod.py): their points from the exact kinematics
    rod: np.ndarray             # (nl,) bool
    rod_T: np.ndarray           # (nl, P+1, ne): ∂θ/∂η at the points and the tip
    rod_C: np.ndarray           # (nl, P+1, ne): ∂ε/∂η
    rod_W: np.ndarray           # (nl, P+1, P): the integration matrix
    # air bearings on the table (model/bearings.py): friction at a body's bearing point
    bearing_idx: np.ndarray     # (nb, 3) int: link, body (0 hub, 1 tip), loading actuator or −1
    bearing_par: np.ndarray     # (nb, 6): p_x, p_y (m), m g₀ (N), v_s (m/s), b (1/m), μ
    bearing_spots: np.ndarray   # (ns, 5): bearing, centre x, y (m), radius (m), μ_i


class Workspace(NamedTuple):
    """Scratch arrays of one kernel evaluation (allocated once per run by
    :func:`workspace`); after :func:`chain.forces` they hold M, f, ż and the frames."""
    q: np.ndarray               # (n,) coordinates (prescribed ones set from their programs)
    qd: np.ndarray              # (n,)
    M: np.ndarray               # (n, n) mass matrix
    h: np.ndarray               # (n,) velocity terms
    Qg: np.ndarray              # (n,) gravity forces
    Jo: np.ndarray              # (2, n) running frame origin Jacobian (last tip frame's)
    Jpsi: np.ndarray            # (n,) running frame angle Jacobian
    Seta: np.ndarray            # (ne,) S(x) η of one point
    inv_vec: np.ndarray         # (6, ne) vectors of one link's invariant terms
    inv_E: np.ndarray           # (ne, ne) its elastic mass block
    Jx: np.ndarray              # (n,) one point's Jacobian rows
    Jy: np.ndarray
    Jtx: np.ndarray             # (n,) the beam tip's Jacobian rows
    Jty: np.ndarray
    Mff: np.ndarray             # (nf, nf) mass matrix of the free coordinates
    ff: np.ndarray              # (nf,)
    L: np.ndarray               # (nf, nf) its Cholesky factor
    y: np.ndarray               # (nf,)
    acc: np.ndarray             # (nf,) free accelerations
    pdd: np.ndarray             # (max(np, 1),) prescribed accelerations
    f: np.ndarray               # (n,) generalized forces
    xdot: np.ndarray            # (2 nf + nz,)
    zd: np.ndarray              # (max(nz, 1),) actuator state rates
    tip: np.ndarray             # (6,) last tip frame: o, c_o, ψ, ψ̇
    frames: np.ndarray          # (nl, 2, 6) hub (0) / tip (1) frame of each link: o, c_o, ψ, ψ̇
    frame_jac: np.ndarray       # (nl, 2, 3, n) their ∂o_x/∂q, ∂o_y/∂q, ∂ψ/∂q
    rod_s: np.ndarray           # (P+1, 2) a rod's local positions (points, tip)
    rod_sd: np.ndarray          # (P+1, 2) their rates
    rod_ds: np.ndarray          # (P+1, 2, ne) their ∂s/∂η
    rod_a: np.ndarray           # (P+1, 2) their velocity-product accelerations
    rod_g: np.ndarray           # (P, 2, ne + 3): the integrands of ∂s/∂η (ne), a, f, ḟ


def workspace(model) -> tuple:
    """Scratch arrays for :func:`chain.chain_terms` / :func:`chain.rhs_into` as the plain
    tuple the compiled entry points take (``model`` named or plain)."""
    model = Model._make(model)
    n, nl, nz = model.n, model.nl, model.nz
    ne = model.phi.shape[2]
    P = model.phi.shape[1] - 1
    nf = model.free.shape[0]
    npr = model.presc.shape[0]
    e = np.empty
    return tuple(Workspace(
        q=e(n), qd=e(n), M=e((n, n)), h=e(n), Qg=e(n), Jo=e((2, n)), Jpsi=e(n), Seta=e(ne),
        inv_vec=e((6, ne)), inv_E=e((ne, ne)),
        Jx=e(n), Jy=e(n), Jtx=e(n), Jty=e(n), Mff=e((nf, nf)), ff=e(nf), L=e((nf, nf)),
        y=e(nf), acc=e(nf), pdd=e(max(npr, 1)), f=e(n), xdot=e(2 * nf + nz),
        zd=e(max(nz, 1)), tip=e(6), frames=e((nl, 2, 6)), frame_jac=e((nl, 2, 3, n)),
        rod_s=e((P + 1, 2)), rod_sd=e((P + 1, 2)), rod_ds=e((P + 1, 2, ne)),
        rod_a=e((P + 1, 2)), rod_g=e((P, 2, ne + 3))))


@jit_inline
def named(model_args, ws_args):
    """(Model, Workspace) of the plain tuples a compiled entry point receives."""
    return Model(*model_args), Workspace(*ws_args)
