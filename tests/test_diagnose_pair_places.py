"""Two laws at one place (issue 16, pair row lono damper + spring NO-ground): a set may
hold a dissipative and a restoring law at one place, never two of one role there; the
joint fit of such a pair explains what neither does alone; and the look-alike second lead
is paired with the later stage's best fits by train cost."""
from __future__ import annotations

import numpy as np

from siva_core import EFFECTS
from siva_core._impl.diagnose import Candidate, DiagnoseSettings, Location
from siva_core._impl.diagnose.grow import can_grow
from siva_core._impl.diagnose.pair_fit import fit_pair
from siva_core._impl.diagnose.sensor_faults import SENSOR_FAULTS
from siva_core._impl.diagnose.set_fit import SetFit
from siva_core._impl.diagnose.set_rules import can_pair
from siva_core._impl.diagnose.sets import _later_mates

from test_diagnose_sets import NOMINAL, _single, two_dof_records

YG = Location(1, -1, ("y", "ground"))
XG = Location(0, -1, ("x", "ground"))


def _c(kind: str, loc: Location, train_cost: float = 1.0) -> Candidate:
    c = Candidate(EFFECTS[kind] if kind in EFFECTS else SENSOR_FAULTS[kind], loc, {},
                  score=0.1)
    c.fitted, c.train_cost = True, train_cost
    return c


def test_one_place_holds_two_roles_never_one_role_twice() -> None:
    assert can_pair(_c("damper", YG), _c("spring", YG))
    assert can_pair(_c("coulomb", YG), _c("clearance", YG))
    assert not can_pair(_c("damper", YG), _c("cubic_damper", YG))
    assert not can_pair(_c("cubic_spring", YG), _c("clearance", YG))
    assert can_pair(_c("cubic_damper", YG), _c("cubic_damper", XG))
    assert can_pair(_c("accelerometer_gain", YG), _c("damper", YG))
    base = SetFit(EFFECTS["damper"], YG, {}, members=[_c("damper", YG), _c("spring", XG)])
    assert can_grow(base, _c("cubic_spring", YG))
    assert not can_grow(base, _c("quadratic_damper", YG))   # the damper's role there
    assert not can_grow(base, _c("clearance", XG))          # the spring's role there


def test_the_best_second_lead_meets_the_later_stages_fits() -> None:
    lead = _c("cubic_damper", YG, 1.8e-3)
    seconds = [_c("quadratic_damper", YG, 1.7e-3), _c("damper", YG, 1.3e-3)]
    refused = [_c("damper", YG, 4.5e-4),          # the second lead's own later fit
               _c("clearance", YG, 7.3e-4), _c("spring", YG, 7.7e-4),
               _c("cubic_spring", YG, 8.1e-4)]
    done: set[frozenset] = {frozenset((seconds[1].key, refused[1].key))}
    got = _later_mates(seconds, refused, lead, done, DiagnoseSettings())
    # the damper (lowest train cost) with the first two later fits of another law, bar
    # the one done
    assert [(a.label(), b.label()) for a, b in got] == [("damper y-ground", "spring y-ground")]
    assert frozenset((seconds[1].key, refused[2].key)) in done
    assert _later_mates([], refused, lead, set(), DiagnoseSettings()) == []


def test_a_damper_and_a_spring_at_one_place_are_fitted_as_a_pair() -> None:
    c, k = 1.5, 900.0
    st, train, val, proc, gap, blocks = two_dof_records(
        [("damper", ("y", "ground"), {"c": c}), ("spring", ("y", "ground"), {"k": k})],
        1.5, (3, 4))
    a = _single(st, "damper", YG, c, train, val, proc, gap, blocks)
    b = _single(st, "spring", YG, k, train, val, proc, gap, blocks)
    assert a.closure < 0.9 and b.closure < 0.9   # each is only a part
    pair = fit_pair(a, b, st, train, val, proc, gap, blocks, DiagnoseSettings())
    assert pair is not None and pair.closure > 0.99
    got = {p: v for p, v in pair.structure.as_dict(pair.theta).items() if p not in NOMINAL}
    assert np.allclose(sorted(got.values()), sorted([c, k]), rtol=0.02), got
