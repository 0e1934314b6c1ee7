"""Suite-wide invariants over every shipped scene (dm_control suite_test habit)."""

import numpy as np
import pytest

from flexarm_ros.model.chain import Chain
from flexarm_ros.model.contact import build_contact
from flexarm_ros.scene import config_dir, load_scene
from flexarm_ros.sim.simulate import simulate

SCENES = sorted(p.stem for p in config_dir().glob("*.yaml"))


def test_required_scenes_are_shipped():
    for name in ("link", "link_tipmass", "link_flexjoint", "hydraulic_0kg", "hydraulic_2kg",
                 "hydraulic_4kg", "two_link_free"):
        assert name in SCENES


@pytest.mark.parametrize("name", SCENES)
def test_scene_loads_runs_finite_and_repeats_bit_identically(name):
    scene = load_scene(name).with_fidelity(output_dt=0.005)
    a = simulate(scene, duration=0.1)
    b = simulate(scene, duration=0.1)
    assert a.summary()["status"] == 0
    for key, col in a.columns.items():
        if col.dtype.kind in "OUS":                           # contact_phase
            assert set(col) <= {"free", "impact", "sliding", "sticking"}, key
        else:
            assert np.all(np.isfinite(col)), key
        assert np.array_equal(col, b.columns[key]), key      # same input → same bits
    assert set(a.chain.names) <= set(a.columns)
    for name_ in a.chain.names:
        assert f"{name_}_rate" in a.columns


@pytest.mark.parametrize("name", SCENES)
def test_scene_documents_its_sources(name):
    scene = load_scene(name)
    assert scene.description.strip() and scene.source.strip()
    for a in scene.assumptions:
        assert a.key.strip() and a.note.strip()


@pytest.mark.parametrize("name", SCENES)
def test_no_energy_gain_without_input(name):
    """With inputs and drives removed, energy can only stay (no damping) or fall (damping).
    (Drives are energy sources or stores the mechanical energy does not count: a valve with
    its null flow, an armature inductance.)"""
    import dataclasses
    scene = load_scene(name)
    scene = dataclasses.replace(scene, links=tuple(
        dataclasses.replace(lk, joint=dataclasses.replace(lk.joint, drive=None))
        for lk in scene.links), sensors=())
    scene = dataclasses.replace(scene, inputs=(), initial=dataclasses.replace(
        scene.initial, static_equilibrium=False)).with_fidelity(output_dt=0.005)
    # give every joint a rate so there is something to conserve
    links = tuple(dataclasses.replace(lk, joint=dataclasses.replace(lk.joint, initial_rate=0.5))
                  for lk in scene.links)
    scene = dataclasses.replace(scene, links=links)
    if scene.fidelity.integrator == "rk4" and not scene.walls:
        # samples on step ends: the step's energy, not the dense output's interpolation
        # (which may exceed it by O(h⁴) between steps); the step as the automatic one
        # capped to divide the output period
        from flexarm_ros.model.statics import initial_x
        from flexarm_ros.sim.step import choose_step
        chain = Chain(scene)
        scene = scene.with_fidelity(dt=choose_step(chain, initial_x(chain), "rk4", 0.0, 0.005))
    res = simulate(scene, duration=0.2)
    e = res.columns["energy"]
    scale = max(abs(e[0]), 1e-9)
    assert np.all(np.diff(e) <= 1e-7 * scale), np.diff(e).max() / scale


def test_every_scene_has_a_built_model_without_unused_parts():
    """Model only what a scene requires: no motor coordinate without joint flexibility or
    backlash, no gravity terms on a horizontal table, no actuator state without a drive
    that has one, no contact without a wall."""
    for name in SCENES:
        scene = load_scene(name)
        chain = Chain(scene)
        flex = any(lk.joint.flexibility or lk.joint.backlash for lk in scene.links)
        assert any(n.endswith("_motor") for n in chain.names) == flex
        assert chain.has_gravity == any(scene.gravity)
        stateful = any(lk.joint.drive is not None and (
            lk.joint.drive.type == "hydraulic" or (lk.joint.drive.inductance or 0) > 0)
            for lk in scene.links)
        assert (chain.nz > 0) == stateful
        assert (build_contact(chain) is not None) == bool(scene.walls)
