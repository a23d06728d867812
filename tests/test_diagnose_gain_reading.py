"""A force gain beside a structural effect (issue 16, fresh seeds 17160-17219, burned):
the generator's truth says which gains the hammer pulse's reading explains
(``benchmarks/pulse_truth.py``), the diagnosis states that limit
(``pulse_reading.reading_limit``), and gains outside it are named with the right law
(17167: the force multiplier of the structural model; 17219: the look-alike law paired
with the lead's gain)."""
from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np

from siva_core import Recording, diagnose
from siva_core._impl.diagnose.pulse_reading import reading_limit

from synthetic import half_sine_hit, unit_sdof

ROOT = Path(__file__).resolve().parents[1]


def _bench(name: str):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    return __import__(name)


def test_the_truth_puts_a_gain_within_the_reading_of_a_two_sample_pulse_only():
    """17164 (2 samples at 362 Hz): the half-sines through its samples deliver 0.91-5.6 x
    the true impulse, so a gain 0.84 is what a fault-free hammer could give; 17182 (8
    samples at 2608 Hz): +-1.5 %, a gain 0.886 is a fault.  A gain of 1 is always within."""
    pt = _bench("pulse_truth")
    short = pt.gain_reading(("force_gain", "force_m1", 0.84), 1, 5.52e-3, 362.0, 0.05, 0.002)
    assert short["within"] and short["samples"] == 2 and short["low"] < 0.5
    assert short["low"] <= 1.0 <= short["high"]
    long_ = pt.gain_reading(("force_gain", "force_m2", 0.886), 3, 3.09e-3, 2608.0, 0.05, 0.002)
    assert not long_["within"] and long_["samples"] == 8
    assert 0.97 < long_["low"] <= 1.0 <= long_["high"] < 1.03
    # a 1-DOF accelerometer gain is the inverse force gain; other faults have no entry
    acc = pt.gain_reading(("accelerometer_gain", "acc_m1", 1.15), 1, 5.74e-3, 367.0, 0.05, 0.0)
    assert math.isclose(acc["gain"], 1 / 1.15) and acc["within"]
    assert pt.gain_reading(("accelerometer_gain", "acc_m1", 1.15), 2, 5e-3, 367.0, 0.05, 0) is None
    assert pt.gain_reading(("channel_delay", "acc_m1", 0.001), 1, 5e-3, 367.0, 0.05, 0) is None


def test_the_diagnosis_states_the_gain_its_pulse_cannot_tell():
    """A 2-sample pulse: a statement naming the hammered channel with a band over 50 %;
    a 15-sample pulse: a band under 2 %; a 40-sample pulse and records without a force
    channel: none."""
    st, th = unit_sdof()
    lim = reading_limit(st, th, [half_sine_hit(2.0, 0.5)])
    assert lim is not None and lim["channel"] == "force_x" and lim["band"] > 0.5
    assert "force_x" in lim["text"] and "cannot be told" in lim["text"]
    # lopsided: wider half-sines pass through two samples, narrower ones hardly do
    assert lim["low"] < 0.5 and 1.0 < lim["high"] < 1.2
    assert reading_limit(st, th, [half_sine_hit(15.0, 0.3)])["band"] < 0.02
    assert reading_limit(st, th, [half_sine_hit(40.0, 0.3)]) is None  # read to well under 1 %
    quiet = Recording(np.arange(512) / 512.0, {"acc_x": np.zeros(512)}, "quiet")
    assert reading_limit(st, th, [quiet]) is None


def _named(seed: int) -> list[str]:
    sc = _bench("scenarios").draw(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = diagnose(sc.nominal, sc.train, sc.val, "auto").to_json()
    # one accelerometer: its gain *is* a force gain (1/g), as bench_scenarios counts it
    same = {"accelerometer_gain acc_m1": "force_gain force_m1"}
    return sorted(same.get(n, n) for n in (f"{v['kind']} {'-'.join(v['between'])}"
                                           for v in out["verdicts"]))


def test_a_gain_outside_the_reading_is_named_with_the_right_law():
    """17167 (an accelerometer gain 1.2 on a 1-DOF, reported as the force gain 1/1.2,
    beside a cubic damper; the nominal-model gain was 0.88) and 17219 (force gain 0.839
    beside a cubic damper; a quadratic damper + gain led): both named in full now."""
    assert _named(17167) == ["cubic_damper m1-ground", "force_gain force_m1"]
    assert _named(17219) == ["cubic_damper m1-ground", "force_gain force_m1"]
