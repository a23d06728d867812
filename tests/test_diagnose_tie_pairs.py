"""A first stage's leads that the tentative one does not separate from are paired with
the later stages' effects (branch tiepair); a lead separated from it, a law of the lead's
role at its place, or the feature switched off gives no pair."""
from __future__ import annotations

import numpy as np

from siva_core import EFFECTS
from siva_core._impl.diagnose import Candidate, DiagnoseSettings, Location
from siva_core._impl.diagnose.tie_pairs import tie_pairs, tied_leads

M1G = Location(0, -1, ("m1", "ground"))
M2G = Location(1, -1, ("m2", "ground"))
M12 = Location(0, 1, ("m1", "m2"))
M3G = Location(2, -1, ("m3", "ground"))


def _fit(kind: str, loc: Location, gap_after: float, train_cost: float,
         gap_before: float = 1.63) -> Candidate:
    c = Candidate(EFFECTS[kind], loc, {}, score=0.1)
    c.fitted, c.train_cost, c.gap_after = True, train_cost, gap_after
    c.closure = 1.0 - gap_after / gap_before
    c.structure, c.theta = object(), np.zeros(1)  # type: ignore[assignment]
    return c


def test_tied_leads_are_those_the_tentative_lead_does_not_separate_from() -> None:
    s = DiagnoseSettings()
    # the last fresh batch's numbers: coulomb m2-ground 0.59, cubic spring m1-ground 0.57
    coulomb = _fit("coulomb", M2G, 0.668, 0.30)
    spring = _fit("cubic_spring", M1G, 0.700, 0.25)
    far = _fit("clearance", M3G, 1.40, 0.60)           # closes 0.14: separated (0.75)
    ranking = [coulomb, spring, far]
    assert tied_leads(ranking, spring, 0.0059, s) == [coulomb]
    assert tied_leads(ranking, coulomb, 0.0059, s) == [spring]
    assert tied_leads(ranking, spring, 0.0059, DiagnoseSettings(tie_leads=0)) == []
    # within noise_factor x the floor though beyond the ratio: a tie too
    near = _fit("clearance", M3G, 0.010, 0.01, gap_before=0.05)
    lead = _fit("coulomb", M2G, 0.005, 0.01, gap_before=0.05)
    assert tied_leads([lead, near], lead, 0.003, s) == [near]
    assert tied_leads([lead, near], lead, 0.001, s) == []


def test_tie_pairs_skip_a_look_alike_at_the_leads_place_and_are_bounded() -> None:
    coulomb = _fit("coulomb", M2G, 0.668, 0.30)
    spring = _fit("cubic_spring", M1G, 0.700, 0.25)
    damper = _fit("quadratic_damper", M12, 0.30, 0.05)
    same_role = _fit("cubic_damper", M2G, 0.35, 0.08)    # dissipative at coulomb's place
    other_role = _fit("cubic_spring", M2G, 0.40, 0.1)    # restoring at coulomb's place
    wide = DiagnoseSettings(tie_pair_fits=10)
    pairs = tie_pairs([coulomb, spring], [damper, same_role, other_role], wide)
    labels = [(a.label(), b.label()) for a, b in pairs]
    assert (coulomb.label(), damper.label()) == labels[0]
    assert (coulomb.label(), same_role.label()) not in labels  # one place, one role
    assert (coulomb.label(), other_role.label()) in labels     # one place, two roles
    assert (spring.label(), same_role.label()) in labels
    assert (spring.label(), other_role.label()) in labels      # same law, other place
    assert len(tie_pairs([coulomb, spring], [damper, other_role],
                         DiagnoseSettings(tie_pair_fits=1))) == 1
