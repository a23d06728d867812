"""Ties on the validation records broken on all records (branch place): a single verdict
naming the right law at a wrong place (chain3 matrix: quadratic damper m3-ground named for
m2-ground, both gaps below the noise floor) is replaced by the contender of as many
coefficients that fits train + validation records best; a contender outside the noise
margin is not refitted."""
from __future__ import annotations

import pytest

from siva_core._impl.diagnose import DiagnoseSettings
from siva_core._impl.diagnose.results import Location
from siva_core._impl.diagnose.ties import break_tie, contenders
from test_diagnose_search import C2, G, XY, _fitted
from test_diagnose_sets import two_dof_records

YG = Location(1, -1, ("y", "ground"))


@pytest.fixture(scope="module")
def places():
    st, train, val, proc, gap, blocks = two_dof_records(
        [("quadratic_damper", ("x", "ground"), {"c2": C2})], 1.5, (5, 6))
    fits = [_fitted(st, "quadratic_damper", loc, v, train, val, proc, gap, blocks, nfev=10)
            for loc, v in ((G, 0.5 * C2), (XY, C2), (YG, C2))]
    return train, val, proc, gap, fits


def test_a_wrong_place_within_the_noise_gives_way_to_the_right_one(places):
    train, val, proc, gap, (right, xy, yg) = places
    s = DiagnoseSettings()
    # the wrong places leave 0.05-0.06 of a gap 1.23, the right one 0.0009
    assert xy.gap_after > 20 * right.gap_after
    noise = 2.0 * yg.gap_after  # a floor above every difference: the data cannot tell
    assert {c.label() for c in contenders(xy, [xy, right, yg], noise, s)} == {
        right.label(), yg.label()}
    rule: dict = {}
    v, vs = break_tie(xy, [xy], [xy, right, yg], train, val, proc, gap, None, noise, s,
                      rule)
    assert v is right and vs == [right]
    assert rule["tie"]["named"] == {"from": xy.label(), "to": right.label()}
    assert "fits all records best" in rule["reason"]
    assert right.coefficients["c2"] == pytest.approx(C2, rel=0.05)


def test_no_contender_within_the_noise_leaves_the_verdict(places):
    train, val, proc, gap, (right, xy, yg) = places
    s = DiagnoseSettings()
    rule: dict = {}
    v, vs = break_tie(right, [right], [right, xy, yg], train, val, proc, gap, None,
                      1e-3 * right.gap_after, s, rule)
    assert v is right and "tie" not in rule
    # a set (two verdicts) is left to the set's own swaps
    v, vs = break_tie(xy, [xy, yg], [xy, right, yg], train, val, proc, gap, None, 1.0, s,
                      rule)
    assert v is xy and "tie" not in rule


def test_look_alikes_within_the_noise_of_the_leader_are_placed_too() -> None:
    """(branch place2) The lono matrix's cubic damper LO-NO, small: the linear damper
    NO-ground led, with quadratic and cubic dampers there within the noise floor; the
    linear damper had no other place, so the cubic damper LO-NO was never fitted."""
    from siva_core._impl.diagnose.results import Candidate
    from siva_core._impl.diagnose.ties import tied_look_alikes
    from siva_core import EFFECTS

    def fit(kind: str, loc: Location, gap: float, cost: float) -> Candidate:
        return Candidate(EFFECTS[kind], loc, {}, fitted=True, gap_after=gap,
                         train_cost=cost)

    lead = fit("damper", G, 0.00165, 1.99e-4)
    others = [lead, fit("quadratic_damper", G, 0.00182, 1.71e-4),
              fit("cubic_damper", G, 0.00331, 1.70e-4),
              fit("cubic_spring", G, 0.0017, 1.0e-4),       # not a look-alike
              fit("cubic_damper", XY, 0.0017, 1.0e-4)]      # not at the leader's place
    s = DiagnoseSettings()
    # the floor 0.0018 covers both differences: both kinds, the lower train cost first
    assert tied_look_alikes(others, lead, 0.0018, s) == ["cubic_damper", "quadratic_damper"]
    # a floor 0.001: the cubic damper (0.00166 worse) is separated from the leader
    assert tied_look_alikes(others, lead, 0.001, s) == ["quadratic_damper"]
    assert tied_look_alikes(others, lead, 0.0018, DiagnoseSettings(place_lookalikes=0)) == []


def test_look_alikes_skip_places_the_leaders_law_already_lost() -> None:
    """(branch speed5) A look-alike is fitted at another place only where the leader's own
    law, fitted there, is not separated from the leader beyond the tie margin: fresh
    seed 17480's quadratic damper m2-ground led at 0.0303 (floor 0.0085); the places
    where it left 0.04 stay, those where it left 0.07-0.085 are decided."""
    from siva_core._impl.diagnose.results import Candidate
    from siva_core._impl.diagnose.ties import undecided_places
    from siva_core import EFFECTS

    ZG = Location(2, -1, ("z", "ground"))

    def fit(kind: str, loc: Location, gap: float, cost: float,
            fitted: bool = True) -> Candidate:
        return Candidate(EFFECTS[kind], loc, {}, fitted=fitted, gap_after=gap,
                         train_cost=cost)

    lead = fit("quadratic_damper", G, 0.0303, 0.0164)
    near = fit("quadratic_damper", XY, 0.0396, 0.0171)   # within margin: kept
    far = fit("quadratic_damper", YG, 0.0725, 0.0261)    # separated: decided
    more = [fit("cubic_damper", XY, 0, 0, False), fit("cubic_damper", YG, 0, 0, False),
            fit("cubic_damper", ZG, 0, 0, False)]        # z-ground: never fitted, kept
    s = DiagnoseSettings()
    kept = undecided_places(more, [lead, near, far], lead, 0.0085, s)
    assert [c.loc.between for c in kept] == [XY.between, ZG.between]
    # a floor so large that every difference is within it: every place stays
    assert len(undecided_places(more, [lead, near, far], lead, 0.05, s)) == 3
    # a far place whose train fit rivals the leader's stays too
    rival = fit("quadratic_damper", YG, 0.0725, 0.0120)
    assert len(undecided_places(more, [lead, near, rival], lead, 0.0085, s)) == 3


def test_the_refits_together_give_what_one_after_the_other_gives(places):
    """Branch lonospeed: with two workers the refits on all records run together and the
    early stop is replayed in order; the comparison is the one of one worker."""
    train, val, proc, gap, (right, xy, yg) = places
    rules = []
    for workers in (1, 2):
        s = DiagnoseSettings(workers=workers)
        rule: dict = {}
        noise = 2.0 * yg.gap_after
        v, vs = break_tie(xy, [xy], [xy, right, yg], train, val, proc, gap, None, noise, s,
                          rule)
        rules.append((v.label(), [x.label() for x in vs],
                      {k: rule["tie"][k] for k in ("compared", "z")}))
    assert rules[0] == rules[1]
    assert len(rules[0][2]["compared"]) == 2 and rules[0][0] == right.label()


class _Traced:
    """A candidate whose refit is a fixed trace of (stage, last, iteration, cost)."""

    def __init__(self, name: str, trace: list, energy: float) -> None:
        self.name, self.trace, self.energy = name, trace, energy

    def label(self) -> str:
        return self.name


def test_a_refit_stopped_by_an_earlier_rival_is_dropped_on_any_worker_count(monkeypatch):
    """The stop rule replayed against the best refit *before* each one (not only the
    verdict's): c is stopped by b's low cost, as when they run one after the other."""
    from siva_core._impl.diagnose import ties

    def fake(c, records, proc, settings, best, seen=None):
        stop = ties.cannot_win(best, settings)
        for x in c.trace:
            if seen is not None:
                seen.append(x)
            elif stop is not None and stop(*x):
                return None
        return c, c.energy, None

    monkeypatch.setattr(ties, "_refit_all", fake)
    full = lambda cost: [(0, True, k, cost) for k in range(4)]  # noqa: E731
    cands = [_Traced("a", full(1.0), 1.0), _Traced("b", full(0.01), 0.01),
             _Traced("c", full(0.5), 0.5)]  # c: 50 x b's cost, 0.5 x a's
    got = {w: [f[0].name for f in ties._refit_each(cands, [], None,
                                                   DiagnoseSettings(workers=w))]
           for w in (1, 2)}
    assert got[1] == got[2] == ["a", "b"]
