"""The nominal fit tries the other sign of the model's nonlinear coefficients (issue 16,
fresh seed 17200, burned): least squares put the known cubic spring m1-m2 at -1.6e9 where
the truth is +3.8e10, the refinement stayed on that side (train cost 4.97e-4, validation
gap 0.0044), and the right channel delay could not be named because every structural
candidate "closed" the gap by leaving that basin."""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

from siva_core._impl.diagnose import DiagnoseSettings
from siva_core._impl.diagnose.band import fit_nominal_in_band
from siva_core._impl.diagnose.nominal import nonlinear_params
from siva_core._impl.siva import choose_processing

ROOT = Path(__file__).resolve().parents[1]


def test_the_nominal_cubic_spring_leaves_the_wrong_sign():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios

    sc = scenarios.draw(17200)
    st = sc.nominal
    assert nonlinear_params(st) == ["knl_m1m2"]
    lines: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        proc0 = choose_processing("auto", [*sc.train, *sc.val], st.dofs)
        proc, fit = fit_nominal_in_band(st, sc.train, [*sc.train, *sc.val], proc0,
                                        DiagnoseSettings(), lines.append)
    knl = st.as_dict(fit.theta)["knl_m1m2"]
    assert any("other sign" in line for line in lines)
    assert "other sign" in fit.start
    # hardening, as the truth (3.84e10); the wrong-sign fit was -1.6e9 at 4.97e-4
    assert 1e10 < knl < 1e11
    assert fit.train_cost < 4.0e-4
