"""An accelerometer gain that the common (force) gain out-fits is not named when that force
gain is the hammer pulse's reading (issue 16, fresh seed 17048, looked at after its run:
acc_m1 0.896 named beside the right cubic damper while a force gain 1.103 within the
pulse-reading band fitted the train records better)."""
from __future__ import annotations

from siva_core._impl.diagnose.pulse_reading import shadowed_by_reading
from siva_core._impl.diagnose.results import Candidate, Location
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN, FORCE_GAIN


def _sensor(fault, ch: str, train_cost: float, reading: bool = False) -> Candidate:
    c = Candidate(fault, Location(0, -1, (ch, "sensor")), {})
    c.fitted, c.train_cost, c.reading = True, train_cost, reading
    c.coefficients = {"gain": 1.1}
    return c


def test_an_accelerometer_gain_out_fitted_by_a_reading_force_gain_is_shadowed():
    force = _sensor(FORCE_GAIN, "force_m1", 0.002166, reading=True)   # 17048's numbers
    acc = _sensor(ACC_GAIN, "acc_m1", 0.003756)
    assert shadowed_by_reading(acc, [force, acc]) is force


def test_a_better_one_channel_fit_or_a_real_force_gain_does_not_shadow():
    force = _sensor(FORCE_GAIN, "force_m1", 0.004, reading=True)
    acc = _sensor(ACC_GAIN, "acc_m2", 0.002)          # one channel fits better: its own fault
    assert shadowed_by_reading(acc, [force, acc]) is None
    fault = _sensor(FORCE_GAIN, "force_m1", 0.001)    # a force gain outside the band: a fault
    acc2 = _sensor(ACC_GAIN, "acc_m1", 0.003)
    assert shadowed_by_reading(acc2, [fault, acc2]) is None
    assert shadowed_by_reading(force, [force, acc]) is None  # only accelerometer gains
