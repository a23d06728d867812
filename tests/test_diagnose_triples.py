"""Three effects (issue 16): two structural effects and a sensor fault are named together
when the pair search grows its best pairs by one more member (``sets.grow_sets``), each
member needed beside the *pair* of the other two; a third member that adds nothing is
not named."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import EFFECTS, Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location, augmented,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.scoring import judge, validation_gap
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN, corrected
from siva_core._impl.diagnose.sets import choose_set
from siva_core._impl.diagnose.where import spectral_noise_floor

TWO = {"name": "two", "dofs": ["x", "y"], "mass": {"x": 1.0, "y": 0.5},
       "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k1"}},
                    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c1"}},
                    {"kind": "spring", "between": ["x", "y"], "params": {"k": "k2"}},
                    {"kind": "damper", "between": ["x", "y"], "params": {"c": "c2"}}]}
NOMINAL = {"k1": 6000.0, "c1": 1.0, "k2": 3000.0, "c2": 0.5}
G = Location(0, -1, ("x", "ground"))
XY = Location(0, 1, ("x", "y"))
K3, FC, GAIN = 2.0e7, 0.6, 1.15


def _single(st: Structure, kind: str, loc: Location, value: float, train, val, proc, gap,
            blocks) -> Candidate:
    """A structural single as a stage would have fitted it (here: at its true size)."""
    eff = EFFECTS[kind]
    aug, names = augmented(st, eff, loc, {eff.magnitude: abs(value)})
    c = Candidate(eff, loc, {}, fitted=True, structure=aug, names=names,
                  theta=aug.vector({**NOMINAL, names[eff.magnitude]: value}))
    c.coefficients = {eff.magnitude: value}
    c.train_cost = 0.0
    judge(c, val, proc, gap, blocks)
    return c


@pytest.fixture(scope="module")
def triple_case():
    st = Structure.from_dict(TWO)
    gen = with_effect(with_effect(st, "cubic_spring", ("x", "ground"), {"k3": K3}),
                      "coulomb", ("x", "y"), {"fc": FC})
    theta = gen.vector(NOMINAL)
    # the accelerometer on x reads GAIN x the truth (corrected() divides: 1/GAIN makes it)
    train = corrected(synthetic_impacts(gen, theta, [60.0, 150.0], dof="y", fs=1024.0,
                                        duration=2.0, seed=1), ACC_GAIN, "acc_x", 1 / GAIN)
    val = corrected(synthetic_impacts(gen, theta, [30.0, 200.0], dof="y", fs=1024.0,
                                      duration=2.0, seed=2), ACC_GAIN, "acc_x", 1 / GAIN)
    proc = Processing.none()
    gap, blocks = validation_gap(st, st.vector(NOMINAL), val, proc)
    noise = spectral_noise_floor(st, val, proc, st.vector(NOMINAL))
    a = _single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks)
    b = _single(st, "coulomb", XY, FC, train, val, proc, gap, blocks)
    s = Candidate(ACC_GAIN, Location(0, -1, ("acc_x", "sensor")), {}, fitted=True,
                  structure=st, theta=st.vector(NOMINAL))
    s.coefficients, s.train_cost = {"gain": GAIN}, 0.0
    judge(s, val, proc, gap, blocks)
    return st, train, val, proc, gap, blocks, noise, [a, b, s]


@pytest.mark.slow
def test_two_structural_effects_and_a_sensor_fault_named_together(triple_case):
    st, train, val, proc, gap, blocks, noise, singles = triple_case
    assert max(c.closure for c in singles) < 0.95  # no single effect explains it
    settings = DiagnoseSettings(fit_nfev=20)
    ranking = sorted(singles, key=lambda c: -c.closure)
    verdict, named, rule = choose_set(None, [], ranking, st, train, val, proc, gap, blocks,
                                      noise, settings)
    assert sorted(m.label() for m in named) == ["accelerometer_gain acc_x",
                                                "coulomb x-y", "cubic_spring x-ground"]
    gain = next(m for m in named if m.category == "sensor").coefficients["gain"]
    assert gain == pytest.approx(GAIN, rel=0.02)
    assert rule["sets"][-1]["set"].count("+") == 2 and rule["combined_closure"] > 0.99
    # pairs only (set_beam 0): the fault is left unnamed, whatever pair is named
    _, two, rule2 = choose_set(None, [], ranking, st, train, val, proc, gap, blocks, noise,
                               DiagnoseSettings(fit_nfev=20, set_beam=0))
    assert len(two) <= 2 and all("+ " not in t["set"] or t["set"].count("+") == 1
                                 for t in rule2["sets"])


@pytest.mark.slow
def test_a_third_member_that_adds_nothing_is_not_named(triple_case):
    """The same structural pair on records *without* the fault: a gain grown onto it
    changes nothing, the pair is named alone."""
    st, _, _, proc, _, _, _, _ = triple_case
    gen = with_effect(with_effect(st, "cubic_spring", ("x", "ground"), {"k3": K3}),
                      "coulomb", ("x", "y"), {"fc": FC})
    theta = gen.vector(NOMINAL)
    train = synthetic_impacts(gen, theta, [60.0, 150.0], dof="y", fs=1024.0, duration=2.0,
                              seed=1)
    val = synthetic_impacts(gen, theta, [30.0, 200.0], dof="y", fs=1024.0, duration=2.0,
                            seed=2)
    gap, blocks = validation_gap(st, st.vector(NOMINAL), val, proc)
    noise = spectral_noise_floor(st, val, proc, st.vector(NOMINAL))
    a = _single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks)
    b = _single(st, "coulomb", XY, FC, train, val, proc, gap, blocks)
    s = Candidate(ACC_GAIN, Location(0, -1, ("acc_x", "sensor")), {}, fitted=True,
                  structure=st, theta=st.vector(NOMINAL))
    s.coefficients, s.train_cost = {"gain": 1.03}, 0.0
    judge(s, val, proc, gap, blocks)
    ranking = sorted([a, b, s], key=lambda c: -c.closure if np.isfinite(c.closure) else 9)
    _, named, _ = choose_set(None, [], ranking, st, train, val, proc, gap, blocks, noise,
                             DiagnoseSettings(fit_nfev=20))
    assert sorted(m.label() for m in named) == ["coulomb x-y", "cubic_spring x-ground"]
