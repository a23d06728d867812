"""Sets of effects (issue 16): a joint pair fit explains what neither effect explains
alone, the set rule prefers it only when both members are needed, an element fitted to
nothing does not show above the noise; and the scenario generator is seeded and draws
what its doc says."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from siva_core import EFFECTS, Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location, augmented,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.scoring import judge, validation_gap
from siva_core._impl.diagnose.sets import better, contributions, fit_pair
from siva_core._impl.diagnose.where import spectral_noise_floor
from siva_core._impl.diagnose.verdict import look_alike

ROOT = Path(__file__).resolve().parents[1]

TWO = {"name": "two", "dofs": ["x", "y"], "mass": {"x": 1.0, "y": 0.5},
       "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k1"}},
                    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c1"}},
                    {"kind": "spring", "between": ["x", "y"], "params": {"k": "k2"}},
                    {"kind": "damper", "between": ["x", "y"], "params": {"c": "c2"}}]}
NOMINAL = {"k1": 6000.0, "c1": 1.0, "k2": 3000.0, "c2": 0.5}
G = Location(0, -1, ("x", "ground"))
XY = Location(0, 1, ("x", "y"))
K3, FC = 2.0e7, 0.6


def _single(st: Structure, kind: str, loc: Location, value: float, train, val, proc, gap,
            blocks) -> Candidate:
    eff = EFFECTS[kind]
    aug, names = augmented(st, eff, loc, {eff.magnitude: abs(value)})
    c = Candidate(eff, loc, {}, fitted=True, structure=aug, names=names,
                  theta=aug.vector({**NOMINAL, names[eff.magnitude]: value}))
    c.coefficients = {eff.magnitude: value}
    judge(c, val, proc, gap, blocks)
    return c


@pytest.fixture(scope="module")
def pair_case():
    st = Structure.from_dict(TWO)
    gen = with_effect(with_effect(st, "cubic_spring", ("x", "ground"), {"k3": K3}),
                      "coulomb", ("x", "y"), {"fc": FC})
    theta = gen.vector(NOMINAL)
    train = synthetic_impacts(gen, theta, [60.0, 150.0], dof="y", fs=1024.0, duration=2.0,
                              seed=1)
    val = synthetic_impacts(gen, theta, [30.0, 200.0], dof="y", fs=1024.0, duration=2.0,
                            seed=2)
    proc = Processing.none()
    gap, blocks = validation_gap(st, st.vector(NOMINAL), val, proc)
    noise = spectral_noise_floor(st, val, proc, st.vector(NOMINAL))
    return st, train, val, proc, gap, blocks, noise


@pytest.mark.slow
def test_joint_pair_explains_what_neither_single_does(pair_case):
    st, train, val, proc, gap, blocks, noise = pair_case
    settings = DiagnoseSettings()
    a = _single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks)
    b = _single(st, "coulomb", XY, FC, train, val, proc, gap, blocks)
    assert a.closure < 0.95 and b.closure < 0.95  # each is only a part
    pair = fit_pair(a, b, st, train, val, proc, gap, blocks, settings)
    assert pair is not None and pair.closure > 0.95
    assert better(pair, a.gap_after, noise, settings) and better(pair, b.gap_after, noise,
                                                                  settings)
    assert [m.label() for m in pair.members] == [a.label(), b.label()]
    contrib = contributions(pair, val, proc)
    assert len(contrib) == 2 and min(contrib) > settings.contribution_noise * noise


@pytest.mark.slow
def test_element_fitted_to_nothing_does_not_show_above_noise(pair_case):
    st, train, val, proc, gap, blocks, noise = pair_case
    tiny = _single(st, "cubic_spring", G, K3 * 1e-4, train, val,
                   proc, gap, blocks)
    (x,) = contributions(tiny, val, proc)
    assert x < DiagnoseSettings().contribution_noise * noise


def test_look_alike_groups():
    assert look_alike("quadratic_damper", "coulomb") and look_alike("cubic_spring", "clearance")
    assert look_alike("damper", "cubic_damper")
    assert not look_alike("coulomb", "cubic_spring") and not look_alike("quadratic_spring",
                                                                         "spring")


def test_scenarios_are_seeded_and_within_their_ranges():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios

    a, b = scenarios.draw(7), scenarios.draw(7)
    assert scenarios.describe(a) == scenarios.describe(b)
    assert np.array_equal(a.val[0].channels[next(iter(a.val[0].channels))],
                          b.val[0].channels[next(iter(b.val[0].channels))])
    for s in (a, scenarios.draw(8), scenarios.draw(9)):  # 9: two effects diverging together
        assert 1 <= s.info["dofs"] <= 4
        assert len(s.train) == 2 and 1 <= len(s.val) <= 2
        assert len(s.effects) <= 2 and all(v >= 1.0 for v in s.visibility)
        assert s.info["fs"] >= 5 * max(s.info["modes_hz"]) - 1
        assert len(s.train[0].time) <= 8192
        assert s.category in ("null", "single", "two", "three")
