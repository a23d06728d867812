"""A nominal start whose stiffness is indefinite diverges through a real eigenvalue that
the linear modes leave out: the plausibility check sees it, and the springs' signs are
flipped for a stable start (fresh seed 17482: k = -838 N/m between m1 and m2)."""
from __future__ import annotations

import numpy as np

from siva_core import Structure
from siva_core._impl.diagnose.nominal import _plausible, _stiffened

CHAIN2 = {"name": "chain2", "dofs": ["m1", "m2"], "mass": {"m1": 1.8, "m2": 0.96},
          "elements": [
              {"kind": "spring", "between": ["m1", "ground"], "params": {"k": "k1"}},
              {"kind": "damper", "between": ["m1", "ground"], "params": {"c": "c1"}},
              {"kind": "spring", "between": ["m1", "m2"], "params": {"k": "k12"}},
              {"kind": "damper", "between": ["m1", "m2"], "params": {"c": "c12"}}]}


def test_an_indefinite_stiffness_grows_and_is_not_plausible() -> None:
    st = Structure.from_dict(CHAIN2)
    stable = st.vector({"k1": 2.2e4, "c1": 20.0, "k12": 8.0e3, "c12": 5.0})
    bad = st.vector({"k1": 2.2e4, "c1": 20.0, "k12": -800.0, "c12": 5.0})
    assert st.linear_growth_rate(stable) < 0
    # m2 hangs on a negative spring alone: a real eigenvalue sqrt(800 / 0.96) ~ +28.9 1/s
    assert st.linear_growth_rate(bad) > 20
    assert len(st.linear_modes(bad)["frequency_hz"]) == 1     # the modes leave it out
    assert _plausible(st, stable, fs=1000.0)
    assert not _plausible(st, bad, fs=1000.0)
    fixed = _stiffened(st, bad)
    assert fixed is not None and np.all(fixed >= 0)
    assert _plausible(st, fixed, fs=1000.0)
    assert _stiffened(st, stable) is None
