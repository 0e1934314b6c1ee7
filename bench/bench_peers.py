"""flexarm_ros against peer codes: error vs cost on the spin-up and seed 001's link (issue 36
item 5; not a unit test — timings are the machine's).

Scenes (read from their files, the same input programs as flexarm_ros):

``spin_up``       Simo & Vu-Quoc / Kane, Ryan & Banerjee: a beam clamped to a hub on the axis
                  whose angle follows the prescribed spin-up profile, 20 s.
``link_tipmass``  seed 001's link: hub inertia, a 1 m beam at hub radius 0.075 m, tip mass and
                  tip inertia, driven by the ±0.55 N·m torque pulse, 3 s.

Tools (each run's cost is its CPU seconds per simulated second, ``time.process_time``
around the solve only — model building excluded for every tool — best of ``--repeats``
rounds, the rounds interleaved over all runs so a shared host's load falls on every tool
alike; flexarm_ros runs one warm-up first, its JIT compilation excluded):

``flexarm``  flexarm_ros's rungs (``simulate`` with fidelity overrides: the rod at
             several curvature terms, the scene's default, modal and fem rungs).
``ancf``     Exudyn's geometrically exact ANCF cable (``ObjectANCFCable2D``) at several
             element counts and fixed steps (Exudyn's adaptive step off), generalized-α
             (Exudyn's implicit solver), modified Newton with an absolute tolerance
             (``ANCF_NEWTON_ABS``, ten and a hundred times it where Newton fails: with the
             default 1e-10 the beam starting at rest cuts the steps ~20× — Newton cannot
             meet it — and the run is 50–100× slower: the "not reached" paragraph of
             docs/accuracy.md before this bench). The hub is a rigid body pinned at the
             origin, the cable's first node clamped to it (``GenericJoint``); the spin-up
             prescribes the hub angle by a ``CoordinateConstraint`` whose offset user
             function is the flexarm_ros program; the link takes the torque program as a
             load user function on the free hub, its tip body a rigid body clamped to the
             last node. A beam without ``EA`` (the link) gets ``LINK_EA`` (steel over the
             seed's 20 × 20 mm section; its stretch is ~1e-9 m here).
``mujoco``   MuJoCo's cable (the ``mujoco.elasticity.cable`` plugin: a discrete Cosserat
             rod of rigid capsules, inextensible) on a hinge (:func:`mujoco_run`).

Error: both measures of :mod:`flexarm_ros.sim.truth` (tip position in the world, tip
deflection in the hub frame, each the largest over the whole run) against the reference
— the finest run of the independent code named by ``--reference`` (ANCF by default) —
on a common grid (``GRID``: every sample of the peer, every k-th of flexarm_ros's 1 ms
output). Two independent codes' finest runs are compared in the table's head.

    python bench/bench_peers.py [--scene spin_up|link_tipmass|both] [--quick]
        [--repeats N] [--markdown FILE] [--plot FILE.png] [--json FILE]

Needs the ``peers`` extra (``pip install -e .[peers]``: exudyn, mujoco); without them
only the flexarm_ros rows run (and say so).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from flexarm_ros.model import programs
from flexarm_ros.scene import load_scene
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.sim.truth import measures

#: comparison grid (s) per scene: the spin-up's motion is slow (first mode ~0.6 Hz), the
#: link's fastest resolved mode ~100 Hz
GRID = {"spin_up": 0.01, "link_tipmass": 0.001}
DURATION = {"spin_up": 20.0, "link_tipmass": 3.0}
ANCF_NEWTON_ABS = 1e-6     # N: Exudyn's Newton absolute tolerance, first tried (module doc)
ANCF_NEWTON_REL = 1e-8
ANCF_RHO_INF = 0.8         # generalized-α spectral radius (1 fails with the index-3 constraints)
#: the link's axial stiffness for the ANCF cable (N): E = 1.5e11 Pa (EI / (b h³/12)) over
#: A = 4e-4 m² (seed 001's 20 × 20 mm section); flexarm_ros's rod is inextensible there
LINK_EA = 6.0e7

#: flexarm_ros runs per scene: (label, fidelity overrides); {} is the scene as shipped
FLEXARM = {
    "spin_up": [
        ("rod 4", {"rung": "rod", "refine": 4, "dt": 0.0}),
        ("rod 5 (default, 3.3 ms)", {}),
        ("rod 5", {"rung": "rod", "refine": 5, "dt": 0.0}),
        ("rod 6", {"rung": "rod", "refine": 6, "dt": 0.0}),
        ("rod 8", {"rung": "rod", "refine": 8, "dt": 0.0}),
        ("modal 6", {"rung": "modal", "refine": 6, "dt": 0.0}),
        ("fem 8", {"rung": "fem", "refine": 8, "dt": 0.0}),
    ],
    "link_tipmass": [
        ("modal 3 (default)", {}),
        ("rod 4", {"rung": "rod", "refine": 4, "dt": 0.0}),
        ("rod 5", {"rung": "rod", "refine": 5, "dt": 0.0}),
        ("rod 6", {"rung": "rod", "refine": 6, "dt": 0.0}),
        ("rod 8", {"rung": "rod", "refine": 8, "dt": 0.0}),
    ],
}
#: ANCF runs per scene: (elements, step s)
ANCF = {
    "spin_up": [(4, 0.01), (8, 0.01), (8, 0.005), (16, 0.005), (16, 0.0025), (32, 0.0025),
                (32, 0.00125)],
    "link_tipmass": [(4, 0.001), (8, 0.001), (8, 0.0005), (16, 0.0005), (16, 0.00025),
                     (32, 0.00025)],
}
#: the reference runs: (ANCF elements, step), the rod's terms
ANCF_REFERENCE = {"spin_up": (64, 0.000625), "link_tipmass": (64, 0.000125)}
ROD_REFERENCE = {"spin_up": 12, "link_tipmass": 12}
#: MuJoCo cable runs per scene: (segments, step s)
MUJOCO = {
    "spin_up": [(10, 0.00025), (20, 0.000125), (40, 0.0000625)],
    "link_tipmass": [(10, 0.0001)],
}


# ---------------------------------------------------------------------------------------
# the scene's data and input program

def scene_data(name: str) -> dict:
    """What the peers need of a one-link scene, from its file."""
    sc = load_scene(name)
    if len(sc.links) != 1 or sc.walls or any(g != 0.0 for g in sc.gravity):
        raise SystemExit(f"{name}: the peers bench takes one link, no wall, no gravity")
    lk = sc.links[0]
    b = lk.beam
    inp = sc.inputs[0]
    if inp.motion is not None:
        code, p, times, values = programs.encode(inp.motion, lk.joint.initial_angle)
        kind = "motion"
    else:
        code, p, times, values = programs.encode(inp.torque)
        kind = "torque"
    return dict(scene=sc, name=name, link=lk.name, L=b.length, EI=b.EI,
                EA=b.EA if b.EA else LINK_EA, rhoA=b.mass_per_length, r=b.hub_radius,
                hub_J=lk.hub.inertia, tip_m=lk.tip.mass, tip_J=lk.tip.inertia,
                theta0=lk.joint.initial_angle, kind=kind,
                program=(code, p, times, values))


def motion(d, t):
    code, p, _, _ = d["program"]
    return programs.eval_motion(code, p, t)


def torque(d, t):
    code, p, times, values = d["program"]
    return programs.eval_torque(code, p, times, values, t)


def _columns(d, t, tip, phi):
    """{t, tip_x, tip_y, <link>_tip_deflection} from tip positions (N, 2) and hub angles."""
    t = np.asarray(t, float)
    tip = np.asarray(tip, float)
    phi = np.asarray(phi, float)
    w = -np.sin(phi) * tip[:, 0] + np.cos(phi) * tip[:, 1]
    return {"t": t, "tip_x": tip[:, 0], "tip_y": tip[:, 1], f"{d['link']}_tip_deflection": w}


def on_grid(cols, grid):
    """The samples of ``cols`` at multiples of ``grid`` (nearest sample, which must be
    within 1e-9 s: every run here samples the grid exactly)."""
    t = cols["t"]
    n = int(math.floor(t[-1] / grid + 1e-9)) + 1
    want = np.arange(n) * grid
    idx = np.searchsorted(t, want - 1e-9)
    idx = np.minimum(idx, len(t) - 1)
    off = np.abs(t[idx] - want)
    if np.max(off) > 1e-7:
        k = int(np.argmax(off > 1e-7))
        raise RuntimeError(f"a run does not sample the comparison grid: nearest sample to "
                           f"t = {want[k]:.6g} s is {t[idx[k]]:.9g} s (largest offset "
                           f"{np.max(off):.3g} s)")
    return {k: np.asarray(v)[idx] for k, v in cols.items()}


# ---------------------------------------------------------------------------------------
# flexarm_ros

def flexarm_run(d, overrides, T, grid):
    """(columns on the grid, CPU s of the simulate call)."""
    sc = d["scene"].with_fidelity(**overrides) if overrides else d["scene"]
    t0 = time.process_time()
    res = simulate(sc, T)
    cpu = time.process_time() - t0
    if not res.summary().get("success", True):
        raise RuntimeError(f"flexarm run failed: {res.summary().get('message')}")
    cols = {k: np.asarray(res.columns[k]) for k in
            ("t", "tip_x", "tip_y", f"{d['link']}_tip_deflection")}
    return on_grid(cols, grid), cpu


# ---------------------------------------------------------------------------------------
# Exudyn: ANCF cable

def have_exudyn() -> bool:
    try:
        import exudyn  # noqa: F401
    except ImportError:
        return False
    return True


#: Newton absolute tolerances (N) tried in turn at a fixed step: Exudyn's solver stops
#: where Newton cannot meet one (the residual's round-off grows with the elements' axial
#: stiffness EA/ℓ: the spin-up's 64 elements failed at 1e-6 and 2e-6 N, ran at 4e-6 N;
#: the link's 32 elements failed at 1e-6 N, 64 ran at 4e-5 N); with Exudyn's adaptive step
#: the run had instead halved its steps for minutes and left the comparison grid (session
#: 22). A run that needed more than the first says so in the log.
ANCF_NEWTON_LADDER = (1.0, 10.0, 100.0)


def ancf_run(d, n_el, h, T, grid):
    """(columns on the grid, CPU s of SolveDynamic) of the scene on ``n_el`` ANCF cable
    elements at a fixed step ``h`` (module doc), at the first Newton tolerance of
    :data:`ANCF_NEWTON_LADDER` (× :data:`ANCF_NEWTON_ABS`) its solver completes; the
    CPU s are those of that run."""
    import exudyn as exu
    err = None
    for factor in ANCF_NEWTON_LADDER:
        tol = ANCF_NEWTON_ABS * factor
        try:
            out = _ancf_once(d, n_el, h, T, grid, tol)
        except exu.SolverError as exc:   # Newton failed at this tolerance: the next one
            err = exc
            continue
        if factor != 1.0:
            print(f"  (ANCF {n_el} el at {1e3 * h:g} ms: Newton absolute tolerance {tol:g} N)",
                  flush=True)
        return out
    raise RuntimeError(f"ANCF {n_el} el at {h} s: Newton failed up to "
                       f"{ANCF_NEWTON_ABS * ANCF_NEWTON_LADDER[-1]:g} N ({err})")


def _ancf_once(d, n_el, h, T, grid, newton_abs):
    """:func:`ancf_run` at one Newton absolute tolerance (N)."""
    import warnings

    import exudyn as exu
    import exudyn.itemInterface as ii
    from exudyn.utilities import RigidBodyInertia  # noqa: F401  (loads the utilities)

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    L, r = d["L"], d["r"]
    th0 = d["theta0"]
    c0, s0 = math.cos(th0), math.sin(th0)
    lel = L / n_el
    nodes = []
    for i in range(n_el + 1):
        x = r + i * lel
        nodes.append(mbs.AddNode(ii.NodePoint2DSlope1(referenceCoordinates=[x * c0, x * s0,
                                                                            c0, s0])))
    for i in range(n_el):
        mbs.AddObject(ii.ObjectANCFCable2D(physicsLength=lel, physicsMassPerLength=d["rhoA"],
                                           physicsBendingStiffness=d["EI"],
                                           physicsAxialStiffness=d["EA"],
                                           nodeNumbers=[nodes[i], nodes[i + 1]]))
    # the hub: a rigid body pinned at the origin, the cable's first node clamped to it
    hub_J = d["hub_J"] if d["hub_J"] > 0 else 1.0
    n_hub = mbs.AddNode(ii.NodeRigidBody2D(referenceCoordinates=[0.0, 0.0, th0]))
    o_hub = mbs.AddObject(ii.ObjectRigidBody2D(nodeNumber=n_hub, physicsMass=1.0,
                                               physicsInertia=hub_J))
    m_root = mbs.AddMarker(ii.MarkerNodeRigid(nodeNumber=nodes[0]))
    m_hub = mbs.AddMarker(ii.MarkerBodyRigid(bodyNumber=o_hub, localPosition=[r, 0.0, 0.0]))
    mbs.AddObject(ii.GenericJoint(markerNumbers=[m_root, m_hub],
                                  constrainedAxes=[1, 1, 0, 0, 0, 1]))
    n_gr = mbs.AddNode(ii.NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
    m_gr = mbs.AddMarker(ii.MarkerNodeCoordinate(nodeNumber=n_gr, coordinate=0))
    for c in (0, 1):
        mc = mbs.AddMarker(ii.MarkerNodeCoordinate(nodeNumber=n_hub, coordinate=c))
        mbs.AddObject(ii.CoordinateConstraint(markerNumbers=[m_gr, mc]))
    if d["kind"] == "motion":
        m_phi = mbs.AddMarker(ii.MarkerNodeCoordinate(nodeNumber=n_hub, coordinate=2))

        def offset(mbs_, t, item, off):
            return motion(d, t)[0] - th0

        mbs.AddObject(ii.CoordinateConstraint(markerNumbers=[m_gr, m_phi],
                                              offsetUserFunction=offset))
    else:
        m_hub0 = mbs.AddMarker(ii.MarkerBodyRigid(bodyNumber=o_hub, localPosition=[0, 0, 0]))

        def load(mbs_, t, vec):
            return [0.0, 0.0, torque(d, t)]

        mbs.AddLoad(ii.LoadTorqueVector(markerNumber=m_hub0, loadVector=[0, 0, 0],
                                        loadVectorUserFunction=load))
    if d["tip_m"] > 0:
        xt = r + L
        n_tip = mbs.AddNode(ii.NodeRigidBody2D(referenceCoordinates=[xt * c0, xt * s0, th0]))
        o_tip = mbs.AddObject(ii.ObjectRigidBody2D(nodeNumber=n_tip, physicsMass=d["tip_m"],
                                                   physicsInertia=d["tip_J"]))
        m_end = mbs.AddMarker(ii.MarkerNodeRigid(nodeNumber=nodes[-1]))
        m_tip = mbs.AddMarker(ii.MarkerBodyRigid(bodyNumber=o_tip, localPosition=[0, 0, 0]))
        mbs.AddObject(ii.GenericJoint(markerNumbers=[m_end, m_tip],
                                      constrainedAxes=[1, 1, 0, 0, 0, 1]))
    s_tip = mbs.AddSensor(ii.SensorNode(nodeNumber=nodes[-1], storeInternal=True,
                                        outputVariableType=exu.OutputVariableType.Position))
    s_hub = mbs.AddSensor(ii.SensorNode(nodeNumber=n_hub, storeInternal=True,
                                        outputVariableType=exu.OutputVariableType.Coordinates))
    mbs.Assemble()
    ss = exu.SimulationSettings()
    ti = ss.timeIntegration
    ti.numberOfSteps = int(round(T / h))
    ti.endTime = T
    ti.verboseMode = 0
    # a fixed step as the table says: Exudyn's default halves the step where Newton
    # fails and grows it again, and its sensor then writes off the comparison grid
    # (session 22's 64-element reference); a step that fails now stops the run, which the
    # end-time check below names
    ti.adaptiveStep = False
    ti.newton.useModifiedNewton = True
    ti.newton.relativeTolerance = ANCF_NEWTON_REL
    ti.newton.absoluteTolerance = newton_abs
    ti.generalizedAlpha.spectralRadius = ANCF_RHO_INF
    ss.solution.file.write = False
    ss.solution.sensors.writePeriod = grid
    ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    ss.parallel.numberOfThreads = 1
    t0 = time.process_time()
    mbs.SolveDynamic(ss)
    cpu = time.process_time() - t0
    tip = mbs.GetSensorStoredData(s_tip)
    hub = mbs.GetSensorStoredData(s_hub)
    cols = _columns(d, tip[:, 0], tip[:, 1:3], hub[:, 3])
    if tip[-1, 0] < T - 1e-9:
        raise RuntimeError(f"ANCF {n_el} at {h}: stopped at {tip[-1, 0]} s")
    return on_grid(cols, grid), cpu


# ---------------------------------------------------------------------------------------
# MuJoCo

def have_mujoco() -> bool:
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return False
    return True


#: the MuJoCo rod's section radius (m): only I = π r⁴/4 matters (E is set so E·I = EI)
MJ_RADIUS = 0.02
#: the hub's armature (kg·m²): the hinge follows θ(t) by a torque J·θ̈ and is set to
#: (θ, θ̇) before every step, so the rod's reaction moves it by ~reaction/J·h² in a step
MJ_HUB_J = 1e9


def mujoco_run(d, n_seg, h, T, grid):
    """(columns on the grid, CPU s of the steps) of a prescribed-motion scene on MuJoCo's
    1D flex rod (MuJoCo ≥ 3.5 / 4: discrete elastic rod, the former cable plugin's
    successor): ``n_seg`` edges, RK4 at a fixed step ``h``, bending E·I = EI, the stretch
    by edge stiffness EA/ℓ (the rod itself is inextensible), the mass lumped on the
    vertices (flexcomp spreads it evenly: the pinned root vertex's share is lost, so the
    total is scaled by (n+1)/n), the first edge pinned to a hub body on a hinge whose
    motion is prescribed (``MJ_HUB_J``). A torque-driven hub with a tip body (seed 001's
    link) is not expressed: the rod's far end would need pinning to a free body carrying
    the tip mass and inertia, which flexcomp's pins (to its own parent body) do not give."""
    import mujoco

    if d["kind"] != "motion" or d["tip_m"] > 0:
        raise RuntimeError("not expressed: MuJoCo's flexcomp rod pins to its parent body "
                           "only (no tip body with rotary inertia at the far end)")
    L, r = d["L"], d["r"]
    E = d["EI"] / (math.pi * MJ_RADIUS ** 4 / 4.0)
    le = L / n_seg
    xml = f"""<mujoco>
 <option timestep="{h!r}" integrator="RK4" gravity="0 0 0"/>
 <worldbody>
  <body name="hub">
   <joint name="hinge" type="hinge" axis="0 0 1" armature="{MJ_HUB_J!r}"
          ref="0" pos="0 0 0"/>
   <geom type="sphere" size="0.05" mass="1" contype="0" conaffinity="0"/>
   <flexcomp name="rod" type="grid" dim="1" count="{n_seg + 1} 1 1" spacing="{le!r} 1 1"
             pos="{r + L / 2!r} 0 0" radius="{MJ_RADIUS!r}"
             mass="{d['rhoA'] * L * (n_seg + 1) / n_seg!r}">
     <pin id="0 1"/>
     <contact contype="0" conaffinity="0"/>
     <elasticity young="{E!r}" poisson="0.3"/>
     <edge stiffness="{d['EA'] / le!r}"/>
   </flexcomp>
  </body>
 </worldbody>
</mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(m)
    th0 = d["theta0"]
    data.qpos[0] = th0
    k = int(round(grid / h))
    n = int(round(T / h))
    if abs(k * h - grid) > 1e-12 or abs(n * h - T) > 1e-9:
        raise RuntimeError("the step must divide the grid and the duration")
    t_out, tip, phi = [], [], []
    t0 = time.process_time()
    for i in range(n + 1):
        if i % k == 0:
            mujoco.mj_fwdPosition(m, data)
            t_out.append(i * h)
            tip.append(data.flexvert_xpos[-1][:2].copy())
            phi.append(data.qpos[0])
        if i == n:
            break
        th, thd, thdd = motion(d, i * h)
        data.qpos[0] = th
        data.qvel[0] = thd
        data.qfrc_applied[0] = MJ_HUB_J * thdd
        mujoco.mj_step(m, data)
    cpu = time.process_time() - t0
    return on_grid(_columns(d, t_out, tip, phi), grid), cpu


# ---------------------------------------------------------------------------------------
# the bench: interleaved runs, errors against the reference, the table

def reference_runs(d, T, grid, quick):
    """{label: columns} of the references: ANCF at its finest element count, Richardson-
    extrapolated in the step (generalized-α is second order: measured ×4 per halving here)
    — and the rod with the most terms, the independent check. Each with its CPU s."""
    out = {}
    if have_exudyn():
        n_el, h = ANCF_REFERENCE[d["name"]]
        if quick:
            n_el, h = n_el // 2, h * 2
        c1, cpu1 = ancf_run(d, n_el, 2 * h, T, grid)
        c2, cpu2 = ancf_run(d, n_el, h, T, grid)
        rich = {k: (v if k == "t" else v + (v - c1[k]) / 3.0) for k, v in c2.items()}
        out[f"ANCF {n_el} el, Richardson of {2e3 * h:g}/{1e3 * h:g} ms"] = (rich, cpu1 + cpu2)
        out[f"ANCF {n_el} el, {1e3 * h:g} ms"] = (c2, cpu2)
    terms = ROD_REFERENCE[d["name"]]
    c, cpu = flexarm_run(d, {"rung": "rod", "refine": terms, "dt": 0.0, "output_dt": grid},
                         T, grid)
    out[f"flexarm rod {terms}"] = (c, cpu)
    return out


def jobs_for(d, T, grid, quick, tools):
    """[(tool, label, callable() -> (columns, cpu))] of one scene."""
    jobs = []
    if "flexarm" in tools:
        for label, ov in FLEXARM[d["name"]]:
            ov = dict(ov, output_dt=grid)
            jobs.append(("flexarm_ros", label, lambda ov=ov: flexarm_run(d, ov, T, grid)))
    if "ancf" in tools and have_exudyn():
        runs = ANCF[d["name"]][:3] if quick else ANCF[d["name"]]
        for n_el, h in runs:
            jobs.append(("Exudyn ANCF", f"{n_el} el, {1e3 * h:g} ms",
                         lambda n_el=n_el, h=h: ancf_run(d, n_el, h, T, grid)))
    if "mujoco" in tools and have_mujoco():
        runs = MUJOCO[d["name"]][:2] if quick else MUJOCO[d["name"]]
        for n_seg, h in runs:
            jobs.append(("MuJoCo rod", f"{n_seg} seg, {1e3 * h:g} ms",
                         lambda n_seg=n_seg, h=h: mujoco_run(d, n_seg, h, T, grid)))
    return jobs


def bench_scene(name, quick=False, repeats=2, tools=("flexarm", "ancf", "mujoco"),
                reference="ancf", duration=None, log=print):
    """Run one scene's jobs interleaved ``repeats`` times; returns a dict with the rows
    (tool, setting, cpu_per_s, position_m, deflection_m, deflection_share) and the
    references' agreement."""
    d = scene_data(name)
    T = duration or (min(DURATION[name], 2.0 if name == "spin_up" else 0.5) if quick
                     else DURATION[name])
    grid = GRID[name]
    # warm-up: flexarm_ros's JIT compilation of every rung it runs, outside the timing
    for _, ov in FLEXARM[name]:
        flexarm_run(d, dict(ov, output_dt=grid), min(T, 0.1), grid)
    jobs = jobs_for(d, T, grid, quick, tools)
    cols, cpu = {}, {}
    failed = {}
    for rep in range(repeats):
        for tool, label, fn in jobs:
            key = (tool, label)
            if key in failed:
                continue
            try:
                c, t = fn()
            except Exception as exc:                           # a peer's solver gave up
                failed[key] = " ".join(str(exc).split())[:160]
                log(f"  {tool} {label}: failed ({failed[key]})")
                continue
            cols.setdefault(key, c)
            cpu[key] = min(cpu.get(key, math.inf), t)
            if rep == 0:
                log(f"  {tool} {label}: {t / T:.4g} CPU s/s")
    refs = reference_runs(d, T, grid, quick) if reference != "none" else {}
    labels = list(refs)
    if reference == "ancf" and have_exudyn():
        ref_label = labels[0]
    else:
        ref_label = labels[-1]
    ref = refs[ref_label][0]
    link = [d["link"]]
    agreement = []
    for lab in labels:
        if lab != ref_label:
            m = measures(refs[lab][0], ref, link)
            agreement.append({"run": lab, "position_m": m.position_m,
                              "deflection_m": m.deflection_max_m,
                              "cpu_per_s": refs[lab][1] / T})
    rows = []
    for (tool, label), c in cols.items():
        m = measures(c, ref, link)
        rows.append({"tool": tool, "setting": label, "cpu_per_s": cpu[(tool, label)] / T,
                     "position_m": m.position_m, "deflection_m": m.deflection_max_m,
                     "deflection_share": m.deflection_share[0]})
    for (tool, label), why in failed.items():
        rows.append({"tool": tool, "setting": label, "failed": why})
    peak = float(np.max(np.abs(ref[f"{d['link']}_tip_deflection"])))
    return {"scene": name, "duration_s": T, "grid_s": grid, "reference": ref_label,
            "reference_cpu_per_s": refs[ref_label][1] / T, "agreement": agreement,
            "peak_deflection_m": peak, "rows": rows, "repeats": repeats}


def front_ratio(result, fast_tool="flexarm_ros", slow_tool="Exudyn ANCF", measure="position_m"):
    """For each run of ``fast_tool``, the cost of ``slow_tool`` at the same error —
    interpolated log-log on the slow tool's lower front (its cheapest run at each error),
    None outside its range — over the fast run's cost: [(setting, error, ratio)]."""
    slow = sorted((r[measure], r["cpu_per_s"]) for r in result["rows"]
                  if r["tool"] == slow_tool and "failed" not in r)
    front = []                                  # error ascending, cost descending
    for e, c in slow:
        if not front or c < front[-1][1]:
            front.append((e, c))
    out = []
    for r in result["rows"]:
        if r["tool"] != fast_tool or "failed" in r:
            continue
        e = r[measure]
        cost = None
        for (e1, c1), (e2, c2) in zip(front, front[1:]):
            if e1 <= e <= e2:
                f = math.log(e / e1) / math.log(e2 / e1)
                cost = math.exp(math.log(c1) + f * (math.log(c2) - math.log(c1)))
        out.append((r["setting"], e, None if cost is None else cost / r["cpu_per_s"]))
    return out


def markdown(results) -> str:
    lines = []
    for res in results:
        lines.append(f"**{res['scene']}** ({res['duration_s']:g} s, errors on a "
                     f"{1e3 * res['grid_s']:g} ms grid, largest over the run, against "
                     f"{res['reference']}; peak tip deflection {res['peak_deflection_m']:.3g} m;"
                     f" CPU best of {res['repeats']} interleaved rounds)")
        lines.append("")
        for a in res["agreement"]:
            lines.append(f"- reference check: {a['run']} is {a['position_m']:.2g} m (position), "
                         f"{a['deflection_m']:.2g} m (deflection) from it "
                         f"({a['cpu_per_s']:.3g} CPU s/s)")
        lines.append("")
        lines.append("| tool | setting | CPU s per sim s | tip position (m) | tip deflection (m) "
                     "| share of peak |")
        lines.append("|---|---|---|---|---|---|")
        for r in res["rows"]:
            if "failed" in r:
                lines.append(f"| {r['tool']} | {r['setting']} | failed: {r['failed']} | | | |")
                continue
            lines.append(f"| {r['tool']} | {r['setting']} | {r['cpu_per_s']:.3g} | "
                         f"{r['position_m']:.2g} | {r['deflection_m']:.2g} | "
                         f"{100 * r['deflection_share']:.2g} % |")
        ratios = front_ratio(res)
        if any(x[2] is not None for x in ratios):
            lines.append("")
            lines.append("ANCF's cost at flexarm_ros's error (log-log interpolation on ANCF's "
                         "front, tip position) over flexarm_ros's cost: " + ", ".join(
                             f"{s} {x:.0f}×" for s, _, x in ratios if x is not None))
        lines.append("")
    return "\n".join(lines)


def plot(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(results), 2, figsize=(10, 4 * len(results)), squeeze=False)
    marks = {"flexarm_ros": "o", "Exudyn ANCF": "s", "MuJoCo rod": "^"}
    for i, res in enumerate(results):
        for j, (meas, title) in enumerate((("position_m", "tip position"),
                                           ("deflection_m", "tip deflection (hub frame)"))):
            ax = axes[i][j]
            for tool, mk in marks.items():
                rows = [r for r in res["rows"] if r["tool"] == tool and "failed" not in r]
                if rows:
                    ax.loglog([r["cpu_per_s"] for r in rows], [r[meas] for r in rows], mk,
                              label=tool)
            ax.set_xlabel("CPU s per simulated s")
            ax.set_ylabel("largest error over the run (m)")
            ax.set_title(f"{res['scene']}: {title}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", choices=("spin_up", "link_tipmass", "both"), default="both")
    ap.add_argument("--quick", action="store_true", help="short runs, fewer settings")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--tools", default="flexarm,ancf,mujoco")
    ap.add_argument("--reference", choices=("ancf", "rod"), default="ancf")
    ap.add_argument("--markdown")
    ap.add_argument("--plot")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats: expected at least 1")
    if not have_exudyn() or not have_mujoco():
        print("note: the peers extra is not (fully) installed (pip install -e .[peers]); "
              f"exudyn: {have_exudyn()}, mujoco: {have_mujoco()}", file=sys.stderr)
    scenes = ("spin_up", "link_tipmass") if a.scene == "both" else (a.scene,)
    tools = tuple(a.tools.split(","))
    results = []
    for name in scenes:
        print(f"{name}:", flush=True)
        results.append(bench_scene(name, a.quick, a.repeats, tools, a.reference,
                                   log=lambda s: print(s, flush=True)))
    md = markdown(results)
    print(md)
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(md + "\n")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f, indent=1)
    if a.plot:
        plot(results, a.plot)


if __name__ == "__main__":
    main()
