"""flexarm_ros.io.units: every column ``flexarm simulate`` writes has a unit, so its CSV
reads as ``name [unit]`` (the convention ``flexarm compare`` reads), and read_table gives
the bare names back.

Truth: the units written here by hand from the model's definitions (angles rad, beam
deflections m, energy J, motor voltage V and current A, torques N*m, pressure Pa, the
instruments' outputs: encoder counts, V with a sensitivity, strain 1, potentiometer rad).
"""

from __future__ import annotations


import numpy as np
import pytest

from flexarm_ros.io.tables import read_table, write_table
from flexarm_ros.io.units import TEXT, column_unit, table_units
from flexarm_ros.scene import load_scene, shipped_scenes
from flexarm_ros.sim.simulate import simulate


def _columns(scene):
    res = simulate(scene, 0.004)
    cols = list(res.columns)
    for table in (res.sensor_tables or {}).values():
        cols += list(table)
    return cols


def _with_rung(scene, rung):
    return scene.with_fidelity(rung=rung, refine=0)


@pytest.mark.heavy
def test_every_simulate_column_of_every_shipped_scene_has_a_unit():
    scenes = [load_scene(n) for n in shipped_scenes()]
    free = load_scene("two_link_free")
    scenes += [_with_rung(free, "rigid"), _with_rung(free, "fem"), _with_rung(free, "modal"),
               _with_rung(load_scene("link"), "fd")]
    rungs = set()
    for sc in scenes:
        rungs.add(sc.fidelity.rung)
        cols = _columns(sc)
        units = table_units(cols, sc)
        assert [c for c in cols if c not in units] == [], sc.name
    assert rungs == {"rigid", "cubic", "modal", "fem", "fd", "rod"}


@pytest.mark.parametrize("name, unit", [
    ("t", "s"), ("link1_joint", "rad"), ("link1_motor", "rad"), ("link1_drive", "rad"),
    ("link1_tip_disp", "m"), ("link1_tip_rot", "rad"), ("link2_w3", "m"), ("link2_th3", "rad"),
    ("arm_y12", "m"), ("arm_mode2", "m"), ("link1_spring", "rad"),
    ("link1_joint_rate", "rad/s"), ("link1_tip_disp_rate", "m/s"), ("arm_mode1_rate", "m/s"),
    ("tip_x", "m"), ("tip_y", "m"), ("link2_tip_deflection", "m"), ("energy", "J"),
    ("link1_voltage", "V"), ("link1_current", "A"), ("arm_valve_current", "A"),
    ("arm_pressure", "Pa"), ("link1_torque_cmd", "N*m"), ("link1_drive_torque", "N*m"),
    ("gap", "m"), ("tool_vx", "m/s"), ("contact_normal_force", "N"),
    ("contact_normal_impulse", "N*s"), ("contact_phase", TEXT), ("no_such_column", None),
])
def test_column_units_by_name(name, unit):
    assert column_unit(name) == unit


def test_sensor_columns_take_the_instrument_units():
    units = {}
    for name in ("two_link_case1", "hydraulic_2kg", "link_motor"):
        sc = load_scene(name)
        units.update(table_units(_columns(sc), sc))
    assert units["acc_A"] == "V" and units["acc_A_true"] == "m/s^2"     # 100 mV/g
    assert units["strain_mid_true"] == "1" and units["pot_base_true"] == "rad"
    assert units["tip_x"] == units["tip_y"] == "m"                      # tip_position
    assert units["enc"] == units["enc_true"] == "count"


def test_headers_carry_units_and_read_back_bare(tmp_path):
    cols = {"t": np.array([0.0, 0.5]), "tip_x": np.array([1.0, 1.25]),
            "contact_phase": np.array(["free", "impact"], dtype=object),
            "mystery": np.array([3.0, 4.0])}
    path = write_table(tmp_path / "x.csv", cols, table_units(cols))
    assert path.read_text().splitlines()[0] == "t [s],tip_x [m],contact_phase [text],mystery"
    back = read_table(path)
    assert list(back) == list(cols)
    assert np.array_equal(back["tip_x"], cols["tip_x"])
    assert list(back["contact_phase"]) == ["free", "impact"]
