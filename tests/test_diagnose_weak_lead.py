"""A weak lead (closing less than step_min of a gap many times the noise, yet removing a
real part of it) has its kind fitted at other places (branch lowclose); a lead on a gap
near the noise (a null) or removing about nothing does not."""
from __future__ import annotations

import math

from siva_core import EFFECTS
from siva_core._impl.diagnose import Candidate, DiagnoseSettings, Location
from siva_core._impl.diagnose.weak_lead import tentative_lead, weak_lead, weak_lead_places

PLACES = [Location(0, -1, ("m1", "ground")), Location(1, -1, ("m2", "ground")),
          Location(0, 1, ("m1", "m2"))]


def _cand(kind: str, loc: Location, score: float, gap_after: float = math.nan,
          gap_before: float = 0.15) -> Candidate:
    c = Candidate(EFFECTS[kind], loc, {}, score=score)
    c.gap_after = gap_after
    c.closure = 1.0 - gap_after / gap_before
    return c


def test_weak_lead_needs_a_real_part_of_a_gap_above_the_noise() -> None:
    s = DiagnoseSettings()
    lead = _cand("coulomb", PLACES[1], 0.4, gap_after=0.124)  # 17506's: closure 0.18
    assert weak_lead(lead, 0.1517, 0.0042, s)            # gap 36 x, removed 6.5 x
    assert not weak_lead(lead, 0.1517, None, s)           # no scale: no search
    assert not weak_lead(lead, 0.1517, 0.02, s)           # gap 7.6 x the floor only
    near = _cand("coulomb", PLACES[1], 0.4, gap_after=0.1455)
    assert not weak_lead(near, 0.1517, 0.0042, s)         # removes 1.5 x the floor
    strong = _cand("coulomb", PLACES[1], 0.4, gap_after=0.09)
    assert not weak_lead(strong, 0.1517, 0.0042, s)       # closes 0.41: the place check
    assert not weak_lead(lead, 0.1517, 0.0042, DiagnoseSettings(weak_places=0))


def test_weak_lead_places_are_the_kind_elsewhere_best_screened_first() -> None:
    s = DiagnoseSettings(weak_places=1)
    cands = [_cand("coulomb", PLACES[0], 0.38), _cand("coulomb", PLACES[1], 0.41),
             _cand("coulomb", PLACES[2], 0.39), _cand("spring", PLACES[0], 0.9)]
    lead = cands[1]
    assert [c.loc.between for c in weak_lead_places(cands, lead, [lead], s)] \
        == [("m1", "m2")]
    more = weak_lead_places(cands, lead, [lead], DiagnoseSettings())
    assert [c.loc.between for c in more] == [("m1", "m2"), ("m1", "ground")]
    assert all(c.effect.kind == "coulomb" for c in more)


def _fit(kind: str, loc: Location, gap_after: float, train_cost: float) -> Candidate:
    c = _cand(kind, loc, 0.1, gap_after=gap_after, gap_before=0.0995)
    c.fitted, c.train_cost = True, train_cost
    return c


def test_tentative_lead_breaks_a_validation_tie_by_train_cost() -> None:
    s = DiagnoseSettings()
    clearance = _fit("clearance", PLACES[2], 0.0790, 0.0789)   # 17485's numbers
    damper = _fit("cubic_damper", PLACES[0], 0.0811, 0.0228)
    assert tentative_lead([clearance, damper], 0.0020, s) is damper   # 1.1 x the floor apart
    assert tentative_lead([clearance, damper], 0.0010, s) is clearance  # 2.1 x: no tie
    assert tentative_lead([clearance, damper], None, s) is clearance
    # more coefficients than the leader: its lower train cost may be its freedom
    spring = _fit("spring", PLACES[0], 0.0795, 0.05)
    two = _fit("clearance", PLACES[1], 0.0800, 0.01)
    assert tentative_lead([spring, two], 0.0020, s) is spring
