"""Invalid scenes are rejected with a message naming the key path, the bad value and the
expectation (schema.py: ``key.path: got V, expected ...``), table-driven.

Each row: a mutation of a valid scene and three fragments the SceneError message must
contain — where (key path), what (the bad value as written back) and the expectation.
"""

import copy
from pathlib import Path

import pytest

from flexarm_ros.errors import SceneError
from flexarm_ros.scene import load_scene, load_scene_dict

BASE = {
    "name": "base",
    "links": [{"name": "l1", "beam": {"length": 1.0, "EI": 2.0, "mass_per_length": 0.5}},
              {"name": "l2", "beam": {"length": 0.8, "EI": 1.5, "mass_per_length": 0.4}}],
    "inputs": [{"joint": 1, "torque": {"type": "constant", "value": 0.1}}],
    "fidelity": {"rung": "cubic", "integrator": "rk4"},
}


def test_base_scene_is_valid():
    scene = load_scene_dict(copy.deepcopy(BASE))
    assert [lk.name for lk in scene.links] == ["l1", "l2"]


def _set(path, value):
    """Mutation setting BASE[path] = value (path: tuple of keys / indices)."""
    def mutate(d):
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
    return mutate


def _drop(path):
    def mutate(d):
        for k in path[:-1]:
            d = d[k]
        del d[path[-1]]
    return mutate


BEAM = ("links", 0, "beam")
TORQUE = ("inputs", 0, "torque")

# (id, mutation, [path fragment, value fragment, expectation fragment])
CASES = [
    # non-positive physical parameters
    ("EI-zero", _set(BEAM + ("EI",), 0.0),
     ["links[0].beam.EI", "got 0.0", "expected a finite number > 0"]),
    ("EI-negative", _set(BEAM + ("EI",), -2.0),
     ["links[0].beam.EI", "got -2.0", "> 0"]),
    ("EI-nan", _set(BEAM + ("EI",), float("nan")),
     ["links[0].beam.EI", "got nan", "a finite number"]),
    ("mass-per-length-zero", _set(BEAM + ("mass_per_length",), 0),
     ["links[0].beam.mass_per_length", "got 0", "> 0"]),
    ("mass-per-length-negative", _set(BEAM + ("mass_per_length",), -0.5),
     ["links[0].beam.mass_per_length", "got -0.5", "(kg/m)"]),
    ("length-zero", _set(("links", 1, "beam", "length"), 0.0),
     ["links[1].beam.length", "got 0.0", "> 0"]),
    ("length-negative", _set(BEAM + ("length",), -1.0),
     ["links[0].beam.length", "got -1.0", "expected a finite number > 0"]),
    ("tip-mass-negative", _set(("links", 0, "tip"), {"mass": -1.0}),
     ["links[0].tip.mass", "got -1.0", ">= 0"]),
    # unknown keys
    ("unknown-top", _set(("colour",), "red"),
     ["colour", "unknown key", "expected one of assumptions, base_angle"]),
    ("unknown-nested", _set(BEAM + ("GA",), 1.0e6),
     ["links[0].beam.GA", "unknown key", "expected one of E, EA, EI, damping"]),
    ("unknown-deep", _set(TORQUE + ("val",), 1.0),
     ["inputs[0].torque.val", "unknown key", "amplitude"]),
    ("unknown-fidelity", _set(("fidelity", "step"), 1e-4),
     ["fidelity.step", "unknown key", "dt"]),
    # wrong types
    ("string-for-number", _set(BEAM + ("EI",), "stiff"),
     ["links[0].beam.EI", "got 'stiff'", "expected a finite number > 0"]),
    ("numeric-string-for-number", _set(BEAM + ("length",), "1.0"),
     ["links[0].beam.length", "got '1.0' (str)", "a finite number"]),
    ("bool-for-number", _set(BEAM + ("length",), True),
     ["links[0].beam.length", "got True (bool)", "a finite number"]),
    ("bool-for-integer", _set(("inputs", 0, "joint"), True),
     ["inputs[0].joint", "got True (bool)", "expected an integer"]),
    ("float-for-integer", _set(("fidelity", "refine"), 2.5),
     ["fidelity.refine", "got 2.5", "expected an integer"]),
    ("list-for-mapping", _set(BEAM, [1.0, 2.0]),
     ["links[0].beam", "got [1.0, 2.0]", "expected a mapping of Beam fields"]),
    ("list-for-fidelity", _set(("fidelity",), ["rk4"]),
     ["fidelity", "got ['rk4']", "expected a mapping of Fidelity fields"]),
    ("mapping-for-list", _set(("links",), {"name": "l1"}),
     ["links", "got {'name': 'l1'}", "expected a list"]),
    ("number-for-bool", _set(("fidelity", "foreshortening"), 1),
     ["fidelity.foreshortening", "got 1", "expected true or false"]),
    ("short-vector", _set(("gravity",), [0.0, -9.81, 0.0]),
     ["gravity", "got [0.0, -9.81, 0.0]", "expected a list of 2 numbers"]),
    ("string-in-list", _set(TORQUE, {"type": "piecewise_constant", "times": [0.0, "one"],
                                     "values": [1.0, 2.0]}),
     ["inputs[0].torque.times[1]", "got 'one'", "a finite number"]),
    ("null-for-number", _set(("duration",), None),
     ["duration", "got None", "> 0"]),
    # missing required fields
    ("missing-links", _drop(("links",)),
     ["links", "missing required field", "the chain"]),
    ("empty-links", _set(("links",), []),
     ["links", "got []", "expected at least one link"]),
    ("missing-beam-length", _drop(BEAM + ("length",)),
     ["links[0].beam.length", "missing required field", "beam length"]),
    ("missing-beam", _drop(("links", 1, "beam")),
     ["links[1].beam", "missing required field", "Beam"]),
    ("missing-link-name", _drop(("links", 0, "name")),
     ["links[0].name", "missing required field", "link name"]),
    ("missing-program-type", _drop(TORQUE + ("type",)),
     ["inputs[0].torque.type", "missing required field", "program type"]),
    # bad choices
    ("bad-rung", _set(("fidelity", "rung"), "spectral"),
     ["fidelity.rung", "got 'spectral'", "expected one of rigid, cubic, modal, fem, fd"]),
    ("bad-integrator", _set(("fidelity", "integrator"), "euler"),
     ["fidelity.integrator", "got 'euler'", "expected one of rk4"]),
    ("bad-modal-basis", _set(("fidelity", "modal_basis"), "free_free"),
     ["fidelity.modal_basis", "got 'free_free'",
      "expected one of chain_loaded, tip_loaded, clamped_free"]),
    ("estimate-not-a-bool", _set(("fidelity", "estimate"), "maybe"),
     ["fidelity.estimate", "got 'maybe'", "expected true or false"]),
    ("program-key-of-another-type", _set(TORQUE + ("type",), "step"),
     ["inputs[0].torque.value", "a step program takes no value",
      "expected one of type, offset, amplitude, start"]),
    ("bad-program-type", _set(TORQUE + ("type",), "ramp"),
     ["inputs[0].torque.type", "got 'ramp'", "expected one of constant"]),
    ("motion-type-as-torque", _set(TORQUE, {"type": "spin_up"}),
     ["inputs[0].torque.type", "got 'spin_up'",
      "expected one of constant, step, pulse, square, piecewise_constant, piecewise_linear"]),
    ("torque-type-as-motion", _set(("inputs", 0), {"joint": 1, "motion": {"type": "pulse"}}),
     ["inputs[0].motion.type", "got 'pulse'", "spin_up, smooth_step, hold"]),
    ("rtol-out-of-range", _set(("fidelity", "rtol"), 1.5),
     ["fidelity.rtol", "got 1.5", "< 1"]),
    # bad inputs
    ("joint-out-of-range", _set(("inputs", 0, "joint"), 3),
     ["inputs[0].joint", "got 3", "expected 1..2"]),
    ("joint-zero", _set(("inputs", 0, "joint"), 0),
     ["inputs[0].joint", "got 0", ">= 1"]),
    ("two-inputs-one-joint", _set(("inputs",), [
        {"joint": 2, "torque": {"type": "constant", "value": 0.1}},
        {"joint": 2, "motion": {"type": "hold"}}]),
     ["inputs[1].joint", "got 2", "expected one input per joint"]),
    ("torque-and-motion", _set(("inputs", 0, "motion"), {"type": "hold"}),
     ["inputs[0]", "got torque, motion of torque/voltage/current/motion", "expected exactly one"]),
    ("neither-torque-nor-motion", _drop(TORQUE),
     ["inputs[0]", "got none of", "expected exactly one"]),
    ("motion-on-flexible-joint", lambda d: (
        d["links"][0].__setitem__("joint", {"flexibility": {"stiffness": 10.0,
                                                            "motor_inertia": 0.01}}),
        d.__setitem__("inputs", [{"joint": 1, "motion": {"type": "hold"}}])),
     ["inputs[0].motion", "flexible joint 1", "expected a torque program"]),
    # piecewise programs
    ("piecewise-descending", _set(TORQUE, {"type": "piecewise_constant",
                                           "times": [0.0, 2.0, 1.0], "values": [1, 2, 3]}),
     ["inputs[0].torque.times", "got [0.0, 2.0, 1.0]", "expected strictly ascending"]),
    ("piecewise-repeated", _set(TORQUE, {"type": "piecewise_linear",
                                         "times": [0.0, 1.0, 1.0], "values": [1, 2, 3]}),
     ["inputs[0].torque.times", "got [0.0, 1.0, 1.0]", "strictly ascending"]),
    ("piecewise-length-mismatch", _set(TORQUE, {"type": "piecewise_linear",
                                                "times": [0.0, 1.0], "values": [1.0]}),
     ["inputs[0].torque.times", "got 2 times and 1 values", "equal non-zero lengths"]),
    # other cross-field checks
    ("duplicate-link-names", _set(("links", 1, "name"), "l1"),
     ["links", "got names ['l1', 'l1']", "expected unique names"]),
    ("angle-in-both-units", _set(("links", 0, "joint"), {"initial_angle": 0.1,
                                                         "initial_angle_deg": 5.0}),
     ["links[0].joint.initial_angle_deg", "got 5.0", "only one of"]),
]


@pytest.mark.parametrize("mutate, fragments", [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_bad_scene_message_names_path_value_and_expectation(mutate, fragments):
    data = copy.deepcopy(BASE)
    mutate(data)
    with pytest.raises(SceneError) as info:
        load_scene_dict(data)
    msg = str(info.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    # the message starts with the key path (no other location prefix)
    assert msg.startswith(fragments[0]), msg


@pytest.mark.parametrize("data, fragments", [
    ([1, 2], ["scene", "got [1, 2]", "expected a mapping of Scene fields"]),
    (None, ["scene", "got None", "expected a mapping"]),
    ("links: []", ["scene", "got 'links: []'", "expected a mapping"]),
], ids=["list", "none", "string"])
def test_scene_that_is_not_a_mapping(data, fragments):
    with pytest.raises(SceneError) as info:
        load_scene_dict(data)
    for frag in fragments:
        assert frag in str(info.value)


def test_yaml_file_error_names_the_file_and_the_key(tmp_path):
    from flexarm_ros.scene import load_scene
    p = tmp_path / "bad.yaml"
    p.write_text("name: bad\nlinks:\n  - name: l1\n    beam: {length: 1.0, EI: -3, "
                 "mass_per_length: 0.5}\n")
    with pytest.raises(SceneError) as info:
        load_scene(p)
    msg = str(info.value)
    assert msg.startswith("bad.yaml: links[0].beam.EI: got -3")
    assert "expected a finite number > 0" in msg


def test_fidelity_override_is_validated_like_the_file():
    scene = load_scene_dict(copy.deepcopy(BASE))
    with pytest.raises(SceneError) as info:
        scene.with_fidelity(rung="spline")
    assert "fidelity.rung: got 'spline', expected one of" in str(info.value)
    with pytest.raises(SceneError) as info:
        scene.with_fidelity(dt=-1e-3)
    assert "fidelity.dt: got -0.001, expected a finite number >= 0" in str(info.value)


def _numeric_keys(data, path=""):
    """The key paths of every number in a scene mapping."""
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _numeric_keys(v, f"{path}.{k}" if path else k)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from _numeric_keys(v, f"{path}[{i}]")
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        yield path


@pytest.mark.parametrize("name", sorted(p.stem for p in
                                        (Path(__file__).parent.parent / "config").glob("*.yaml")))
def test_every_number_of_a_shipped_scene_at_1e300_is_refused_naming_its_key(name):
    """1e300 in any numeric key of any shipped scene: refused as the scene loads, one
    line naming that key — never an OverflowError or a matrix of infinities later."""
    from flexarm_ros.scene.keys import scene_mapping, set_keys
    sc = load_scene(name)
    keys = list(_numeric_keys(scene_mapping(sc)))
    assert len(keys) > 20
    for key in keys:
        with pytest.raises(SceneError) as exc:
            set_keys(sc, {key: 1e300})
        msg = str(exc.value)
        assert "\n" not in msg and (key in msg or key.split("[")[0] in msg), (key, msg)
