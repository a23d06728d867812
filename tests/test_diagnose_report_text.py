"""The diagnosis HTML says what its own tables say (issue 17, finding 9): the sentences come
from the same numbers as the tables (amplitude trend, decay windows, damping curve)."""
from __future__ import annotations

import numpy as np

from siva_core._impl.diagnose.report import measured_here
from siva_core._impl.diagnose.signatures import _reading, damping_change, damping_words
from siva_core._impl.diagnose.where import _amplitude_trend


def _where(gaps, peaks, decay):
    entries = [{"record": f"r{p}", "role": "val", "peak_force": p, "gap": g,
                "response_rms": {"x": 1.0}} for p, g in zip(peaks, gaps)]
    return {"per_record": entries, "amplitude_trend": _amplitude_trend(entries),
            "decay": decay, "per_dof": {"x": 1.0}, "frequency_bands": {}}


def test_measured_sentence_follows_the_tables():
    # the gap shrinks with amplitude and is worst late: the page must say exactly that
    where = _where([0.30, 0.12, 0.05], [37.0, 530.0, 899.0],
                   {"early": 0.02, "middle": 0.05, "late": 0.4})
    text = measured_here(where)
    assert "shrinks with amplitude" in text and "worst late" in text
    assert "early in the decay" not in text and "grows" not in text
    where = _where([0.05, 0.12, 0.30], [37.0, 530.0, 899.0],
                   {"early": 0.4, "middle": 0.05, "late": 0.02})
    text = measured_here(where)
    assert "grows with amplitude" in text and "worst early" in text


def test_doubling_damping_is_not_called_constant():
    # a cubic damper over one decade of amplitude: zeta doubles, fitted exponent ~ +0.3
    amp = np.geomspace(1e-4, 1e-3, 6)
    zeta = 0.01 * (1 + (amp / amp[-1]) ** 2)
    curve = {"amplitude": amp.tolist(), "damping_ratio": zeta.tolist(),
             "frequency_hz": [20.0] * 6}
    p = float(np.polyfit(np.log(amp), np.log(zeta), 1)[0])
    assert p < 0.4  # the old rule's "about constant" band
    assert damping_change(curve) > 1.9
    words = damping_words(curve, p)
    assert "about constant" not in words and "grows x1.9" in words
    modes = [{"mode": 1, "dof": "x", "linear_frequency_hz": 20.0,
              "measured": {**curve, "damping_exponent": p, "frequency_shift": 0.0,
                           "even_harmonics": None},
              "nominal": {**curve, "damping_ratio": [0.01] * 6, "damping_exponent": 0.0,
                          "frequency_shift": 0.0, "even_harmonics": None}}]
    assert "about constant" not in _reading(modes)


def test_flat_damping_is_called_constant():
    curve = {"amplitude": [1e-4, 1e-3], "damping_ratio": [0.010, 0.0105]}
    assert "about constant" in damping_words(curve, 0.02)
