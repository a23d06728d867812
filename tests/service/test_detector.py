"""The drift detector (service/detector.py) on synthetic per-record series.

Reduced-size versions of the benchmark's claims: at most one false alarm in 2000 in-control records
of 10 quantities (heteroscedastic errors, as per-record fits of light and hard taps give),
a 15 % shift named within 8 records with its change point, one outlier never alarms, the
states raised -> confirmed -> cleared, reset, and the checkpoint round trip.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from service.monitoring.cusum import cusum_threshold
from service.monitoring.detector import ChangeDetector, DetectorSettings

QS = [f"q{i}" for i in range(10)]


def _feed(det: ChangeDetector, x: np.ndarray, se: np.ndarray, start: int = 0) -> list[dict]:
    changes = []
    for i, (row, err) in enumerate(zip(x, se), start=start):
        changes += [dict(a, record=i) for a in det.observe(
            {"id": f"r{i}", "index": i, "time": float(i)},
            dict(zip(QS, row)), dict(zip(QS, err)))]
    return changes


def test_threshold_matches_siegmund_and_bonferroni():
    h = cusum_threshold(1e5, 0.5)
    b = h + 1.166
    assert (math.exp(b) - b - 1) / 0.5 == pytest.approx(1e5, rel=1e-6)
    assert cusum_threshold(1e6, 0.5) > h > cusum_threshold(1e4, 0.5)
    s = DetectorSettings()
    assert s.threshold(10) == pytest.approx(cusum_threshold(2 * 10 * s.arl0_records, s.k))
    assert ChangeDetector(QS).report()["rule"]["false_alarms_per_1000_records_nominal"] == 0.05


def test_at_most_one_false_alarm_in_2000_in_control_records():
    """Nominal rate 0.05 per 1000 records (0.1 expected here); this synthetic case is harsher
    than LO-NO (errors vary six-fold and reach the scatter floor) and gives 1 in 2000 -
    more would mean the threshold or the baseline's uncertainty is handled wrongly."""
    raised = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        se = rng.uniform(0.005, 0.03, size=(200, len(QS)))  # light and hard taps
        x = 1 + se * rng.standard_normal(se.shape)
        raised += [a for a in _feed(ChangeDetector(QS), x, se) if a["state"] == "raised"]
    assert len(raised) <= 1, [a["message"] for a in raised]


def test_shift_alarm_states_change_point_and_reset():
    rng = np.random.default_rng(3)
    se = np.full((40, len(QS)), 0.001)
    x = 1 + se * rng.standard_normal(se.shape)
    x[20:30, 0] *= 0.85  # q0 loses 15 % at record 20, back at record 30
    x[12, 1] = 1.5       # one wild record on q1: never alarms alone
    det = ChangeDetector(QS)
    changes = _feed(det, x, se)
    q0 = [a for a in changes if a["parameter"] == "q0"]
    assert {a["parameter"] for a in changes} == {"q0"}
    raised = next(a for a in q0 if a["state"] == "raised")
    assert 20 <= raised["record"] <= 27  # within 8 records
    assert [a["state"] for a in q0] == ["raised", "confirmed", "cleared"]
    alarm = det.alarms[0]
    assert alarm["state"] == "cleared" and alarm["active"] is False
    assert alarm["direction"] == "decrease"
    cp = alarm["change_point"]
    assert cp["interval_records"][0] <= 20 <= cp["interval_records"][1]
    assert alarm["change_rel"] == pytest.approx(-0.15, abs=0.01)
    lo, hi = alarm["change_rel_ci95"]
    assert lo <= -0.15 <= hi
    assert "q0: decrease of 15" in alarm["message"]  # cleared: what was seen, then why it cleared
    # checkpoint round trip, then reset forgets baseline and alarms
    clone = ChangeDetector(QS)
    clone.load_state_dict(det.state_dict())
    assert clone.report() == det.report()
    det.reset()
    assert det.baseline is None and det.alarms == [] and det.report()["active_alarms"] == []


def test_floor_keeps_tiny_changes_quiet():
    """Estimates far more precise than the 0.5 % floor: a 0.2 % change is not an alarm,
    a 2 % one is (4 floor units per record)."""
    rng = np.random.default_rng(5)
    se = np.full((40, len(QS)), 1e-5)
    x = 1 + se * rng.standard_normal(se.shape)
    x[20:, 2] *= 0.998
    x[20:, 3] *= 0.98
    det = ChangeDetector(QS)
    alarmed = {a["parameter"] for a in _feed(det, x, se)}
    assert alarmed == {"q3"}


def test_small_persistent_shift_stays_confirmed_and_messages_agree_with_states():
    """Issue 17, finding 8: f1 stayed 1 % low, yet its alarm went raised -> confirmed ->
    cleared within a few records (each |z| < 2), cleared rows still ended "; confirmed", and a
    message read "decreased by 0.0 % (95 % CI 0.6-0.6 %)"."""
    rng = np.random.default_rng(5)
    n = 80
    se = np.full((n, len(QS)), 0.001)
    x = 1 + se * rng.standard_normal(se.shape)
    x[30:, 0] *= 0.992  # q0 0.8 % low from record 30 on, for good: z about -1.6 per record
    det = ChangeDetector(QS)
    changes = _feed(det, x, se)
    q0 = [a for a in changes if a["parameter"] == "q0"]
    assert [a["state"] for a in q0] == ["raised", "confirmed"], [a["message"] for a in q0]
    alarm = det.alarms[0]
    assert alarm["active"] and alarm["state"] == "confirmed"
    msg = alarm["message"]
    assert msg.startswith("q0 decreased by 0.") and msg.count("decreased") == 1, msg
    assert "confirmed at record" in msg and "raised" not in msg.split(";")[0]
    lo, hi = alarm["change_rel_ci95"]
    assert lo < alarm["change_rel"] < hi < 0  # the interval is on the side of the change
    assert alarm["change_rel"] == pytest.approx(-0.008, abs=0.002)


def test_cleared_alarm_message_says_cleared_once():
    rng = np.random.default_rng(3)
    se = np.full((40, len(QS)), 0.001)
    x = 1 + se * rng.standard_normal(se.shape)
    x[20:30, 0] *= 0.85
    det = ChangeDetector(QS)
    _feed(det, x, se)
    msg = det.alarms[0]["message"]
    assert det.alarms[0]["state"] == "cleared"
    assert msg.startswith("q0: decrease of 15") and "cleared at record" in msg, msg
    assert not msg.rstrip().endswith("confirmed") and msg.count("cleared at") == 1


def test_message_interval_across_zero_is_signed():
    from service.monitoring.alarm_text import alarm_message
    msg = alarm_message({"parameter": "f1_hz", "direction": "decrease", "state": "raised",
                         "change_rel": -0.0004, "change_rel_ci95": [-0.006, 0.005],
                         "raised_index": 9, "change_since_index": 7})
    assert "(95 % CI -0.6 to +0.5 %)" in msg and "0.6-0.6" not in msg, msg
