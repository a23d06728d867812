"""Three effects (issue 16): two structural effects and a sensor fault are named together
when the pair search grows its best pairs by one more member (``sets.grow_sets``), each
member needed beside the *pair* of the other two; a third member that adds nothing is
not named."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.scoring import judge, validation_gap
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN, corrected
from siva_core._impl.diagnose.sets import choose_set
from siva_core._impl.diagnose.where import spectral_noise_floor
# the pair tests' structure, effects and single fits (the same two-DOF case)
from test_diagnose_sets import FC, G, K3, NOMINAL, TWO, XY, _single

GAIN = 1.15


def _records(gain: float | None):
    """Train and validation impacts of TWO with the cubic spring and the coulomb, the
    accelerometer on x reading ``gain`` x the truth (None: a right sensor)."""
    gen = with_effect(with_effect(Structure.from_dict(TWO), "cubic_spring", ("x", "ground"),
                                  {"k3": K3}), "coulomb", ("x", "y"), {"fc": FC})
    theta = gen.vector(NOMINAL)
    out = []
    for amps, seed in (([60.0, 150.0], 1), ([30.0, 200.0], 2)):
        recs = synthetic_impacts(gen, theta, amps, dof="y", fs=1024.0, duration=2.0,
                                 seed=seed)
        # corrected() divides: 1 / gain makes the reading gain x the truth
        out.append(recs if gain is None else corrected(recs, ACC_GAIN, "acc_x", 1 / gain))
    return out


def _candidates(st: Structure, train, val, proc, gain: float):
    """(gap, blocks, noise floor, [cubic spring, coulomb, accelerometer gain ``gain``]) as
    a stage would have fitted them (at their true sizes; train costs 0)."""
    gap, blocks = validation_gap(st, st.vector(NOMINAL), val, proc)
    noise = spectral_noise_floor(st, val, proc, st.vector(NOMINAL))
    singles = [_single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks),
               _single(st, "coulomb", XY, FC, train, val, proc, gap, blocks)]
    s = Candidate(ACC_GAIN, Location(0, -1, ("acc_x", "sensor")), {}, fitted=True,
                  structure=st, theta=st.vector(NOMINAL))
    s.coefficients = {"gain": gain}
    judge(s, val, proc, gap, blocks)
    for c in [*singles, s]:
        c.train_cost = 0.0
    return gap, blocks, noise, [*singles, s]


@pytest.fixture(scope="module")
def triple_case():
    st = Structure.from_dict(TWO)
    train, val = _records(GAIN)
    proc = Processing.none()
    gap, blocks, noise, singles = _candidates(st, train, val, proc, GAIN)
    return st, train, val, proc, gap, blocks, noise, singles


@pytest.mark.slow
def test_two_structural_effects_and_a_sensor_fault_named_together(triple_case):
    st, train, val, proc, gap, blocks, noise, singles = triple_case
    assert max(c.closure for c in singles) < 0.95  # no single effect explains it
    settings = DiagnoseSettings(fit_nfev=20)
    ranking = sorted(singles, key=lambda c: -c.closure)
    verdict, named, rule = choose_set(None, [], ranking, st, train, val, proc, gap, blocks,
                                      noise, settings)
    assert sorted(m.label() for m in named) == ["accelerometer_gain acc_x",
                                                "coulomb x-y", "cubic_spring x-ground"]
    gain = next(m for m in named if m.category == "sensor").coefficients["gain"]
    assert gain == pytest.approx(GAIN, rel=0.02)
    assert rule["sets"][-1]["set"].count("+") == 2 and rule["combined_closure"] > 0.99
    # pairs only (set_beam 0): the fault is left unnamed, whatever pair is named
    _, two, rule2 = choose_set(None, [], ranking, st, train, val, proc, gap, blocks, noise,
                               DiagnoseSettings(fit_nfev=20, set_beam=0))
    assert len(two) <= 2 and all("+ " not in t["set"] or t["set"].count("+") == 1
                                 for t in rule2["sets"])


@pytest.mark.slow
def test_a_third_member_that_adds_nothing_is_not_named(triple_case):
    """The same structural pair on records *without* the fault: a gain grown onto it
    changes nothing, the pair is named alone."""
    st, _, _, proc, _, _, _, _ = triple_case
    train, val = _records(None)
    gap, blocks, noise, singles = _candidates(st, train, val, proc, 1.03)
    ranking = sorted(singles, key=lambda c: -c.closure if np.isfinite(c.closure) else 9)
    _, named, _ = choose_set(None, [], ranking, st, train, val, proc, gap, blocks, noise,
                             DiagnoseSettings(fit_nfev=20))
    assert sorted(m.label() for m in named) == ["coulomb x-y", "cubic_spring x-ground"]
