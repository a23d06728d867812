"""A nominal model that escapes on the validation records is never read as fitting them
(issue 16, fresh seed 17471: a softening nominal cubic spring k3 = -5.8e11 fitted on 29
and 53 N hits diverged on the 132 and 190 N validation hits; the gap was NaN and the
report said "fits ... to the noise level (gap nan)")."""
from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

from siva_core._impl.diagnose import DiagnoseSettings
from siva_core._impl.diagnose.bounded import diverging
from siva_core._impl.diagnose.results import Candidate, Location
from siva_core._impl.diagnose.verdict import _reasons
from siva_core._impl.effects import EFFECTS
from siva_core._impl.siva import choose_processing

ROOT = Path(__file__).resolve().parents[1]

#: the nominal fit of seed 17471 (measured), rounded
NOMINAL_17471 = {"k_m1g": 85308.0, "c_m1g": -9.45, "k_m1m2": 227390.0, "c_m1m2": 852.7,
                 "k_m2m3": 201889.0, "c_m2m3": 16.77, "k_m3m4": 126860.0, "c_m3m4": 43.58,
                 "k_m2g": 81069.0, "c_m2g": 68.21, "k_m3g": 46962.0, "c_m3g": 0.737,
                 "k_m4g": 59167.0, "c_m4g": 6.077, "knl_m4g": -5.8188e11}


def test_the_escaping_nominal_diverges_on_the_large_records_only():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios

    sc = scenarios.draw(17471)
    st = sc.nominal
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        proc = choose_processing("auto", [*sc.train, *sc.val], st.dofs)
        theta = st.vector(NOMINAL_17471)
        assert diverging(st, theta, sc.val, proc) == [r.name for r in sc.val]
        assert diverging(st, theta, sc.train, proc) == []
        linear = st.vector({**NOMINAL_17471, "knl_m4g": 0.0})
        assert diverging(st, linear, sc.val, proc) == []


def test_a_nan_gap_is_never_read_as_fitting():
    c = Candidate(EFFECTS["coulomb"], Location(0, 1, ("m1", "m2")), {})
    c.gap_after, c.closure = math.nan, math.nan
    text = _reasons(c, None, math.nan, 0.001, 0.001, DiagnoseSettings())["above_noise"]
    assert "diverges" in text and "noise level" not in text
