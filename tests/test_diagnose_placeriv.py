"""Places on 3-4 DOF structures (issue 16, branch placeriv): a set refused only because
a member does not show is re-fitted without it (``pruned``); a law that won its swap is
moved too (``swap_moves``); a named member never reports closure None (fresh seed 17676:
damper m2-ground named with closure None beside the refused set that held the right
damper m3-ground)."""
from __future__ import annotations

import math

import pytest

from siva_core._impl.diagnose import DiagnoseSettings
from siva_core import EFFECTS
from siva_core._impl.diagnose.grow import grow
from siva_core._impl.diagnose.pair_fit import fit_pair
from siva_core._impl.diagnose.pruned import without_members
from siva_core._impl.diagnose.results import Candidate, Location
from siva_core._impl.diagnose.set_fit import SetFit
from siva_core._impl.diagnose.set_members import fill_closures
from siva_core._impl.diagnose.swap_moves import swapped_members
from test_diagnose_search import C2, K3, G, XY, _fitted
from test_diagnose_sets import two_dof_records

Y = Location(1, -1, ("y", "ground"))


def _cand(kind: str, loc: Location, closure: float = math.nan) -> Candidate:
    return Candidate(EFFECTS[kind], loc, {}, closure=closure)


def test_a_member_without_a_single_fit_reports_what_it_adds():
    swapped = _cand("damper", G)
    swapped.closure_added = 0.31
    known = _cand("cubic_spring", XY)
    known_single = _cand("cubic_spring", XY, closure=0.6)
    fill_closures([swapped, known], [known_single])
    assert swapped.closure == pytest.approx(0.31)  # no single fit: what the set loses
    assert known.closure == pytest.approx(0.6)     # its single fit's closure


def test_only_members_whose_law_changed_in_place_are_moved():
    a, b = _cand("cubic_damper", G), _cand("cubic_spring", XY)
    chosen = SetFit(b.effect, b.loc, {}, members=[a, b])
    win = SetFit(b.effect, b.loc, {}, members=[_cand("damper", G), b])
    moved = SetFit(b.effect, b.loc, {}, members=[_cand("cubic_damper", Y), b])
    assert swapped_members(chosen, win) == [0]
    assert swapped_members(chosen, moved) == []


def test_a_set_without_its_silent_member_is_fitted_from_the_set():
    st, train, val, proc, gap, blocks = two_dof_records(
        [("quadratic_damper", ("x", "ground"), {"c2": C2}),
         ("cubic_spring", ("x", "y"), {"k3": K3})], 1.5, (5, 6))
    s = DiagnoseSettings(fit_nfev=10)
    quad = _fitted(st, "quadratic_damper", G, C2, train, val, proc, gap, blocks, nfev=10)
    spring = _fitted(st, "cubic_spring", XY, K3, train, val, proc, gap, blocks)
    extra = _fitted(st, "damper", Y, 1e-3, train, val, proc, gap, blocks)
    pair = fit_pair(quad, spring, st, train, val, proc, gap, blocks, s)
    three = grow(pair, extra, st, train, val, proc, gap, blocks, s)
    assert three is not None
    less = without_members(three, [2], st, train, val, proc, gap, blocks, s)
    assert less is not None
    assert [m.label() for m in less.members] == [m.label() for m in three.members[:2]]
    assert less.gap_after < 0.1 * gap  # the two true effects, fitted from the set
    assert without_members(less, [1], st, train, val, proc, gap, blocks, s) is None
