"""Nested laws (issue 16, branch lookalike3): a clearance holds a linear spring (gap 0),
so a clearance is named only when it beats the spring at its place on the validation
records by the set test's statistic; a missing spring named as a clearance with a small
gap (fresh seeds 17578, 17549) is named as the spring, a real clearance stays."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import EFFECTS
from siva_core._impl.diagnose import DiagnoseSettings, augmented
from siva_core._impl.diagnose.nested import prefer_simpler, simpler_law
from siva_core._impl.diagnose.results import Candidate
from siva_core._impl.diagnose.scoring import judge
from siva_core._impl.diagnose.set_fit import _refit
from test_diagnose_sets import NOMINAL, G, two_dof_records


def test_the_nested_law_is_found_in_the_registry():
    assert simpler_law("clearance") == ("spring", (("gap", 0.0),))
    assert all(simpler_law(k) is None for k in ("spring", "cubic_spring", "damper",
                                                "coulomb", "quadratic_damper"))


def _fit(st, kind, start, train, val, proc, gap, blocks):
    eff = EFFECTS[kind]
    aug, names = augmented(st, eff, G, {c: abs(x) for c, x in start.items()})
    th0 = aug.vector({**NOMINAL, **{names[c]: x for c, x in start.items()}})
    theta, cost, _ = _refit(aug, [th0], train, proc, 15)
    vals = aug.as_dict(theta)
    c = Candidate(eff, G, {}, fitted=True, structure=aug, names=names, theta=theta,
                  train_cost=cost, coefficients={k: vals[p] for k, p in names.items()},
                  parameters={p: vals[p] for p in st.free})
    judge(c, val, proc, gap, blocks)
    return c


def _named(truth, start_gap):
    st, train, val, proc, gap, blocks = two_dof_records([truth], 1.0, (3, 4))
    clearance = _fit(st, "clearance", {"k": 1500.0, "gap": start_gap}, train, val, proc,
                     gap, blocks)
    spring = _fit(st, "spring", {"k": 1500.0}, train, val, proc, gap, blocks)
    rule: dict = {}
    v, vs = prefer_simpler(clearance, [clearance], [clearance, spring], st, train, val,
                           proc, gap, blocks, 1e-3 * gap, 1e-3 * gap, DiagnoseSettings(),
                           rule)
    return clearance, spring, v, vs, rule


@pytest.mark.parametrize("true_gap", [None, 2e-3])
def test_a_clearance_is_named_only_when_it_beats_the_spring(true_gap):
    truth = ("spring", ("x", "ground"), {"k": 1500.0}) if true_gap is None else \
        ("clearance", ("x", "ground"), {"k": 1500.0, "gap": true_gap})
    clearance, spring, v, vs, rule = _named(truth, 1e-4 if true_gap is None else 1.5e-3)
    assert rule["nested"]["simpler"] == "spring x-ground"
    if true_gap is None:  # the spring's own law: the clearance does not beat it
        assert v is spring and vs == [spring]
        assert rule["nested"]["z"] < 3.0
        assert [r["candidate"] for r in v.rivals] == ["clearance x-ground"]
    else:  # a real gap: the clearance beats the spring by many standard errors
        assert v is clearance and vs == [clearance]
        assert rule["nested"]["z"] >= 3.0
        assert clearance.coefficients["gap"] == pytest.approx(true_gap, rel=0.2)
