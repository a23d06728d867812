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
