"""Model specs: the examples load, and every bad spec gives a SpecError naming where."""
from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from siva_core import SpecError, Structure

BASE: dict[str, Any] = {
    "name": "two",
    "dofs": ["a", "b"],
    "mass": {"a": 1.0, "b": 2.0},
    "elements": [
        {"kind": "spring", "between": ["a", "ground"], "params": {"k": "k1"}},
        {"kind": "damper", "between": ["a", "ground"], "params": {"c": "c1"}},
        {"kind": "spring", "between": ["a", "b"], "params": {"k": "k2"}},
        {"kind": "power_spring", "between": ["a", "b"], "params": {"alpha": "al", "beta": "be"}},
    ],
    "parameters": {"be": {"scale": 1.0}},
}


def spec(**changes: Any) -> dict[str, Any]:
    out = copy.deepcopy(BASE)
    out.update(changes)
    return out


def refused(data: dict[str, Any], *parts: str) -> str:
    with pytest.raises(SpecError) as exc:
        Structure.from_dict(data)
    msg = str(exc.value)
    for p in parts:
        assert p in msg, f"{p!r} not in {msg!r}"
    return msg


# ------------------------------------------------------------------------- good specs
def test_examples_load(model_paths):
    models = {name: Structure.from_file(p) for name, p in model_paths.items()}
    assert models["duffing"].free == ["b", "b_nl", "k", "k_nl"]
    assert models["lono"].free == ["b1", "k1", "b2", "k2", "alpha", "beta"]
    assert models["lono"].linear_parameters() == ["b1", "k1", "b2", "k2", "alpha"]
    assert models["silverbox"].free == ["c", "k1", "k2", "k3", "g"]
    assert models["silverbox"].force_gains == {"y": "g"}
    assert models["lono"].parameters["beta"].scale == 1


def test_base_spec_is_valid():
    s = Structure.from_dict(BASE)
    assert s.free == ["k1", "c1", "k2", "al", "be"]
    assert s.masses.tolist() == [1.0, 2.0]


def test_shared_parameter_names_make_one_parameter():
    data = spec(elements=[
        {"kind": "spring", "between": ["a", "ground"], "params": {"k": "k"}},
        {"kind": "spring", "between": ["b", "ground"], "params": {"k": "k"}},
        {"kind": "damper", "between": ["a", "b"], "params": {"c": "c"}}], parameters={})
    s = Structure.from_dict(data)
    assert s.free == ["k", "c"]
    theta = np.array([100.0, 0.0])
    acc = s.accelerations(theta, np.array([[0.01, 0.02]]), np.zeros((1, 2)))
    np.testing.assert_allclose(acc, [[-1.0, -1.0]])  # both springs use the one k


def test_fixed_values_leave_the_free_vector():
    data = spec(parameters={"be": {"fixed": 2.0}, "k1": {"fixed": 1e4, "scale": 1e4}})
    s = Structure.from_dict(data)
    assert s.free == ["c1", "k2", "al"]
    assert s.full_values(np.array([1.0, 2.0, 3.0]))["be"] == 2.0
    assert s.parameters["k1"].fixed == 1e4


def test_literal_number_is_a_fixed_parameter():
    data = spec()
    data["elements"][0]["params"] = {"k": 5000}
    s = Structure.from_dict(data)
    assert "k1" not in s.parameters
    fixed = [p for p, info in s.parameters.items() if info.fixed == 5000.0]
    assert len(fixed) == 1 and fixed[0] not in s.free


def test_spec_files_toml_and_json(tmp_path: Path):
    toml = tmp_path / "m.toml"
    toml.write_text('name = "m"\ndofs = ["x"]\n[mass]\nx = 2.0\n[[elements]]\nkind = "spring"\n'
                    'between = ["x", "ground"]\nparams = { k = "k" }\n')
    js = tmp_path / "m.json"
    js.write_text(json.dumps({"name": "m", "dofs": ["x"], "mass": {"x": 2.0}, "elements": [
        {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}))
    a, b = Structure.from_file(toml), Structure.from_file(js)
    assert a.free == b.free == ["k"] and a.spec == b.spec


# ------------------------------------------------------------------------- bad specs
@pytest.mark.parametrize("mass,parts", [
    ({"a": -1.0, "b": 2.0}, ["mass.a", "positive", "-1.0"]),
    ({"a": 0, "b": 2.0}, ["mass.a", "positive"]),
    ({"a": 1.0}, ["mass.b", "missing"]),
    ({"a": 1.0, "b": "2"}, ["mass.b", "number"]),
    ({"a": 1.0, "b": 2.0, "c": 3.0}, ["mass.c", "not a DOF"]),
    ({"a": 1.0, "b": float("nan")}, ["mass.b", "finite"]),
    ([1.0, 2.0], ["'mass'"]),
])
def test_bad_mass(mass, parts):
    refused(spec(mass=mass), *parts)


@pytest.mark.parametrize("kind", ["magic_spring", ["spring"], None, 3])
def test_unknown_element_kind(kind):
    data = spec()
    data["elements"][2]["kind"] = kind
    refused(data, "elements[2].kind", "unknown element kind", "known:")


@pytest.mark.parametrize("between,parts", [
    (["a", "c"], ["elements[1].between", "'c'", "not a DOF"]),
    (["z", "ground"], ["elements[1].between", "'z'"]),
    (["ground", "a"], ["elements[1].between", "DOF first"]),
    (["a", "a"], ["elements[1].between", "itself"]),
    (["a"], ["elements[1].between", "two names"]),
    ("a-ground", ["elements[1].between"]),
])
def test_dangling_between(between, parts):
    data = spec()
    data["elements"][1]["between"] = between
    refused(data, *parts)


def test_missing_coefficient():
    data = spec()
    data["elements"][3]["params"] = {"alpha": "al"}
    refused(data, "elements[3].params", "needs coefficient 'beta'")


def test_unknown_coefficient():
    data = spec()
    data["elements"][1]["params"] = {"c": "c1", "k": "k9"}
    refused(data, "elements[1].params.k", "no coefficient 'k'")


@pytest.mark.parametrize("name", ["", "two words", 3.5j, ["k"], None])
def test_bad_parameter_name(name):
    data = spec()
    data["elements"][0]["params"] = {"k": name}
    refused(data, "elements[0].params.k")


def test_parameters_entry_not_used():
    refused(spec(parameters={"k_typo": {"scale": 1.0}}), "parameters.k_typo", "not used")


@pytest.mark.parametrize("setting,parts", [
    ({"fixed": "3e8"}, ["parameters.k2.fixed", "number"]),
    ({"fixed": True}, ["parameters.k2.fixed", "number"]),
    ({"scale": -1.0}, ["parameters.k2.scale", "positive"]),
    ({"scale": 0}, ["parameters.k2.scale", "positive"]),
    ({"lower": 5.0, "upper": 1.0}, ["parameters.k2", "lower"]),
    ({"fixed": 10.0, "upper": 1.0}, ["parameters.k2.fixed", "outside"]),
    ({"fixd": 1.0}, ["parameters.k2", "unknown setting", "fixd"]),
    (3.0, ["parameters.k2", "table"]),
])
def test_bad_parameter_settings(setting, parts):
    refused(spec(parameters={"k2": setting}), *parts)


@pytest.mark.parametrize("forces,parts", [
    ({"c": {"gain": 1.0}}, ["forces.c", "not a DOF"]),
    ({"b": {"gian": "g"}}, ["forces.b.gian", "unknown key"]),
    ({"b": {"gain": "two words"}}, ["forces.b.gain"]),
    ({"b": {"gain": [1]}}, ["forces.b.gain", "number"]),
    ([1], ["'forces'"]),
])
def test_bad_forces(forces, parts):
    refused(spec(forces=forces), *parts)


def test_force_gain_parameter_is_identified():
    s = Structure.from_dict(spec(forces={"b": {"gain": "g"}}))
    assert s.free[-1] == "g" and s.force_gains == {"b": "g"}


@pytest.mark.parametrize("dofs,parts", [
    ([], ["'dofs'"]),
    (["a", "a"], ["'dofs'", "duplicate"]),
    (["a", "ground"], ["'dofs'", "reserved"]),
    (["a", "b c"], ["'dofs'", "'b c'"]),
    ("ab", ["'dofs'"]),
])
def test_bad_dofs(dofs, parts):
    refused(spec(dofs=dofs), *parts)


def test_unknown_keys_are_refused():
    refused(spec(element=[]), "element", "unknown top-level key")
    data = spec()
    data["elements"][0]["parms"] = {}
    refused(data, "elements[0].parms", "unknown key")


@pytest.mark.parametrize("elements,parts", [
    ([], ["'elements'", "non-empty"]),
    ({"kind": "spring"}, ["'elements'"]),
    ([3], ["elements[0]", "table"]),
])
def test_bad_elements(elements, parts):
    refused(spec(elements=elements), *parts)


def test_not_a_table():
    refused([1, 2], "object")


def test_file_errors_name_the_file(tmp_path: Path):
    bad_toml = tmp_path / "broken.toml"
    bad_toml.write_text('name = "m"\ndofs = ["x"\n')
    with pytest.raises(SpecError, match=r"broken\.toml: invalid TOML"):
        Structure.from_file(bad_toml)
    bad_json = tmp_path / "broken.json"
    bad_json.write_text('{"name": "m",\n "dofs": [}')
    with pytest.raises(SpecError, match=r"broken\.json: invalid JSON at line 2"):
        Structure.from_file(bad_json)
    neg = tmp_path / "neg.json"
    data = spec()
    data["mass"]["b"] = -2.0
    neg.write_text(json.dumps(data))
    with pytest.raises(SpecError, match=r"neg\.json: mass\.b: mass must be positive"):
        Structure.from_file(neg)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00\x01garbage")
    with pytest.raises(SpecError, match=r"bin\.toml: not UTF-8"):
        Structure.from_file(binary)
    with pytest.raises(SpecError, match=r"missing\.toml"):
        Structure.from_file(tmp_path / "missing.toml")
