"""Faint effects judged against what a right model can remove (issue 16, fresh seeds
17000-17059, looked at after their run): the size check on the gap *above the noise
floor*, and the hammer pulse's reading gain fitted as a nuisance of a set, never named."""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

from siva_core import EFFECTS, DiagnoseSettings, diagnose
from siva_core._impl.diagnose.results import Candidate, Location
from siva_core._impl.diagnose.verdict import closes_above_noise, decide

ROOT = Path(__file__).resolve().parents[1]


def test_the_size_check_counts_the_gap_above_the_noise_floor():
    """17023's numbers: the right cubic damper took a 0.0662 gap to 0.0368 (closure 0.445)
    with a spectral floor of 0.0117 -- 0.54 of the gap above the floor.  A fit removing
    less than 2 x the floor passes never, whatever its share of a gap that is mostly
    noise."""
    s = DiagnoseSettings()
    assert closes_above_noise(0.0662, 0.0368, 0.0117, s.closure_min, s)
    assert not closes_above_noise(0.0662, 0.0368, None, s.closure_min, s)
    assert not closes_above_noise(0.0662, 0.045, 0.0117, s.closure_min, s)  # 0.39 of it
    # a gap 2.5 x the floor: 0.6 of its excess is only 0.9 x the floor removed
    assert not closes_above_noise(0.025, 0.016, 0.01, s.closure_min, s)
    assert not closes_above_noise(0.005, 0.008, 0.001, s.closure_min, s)  # worse


def _fitted(kind: str, gap_before: float, gap_after: float) -> Candidate:
    c = Candidate(EFFECTS[kind], Location(0, -1, ("m1", "ground")), {}, fitted=True,
                  gap_before=gap_before, gap_after=gap_after,
                  closure=1.0 - gap_after / gap_before)
    c.per_record = [{"record": "val", "gap_before": gap_before, "gap_after": gap_after,
                     "closure": c.closure}]
    return c


def test_a_gap_far_above_the_noise_is_not_reported_as_noise():
    """Fresh seed 17227's numbers (branch absorbed): a 0.0024 gap, 110 x the floor, under
    gap_min, whose best candidate (a clearance) closed 0.25 and a coulomb 0.05: refused,
    and the reason says the gap's size against the floor and the closures, not that the
    nominal model fits to the noise level.  A gap at the floor still reads so."""
    s = DiagnoseSettings()
    gap, floor = 0.0024064, 2.1786e-05
    ranking = [_fitted("clearance", gap, 0.00181), _fitted("coulomb", gap, 0.00228)]
    verdict, rule = decide(ranking, gap, floor, s, spectral=floor)
    assert verdict is None
    assert "110.5 x the noise floor" in rule["reason"]
    assert "closes 0.25 of it" in rule["reason"]
    assert "(coulomb m1-ground, closure 0.05, against 0.25)" in rule["reason"]
    assert "fits the validation records to the noise level" not in rule["reason"]
    _, rule = decide([_fitted("clearance", 3e-5, 1e-5)], 3e-5, floor, s, spectral=floor)
    assert "fits the validation records to the noise level (gap 3e-05, 1.4 x" \
        in rule["reason"]
    # 17230's numbers: 0.61 of the part above the floor, but only 0.5 x the floor removed
    gap, floor = 0.003956, 0.002164
    _, rule = decide([_fitted("spring", gap, 0.00286)], gap, floor, s, spectral=floor)
    assert "0.61 of its part above the noise floor (removing 0.0011, 0.5 x the floor" \
        in rule["reason"]


def test_a_gap_under_gap_min_counts_by_its_part_above_the_noise():
    """The 3-DOF chain's small damper m1-m3 (matrix case, branch absorbed): a 0.000845
    gap, 9.7 x the floor 8.74e-5, under gap_min and under faint_noise x the floor; the
    right damper left 0.000223 (closure 0.74, 0.82 of the part above the floor) and is
    named.  A null's residue (a 0.0009 gap of which a flexible element explains 46 %,
    settings' doc) stays refused at any floor: either its share of the part above the
    floor is under 0.8 or what it removes is under 2 x the floor."""
    s = DiagnoseSettings()
    gap, floor = 0.000845, 8.74e-5
    ranking = [_fitted("damper", gap, 0.000223), _fitted("clearance", gap, 0.00057)]
    verdict, rule = decide(ranking, gap, floor, s, spectral=0.000339)
    assert verdict is not None and rule.get("faint_above_noise")
    for floor in (1e-5, 5e-5, 1e-4, 2e-4, 3e-4, 4e-4):
        ranking = [_fitted("damper", 0.0009, 0.000486), _fitted("clearance", 0.0009, 0.0009)]
        verdict, rule = decide(ranking, 0.0009, floor, s, spectral=floor)
        assert verdict is None and not rule["checks"]["above_noise"], floor


def test_a_faint_cubic_spring_is_named_with_the_pulse_reading_as_a_nuisance():
    """17026 (1-DOF at 288 Hz, a 2.1 % hum, a cubic spring at 3.0 x the noise): the spring
    alone closes 0.36 -- as much as the truth model refitted -- because the rest of the
    gap is how the diagnosis reads the continuous hammer pulse between its samples; with
    a force gain 1.08 inside the pulse-reading band the pair closes 0.96.  The gain was
    refused as a fault (right) and the pair with it; now it is fitted as a nuisance and
    the spring alone named, its k3 within 10 % of the truth."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios

    sc = scenarios.draw(17026)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = diagnose(sc.nominal, sc.train, sc.val, "auto").to_json()
    named = [(v["kind"], tuple(v["between"])) for v in out["verdicts"]]
    assert named == [("cubic_spring", ("m1", "ground"))], named
    k3 = out["verdicts"][0]["coefficients"]["k3"]
    assert abs(k3 / sc.effects[0][2]["k3"] - 1) < 0.1, k3
