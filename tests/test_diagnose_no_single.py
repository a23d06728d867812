"""When no single closes much of a gap many times the noise, the train records rank the
singles (branch nosingle): the tentative first effect is the one lowering the train cost
most, and the singles explaining part of the train records are paired with each other
and the joining sensor faults.  A gap near the noise, a single closing ``step_min``, or a
lead of more coefficients gives nothing."""
from __future__ import annotations

from siva_core._impl.diagnose import Candidate, DiagnoseSettings, Location
from siva_core._impl.diagnose.no_single import no_single_closes, train_lead, weak_pairs
from siva_core._impl.diagnose.sensor_faults import CHANNEL_DELAY
from test_diagnose_tie_pairs import _fit as _single

M1G = Location(0, -1, ("m1", "ground"))
M2G = Location(1, -1, ("m2", "ground"))
M12 = Location(0, 1, ("m1", "m2"))


def _fit(kind: str, loc: Location, gap_after: float, train_cost: float) -> Candidate:
    """A fitted single of seed 17681's first stage (nominal gap 0.04697)."""
    return _single(kind, loc, gap_after, train_cost, gap_before=0.04697)


def _seed_17681() -> list[Candidate]:
    """Fresh seed 17681's first stage (nominal train cost 0.00698, gap 0.04697)."""
    return [_fit("quadratic_spring", M2G, 0.04356, 0.006646),
            _fit("quadratic_spring", M1G, 0.04485, 0.006575),
            _fit("quadratic_damper", M12, 0.07327, 0.002008),
            _fit("clearance", M1G, 0.05276, 0.005498)]


def test_the_train_lead_when_no_single_closes_much() -> None:
    s = DiagnoseSettings()
    rk = _seed_17681()
    assert no_single_closes(rk, 0.04697, 0.00013, s)      # 360 x the floor
    assert not no_single_closes(rk, 0.04697, 0.01, s)     # 4.7 x: not many times
    assert not no_single_closes(rk, 0.04697, None, s)
    lead = train_lead(rk, rk[0], 0.00698, s)
    assert lead is rk[2]                                  # the damper, 71 % of the train
    # a clearance (two coefficients) is not a one-coefficient lead's replacement
    assert train_lead([rk[0], rk[3]], rk[0], 0.00698, s) is None
    # a single removing less than step_min of the train cost is not preferred
    assert train_lead(rk[:2], rk[0], 0.00698, s) is None


def test_a_single_closing_step_min_leaves_the_rule_off() -> None:
    s = DiagnoseSettings()
    rk = [_fit("coulomb", M1G, 0.02, 0.006), *_seed_17681()]  # closes 0.57
    assert not no_single_closes(rk, 0.04697, 0.00013, s)


def test_weak_pairs_pair_the_train_explaining_singles_with_faults_and_each_other() -> None:
    s = DiagnoseSettings()
    rk = _seed_17681()
    delay = Candidate(CHANNEL_DELAY, Location(0, -1, ("acc_m1", "sensor")), {})
    pairs = weak_pairs(rk, [delay], 0.00698, s)
    labels = [frozenset((a.label(), b.label())) for a, b in pairs]
    # damper m1-m2 (0.0020) and clearance m1-ground (0.0055) explain >= 12.5 %; the
    # quadratic springs (5 %, 6 %) do not: each with the fault first, then together
    assert labels == [frozenset((rk[2].label(), delay.label())),
                      frozenset((rk[3].label(), delay.label())),
                      frozenset((rk[2].label(), rk[3].label()))]
    faults = [delay]
    assert len(weak_pairs(rk, faults, 0.00698, DiagnoseSettings(weak_pair_fits=1))) == 1
    assert weak_pairs(rk, faults, 0.00698, DiagnoseSettings(weak_pair_fits=0)) == []
