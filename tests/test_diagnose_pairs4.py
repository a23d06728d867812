"""Branch pairs4: a later stage's candidate paired with a sensor fault names the earlier
structural verdicts its model holds (fresh seed 17420), and a single of as many
coefficients whose train fit beats the verdict's by the separation ratio is compared on
all records (fresh seed 17365)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from siva_core import EFFECTS
from siva_core._impl.diagnose import DiagnoseSettings
from siva_core._impl.diagnose.results import Candidate, Location
from siva_core._impl.diagnose.set_fit import SetFit
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN
from siva_core._impl.diagnose.set_members import with_embedded
from siva_core._impl.diagnose.ties import contenders

G2 = Location(1, -1, ("m2", "ground"))
M12 = Location(0, 1, ("m1", "m2"))


def _fit(kind: str, loc: Location, gap: float, cost: float, **kw: object) -> Candidate:
    return Candidate(EFFECTS[kind], loc, {}, fitted=True, gap_after=gap, train_cost=cost,
                     structure=SimpleNamespace(spec={}), theta=np.zeros(1), **kw)


def test_a_train_fit_much_better_makes_a_contender() -> None:
    s = DiagnoseSettings()
    verdict = _fit("cubic_damper", G2, 0.00617, 0.00988)
    better_train = _fit("quadratic_damper", G2, 0.00894, 0.00192)
    near_train = _fit("quadratic_damper", M12, 0.00894, 0.9 * 0.00988)
    two_coeffs = _fit("clearance", G2, 0.00894, 0.001)
    got = contenders(verdict, [verdict, better_train, near_train, two_coeffs], 2e-4, s)
    assert [c.label() for c in got] == [better_train.label()]


def test_a_set_names_the_verdicts_its_model_holds() -> None:
    damper = Candidate(EFFECTS["cubic_damper"], G2, {}, names={"c3": "c3_m2_ground"})
    spec = {"elements": [
        {"kind": "cubic_damper", "between": ["m2", "ground"], "params": {"c3": "c3_m2_ground"}},
        {"kind": "clearance", "between": ["m1", "m2"],
         "params": {"k": "k_m1_m2", "gap": "gap_m1_m2"}}]}
    clearance = Candidate(EFFECTS["clearance"], M12, {},
                          names={"k": "k_m1_m2", "gap": "gap_m1_m2"})
    gain = Candidate(ACC_GAIN, Location(1, -1, ("acc_m2", "sensor")), {})
    s = SetFit(clearance.effect, M12, {}, structure=SimpleNamespace(spec=spec),
               members=[clearance, gain], sensor=gain)
    other = Candidate(EFFECTS["cubic_damper"], M12, {}, names={"c3": "c3_m1_m2"})
    (out,) = with_embedded([s], [damper, gain, other])
    assert [m.key for m in out.members] == [damper.key, clearance.key, gain.key]
    # a set whose model does not hold the verdict is left as it is
    bare = SetFit(clearance.effect, M12, {}, structure=SimpleNamespace(spec={}),
                  members=[clearance, gain], sensor=gain)
    assert with_embedded([bare], [damper])[0].members == [clearance, gain]
