"""The backward step of the greedy two-effect search: a first effect that only stood in for
the second is dropped, a first effect that carries its own part of the gap stays."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import EFFECTS, Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location, augmented,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.elimination import without_first
from siva_core._impl.diagnose.scoring import judge, validation_gap

SDOF = {"name": "sdof", "dofs": ["x"], "mass": {"x": 1.0},
        "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                     {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
NOMINAL = {"c": 0.5, "k": 4000.0}
K3 = 1.0e6        # hardening: ~25 % of the linear force at the largest train amplitude
PLACE = Location(0, -1, ("x", "ground"))


def _records(gen: Structure):
    theta = gen.vector(NOMINAL)
    train = synthetic_impacts(gen, theta, [200.0, 400.0], dof="x", fs=1024.0, duration=3.0,
                              seed=1)
    val = synthetic_impacts(gen, theta, [100.0, 600.0], dof="x", fs=1024.0, duration=3.0,
                            seed=2)
    return train, val


def _joint(first: tuple[str, float], train, val, proc, gap, blocks):
    """The greedy result: ``first`` (kind, magnitude) named in stage 1, the cubic spring at
    its true size added in stage 2, both in one model."""
    sdof = Structure.from_dict(SDOF)
    kind, mag = first
    eff1, eff2 = EFFECTS[kind], EFFECTS["cubic_spring"]
    aug1, names1 = augmented(sdof, eff1, PLACE, {eff1.magnitude: max(abs(mag), 1e-6)})
    aug2, names2 = augmented(aug1, eff2, PLACE, {"k3": K3})
    theta = aug2.vector({**NOMINAL, names1[eff1.magnitude]: mag, names2["k3"]: K3})
    one = Candidate(eff1, PLACE, {}, fitted=True, structure=aug1, names=names1,
                    theta=aug1.vector({**NOMINAL, names1[eff1.magnitude]: mag}),
                    coefficients={eff1.magnitude: mag})
    two = Candidate(eff2, PLACE, {}, fitted=True, structure=aug2, names=names2, theta=theta,
                    coefficients={"k3": K3})
    judge(two, val, proc, gap, blocks)
    return [one, two]


@pytest.mark.parametrize("generator_extra,first,dropped", [
    (None, ("spring", 1.0), True),                    # a negligible look-alike: dropped
    (("coulomb", {"fc": 3.0}), ("coulomb", 3.0), False),   # a real second effect: kept
])
def test_a_stand_in_first_effect_is_dropped(generator_extra, first, dropped):
    sdof = Structure.from_dict(SDOF)
    gen = with_effect(sdof, "cubic_spring", ("x", "ground"), {"k3": K3})
    if generator_extra:
        gen = with_effect(gen, generator_extra[0], ("x", "ground"), generator_extra[1])
    train, val = _records(gen)
    proc = Processing.auto(train, sdof.dofs)
    gap, blocks = validation_gap(sdof, sdof.vector(NOMINAL), val, proc)
    verdicts = _joint(first, train, val, proc, gap, blocks)
    alone = without_first(verdicts, sdof, train, val, proc, gap, blocks, DiagnoseSettings())
    if not dropped:
        assert alone is None
        return
    assert alone is not None and alone.effect.kind == "cubic_spring"
    assert alone.coefficients["k3"] == pytest.approx(K3, rel=0.05)
    assert alone.closure > 0.95
    assert "dropped" in alone.note and np.isfinite(alone.gap_after)
