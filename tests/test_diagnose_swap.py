"""Look-alike laws inside a chosen set (issue 16, branch lookalike): a set named with a
wrong law for one member (fresh seed 17240: a cubic damper for a quadratic one, found in
a later stage, never compared with its look-alikes beside the other member) gets each
member's law swapped, the set re-fitted jointly from its own fit: the better law replaces
it (the lowest validation gap, as for a single verdict), a law within the noise of the
named set is listed as the member's rival."""
from __future__ import annotations

import pytest

from siva_core._impl.diagnose import DiagnoseSettings
from siva_core._impl.diagnose.pair_fit import fit_pair
from siva_core._impl.diagnose.swap import member_swaps, swap_rivals
from test_diagnose_search import C2, K3, G, XY, _fitted
from test_diagnose_sets import two_dof_records


@pytest.fixture(scope="module")
def wrong_law_set():
    st, train, val, proc, gap, blocks = two_dof_records(
        [("quadratic_damper", ("x", "ground"), {"c2": C2}),
         ("cubic_spring", ("x", "y"), {"k3": K3})], 1.5, (5, 6))
    s = DiagnoseSettings(fit_nfev=10, swap_places=0)  # law swaps only (places: place2)
    wrong = _fitted(st, "cubic_damper", G, 1.0e4, train, val, proc, gap, blocks, nfev=10)
    mate = _fitted(st, "cubic_spring", XY, K3, train, val, proc, gap, blocks)
    chosen = fit_pair(wrong, mate, st, train, val, proc, gap, blocks, s)
    swaps = member_swaps(chosen, st, train, val, proc, gap, blocks, s, [wrong, mate])
    return chosen, swaps


def test_a_wrong_law_in_the_chosen_set_is_swapped(wrong_law_set):
    chosen, swaps = wrong_law_set
    assert chosen is not None and chosen.members[0].effect.kind == "cubic_damper"
    # the damper member's look-alikes (2 of damper, quadratic damper, coulomb) and the
    # spring member's (2 of spring, clearance), each fitted with the other member
    kinds = {(k, s.members[k].effect.kind) for k, s in swaps}
    assert (0, "quadratic_damper") in kinds
    assert {k for k, _ in kinds} == {0, 1} and len(swaps) <= 4
    quad = next(s for k, s in swaps if s.members[k].effect.kind == "quadratic_damper")
    assert quad.gap_after < 0.5 * chosen.gap_after
    assert quad.members[0].coefficients["c2"] == pytest.approx(C2, rel=0.2)
    # the lowest gap is named; beyond a small noise floor the replaced law is no rival
    win, rivals = swap_rivals(chosen, swaps, 1e-3 * chosen.gap_after, DiagnoseSettings())
    assert win is quad
    assert all(r["candidate"] != "cubic_damper x-ground" for r in rivals[0])
    # within the noise (a floor above the difference): the replaced law is its rival
    win, rivals = swap_rivals(chosen, swaps, chosen.gap_after, DiagnoseSettings())
    assert win is quad
    assert "cubic_damper x-ground" in [r["candidate"] for r in rivals[0]]
    # a swap the set's checks refuse is not named; within the noise it is a rival
    win, rivals = swap_rivals(chosen, swaps, chosen.gap_after, DiagnoseSettings(),
                              lambda s: False)
    assert win is None
    assert "quadratic_damper x-ground" in [r["candidate"] for r in rivals[0]]
