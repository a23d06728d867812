"""Nothing unphysical is recommended (issue 17, findings 1 and 2): bounds from the element
kinds (damping and stiffness >= 0 unless the spec allows otherwise), candidates moved inside
before Approach III and the refinement, and the verdict that says what the fit is worth."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from siva_core import Processing, Structure, recommend_best
from siva_core._impl.assessment import assess
from siva_core._impl.ensemble import Ensemble
from siva_core._impl.siva import physical_candidates

ROOT = Path(__file__).resolve().parents[1]


def test_bounds_come_from_the_element_kinds_and_the_spec():
    st = Structure.from_file(ROOT / "examples/models/lono.toml")
    lo, hi = st.physical_bounds()
    bounds = dict(zip(st.free, lo))
    assert bounds["b1"] == bounds["b2"] == bounds["k1"] == bounds["k2"] == 0.0
    assert bounds["alpha"] == -np.inf and bounds["beta"] == -np.inf  # softening allowed
    spec = dict(st.spec)
    spec["parameters"] = {**spec.get("parameters", {}), "k2": {"lower": -500.0}}
    lo2, _ = Structure.from_dict(spec).physical_bounds()
    assert dict(zip(st.free, lo2))["k2"] == -500.0  # the spec allows a negative stiffness
    assert np.all(np.isinf(hi))


def test_candidates_are_reflected_inside():
    lo, hi = np.array([0.0, -np.inf]), np.array([np.inf, np.inf])
    moved = physical_candidates(np.array([[-0.9, -3.0], [0.5, 2.0], [0.0, 1.0]]), lo, hi,
                                ["b", "a"])
    c = moved.candidates
    assert moved.names == ["b"]
    assert c[0, 0] == pytest.approx(0.9) and c[1, 0] == 0.5 and c[2, 0] > 0
    assert c[0, 1] == -3.0  # unbounded parameters are left alone


def test_negative_damping_is_never_recommended(make_sdof, sdof_model):
    rec, truth = make_sdof(noise=0.002, seed=3)
    k, c = truth["k"], truth["c"]
    names = sdof_model.free
    cand = np.array([[k if p == "k" else -c for p in names],
                     [1.02 * k if p == "k" else -0.5 * c for p in names]])
    rec_best = recommend_best(sdof_model, cand, [rec], Processing())
    best = dict(zip(names, rec_best.theta))
    assert best["c"] > 0 and best["k"] > 0
    assert best["c"] == pytest.approx(c, rel=0.05)
    assert "outside the physical bounds" in (rec_best.note or "")


def test_a_candidate_that_diverges_everywhere_is_not_refined(make_sdof, sdof_model, monkeypatch):
    """Approach II's mean of a runaway softening spring (a 3-DOF chain, fresh seed) crashed
    ``siva identify`` in the second refinement: every candidate diverging now leaves best
    unrefined, with the reason, instead of raising."""
    import siva_core._impl.refine as refine_mod

    rec, truth = make_sdof(noise=0.002, seed=3)
    cand = np.array([[truth[p] for p in sdof_model.free]])
    monkeypatch.setattr(refine_mod, "displacement_mse",
                        lambda st, c, *a, **k: np.full(len(c), np.inf))
    out = recommend_best(sdof_model, cand, [rec], Processing())
    assert not out.refined and out.std is None
    assert "diverges" in (out.note or "")


def test_a_diverged_epoch_leaves_the_ensemble():
    ens = Ensemble()
    ens.add(np.array([1.0, 2.0]), 1)
    ens.add(np.array([np.nan, 2.0]), 2)
    ens.add(np.array([1.1, 2.1]), 3)
    ens.drop_nonfinite()
    assert len(ens) == 2 and np.all(np.isfinite(ens.samples))


def _result(best, std, test):
    st = Structure.from_file(ROOT / "examples/models/lono.toml")
    return SimpleNamespace(structure=st, best=np.asarray(best, float),
                           best_std=None if std is None else np.asarray(std, float),
                           metrics={"validation_test": {"best": test}})


def test_assessment_states_rejection_and_what_to_try():
    theta = [3.8, 19000.0, 0.8, 1950.0, 2.7e7, 2.0]
    a = assess(_result(theta, [0.01, 5, 0.01, 2, 1e5, 0.01],
                       {"statistic": 6.8, "accepted": False, "records": {"x.csv": {
                           "statistic": 6.8}}}), model="m.toml", train="x.csv")
    assert a.status == "rejected" and not a.usable
    assert "REJECTED" in a.headline and "6.8" in a.headline
    assert any(s.startswith("siva diagnose m.toml --train x.csv") for s in a.next_steps)
    ok = assess(_result(theta, None, {"statistic": 1.1, "accepted": True}))
    assert ok.usable and "ACCEPTED" in ok.headline


def test_assessment_names_unphysical_and_undetermined_values():
    a = assess(_result([3.8, 19000.0, -0.88, 1950.0, 2.7e7, 2.0],
                       [0.01, 5, 0.01, 2, 2e7, 0.01], {"statistic": 1.0, "accepted": True}))
    assert a.unphysical == ["b2"] and not a.usable
    assert a.undetermined == ["alpha"]
    assert any("alpha is not determined" in d for d in a.details)
