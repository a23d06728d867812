"""A named member's own contribution is measured against the best fit known without it
(``without_member``): a right element whose fit re-tunes the nominal parameters shows
although zeroing it alone changes the small validation records little; an element that
only rides on a better-tuned nominal model still does not show."""
from __future__ import annotations

import numpy as np

from siva_core import EFFECTS, Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location, augmented,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.set_members import contributions, floor_for, shown
from siva_core._impl.diagnose.where import spectral_noise_floor
from siva_core._impl.diagnose.without_member import KnownFits

SDOF = {"name": "one", "dofs": ["x"], "mass": {"x": 1.0},
        "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k1"}},
                     {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c1"}}]}
TRUE = {"k1": 4000.0, "c1": 1.0}
G = Location(0, -1, ("x", "ground"))
C3 = 3.0e4    # cubic damper: strong on the large train hits, negligible on the small val hits


def _records(effect: bool):
    st = Structure.from_dict(SDOF)
    gen = with_effect(st, "cubic_damper", ("x", "ground"), {"c3": C3}) if effect else st
    theta = gen.vector(TRUE)
    train = synthetic_impacts(gen, theta, [20.0, 400.0], dof="x", fs=1024.0, duration=2.0,
                              seed=1)
    val = synthetic_impacts(gen, theta, [15.0], dof="x", fs=1024.0, duration=2.0, seed=2)
    return st, train, val, Processing.none()


def _cubic(st: Structure, c1: float, c3: float, val, proc) -> Candidate:
    eff = EFFECTS["cubic_damper"]
    aug, names = augmented(st, eff, G, {eff.magnitude: max(abs(c3), 1.0)})
    return Candidate(eff, G, {}, fitted=True, structure=aug, names=names,
                     theta=aug.vector({**TRUE, "c1": c1, names[eff.magnitude]: c3}))


def _best_c1(st: Structure, train, proc) -> float:
    """The nominal refit's linear damping (a scan: the only parameter that moves)."""
    known = KnownFits(st, st.vector(TRUE), train, train, proc)
    grid = np.geomspace(0.5, 60.0, 40)
    costs = [known.train_cost(st, st.vector({**TRUE, "c1": c}), train) for c in grid]
    return float(grid[int(np.argmin(costs))])


def test_a_right_element_that_retunes_the_nominal_shows():
    st, train, val, proc = _records(effect=True)
    noise = spectral_noise_floor(st, val, proc, st.vector(TRUE))
    c1 = _best_c1(st, train, proc)
    assert c1 > 1.5  # the nominal refit takes the large hit's damping into c1
    right = _cubic(st, TRUE["c1"], C3, val, proc)
    need = DiagnoseSettings().contribution_noise * noise
    (held,) = contributions(right, val, proc)
    assert held < need  # zeroed with c1 held: the small validation hit barely changes
    known = KnownFits(st, st.vector({**TRUE, "c1": c1}), train, val, proc)
    (x,) = contributions(right, val, proc, known)
    assert x > need  # against the nominal refit (the better fit without it): it shows


def test_an_element_riding_on_a_better_tuned_nominal_does_not_show():
    st, train, val, proc = _records(effect=False)
    noise = spectral_noise_floor(st, val, proc, st.vector(TRUE))
    poor = st.vector({**TRUE, "c1": 6.0})  # a nominal fit stopped away from the optimum
    tiny = _cubic(st, TRUE["c1"], 1e-3, val, proc)  # the element adds nothing; c1 re-tuned
    known = KnownFits(st, poor, train, val, proc)
    (x,) = contributions(tiny, val, proc, known)
    assert x < DiagnoseSettings().contribution_noise * noise


def test_the_floor_is_capped_by_what_the_fit_leaves_on_the_validation_records():
    st, train, val, proc = _records(effect=True)
    right = _cubic(st, TRUE["c1"], C3, val, proc)
    right.gap_after = 1e-4
    assert floor_for(right, 4e-4) == 1e-4 and floor_for(right, 5e-5) == 5e-5
    assert floor_for(right, None) is None
    # a contribution of 3e-4: below 2 x a spectral floor of 4e-4, above 2 x the 1e-4 the
    # fit leaves (chain3:quadratic_spring:m1-ground:large, measured)
    ok, _ = shown(right, [3e-4], val, proc, 4e-4, DiagnoseSettings())
    assert ok == [True]
    right.gap_after = 5e-4
    ok, _ = shown(right, [3e-4], val, proc, 4e-4, DiagnoseSettings())
    assert ok == [False]
