"""Sensor faults alone and beside structural effects (branch sensor2; fresh seeds 17359
and 17386, burned): a one-value sensor fault is separated from a structural rival by the
block test on all records when the bare ratio of the validation gaps, pulled towards 1
by the noise, cannot; and a sensor fault left under a structural verdict that seems to
explain the gap is looked for at that verdict's model."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from siva_core import EFFECTS
from siva_core._impl.diagnose import Candidate, DiagnoseSettings
from siva_core._impl.diagnose.residue import sensor_residue
from siva_core._impl.diagnose.results import Location
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN
from siva_core._impl.diagnose.set_test import one_value_separation
from siva_core._impl.diagnose.verdict import decide
from test_diagnose_sets import G, K3, _single, two_dof_records


def _cand(effect, loc, gap_before: float, gap_after: float) -> Candidate:
    c = Candidate(effect, loc, {}, fitted=True)
    c.gap_before, c.gap_after = gap_before, gap_after
    c.closure = 1.0 - gap_after / gap_before
    c.per_record = [{"gap_before": gap_before, "gap_after": gap_after,
                     "closure": c.closure}]
    return c


def test_a_sensor_fault_passes_separation_by_the_statistic_not_a_structure():
    """17359's numbers: the gain leaves 0.0112, a spring 0.0139 (ratio 0.80 > 0.75)."""
    s = DiagnoseSettings()
    gain = _cand(ACC_GAIN, Location(1, -1, ("acc_y", "sensor")), 0.0189, 0.0085)
    spring = _cand(EFFECTS["spring"], Location(1, -1, ("y", "ground")), 0.0189, 0.0105)
    v, rule = decide([gain, spring], 0.0189, 0.006, s)
    assert v is None and not rule["checks"]["separation"]
    v, rule = decide([gain, spring], 0.0189, 0.006, s, separated=lambda t, r: 2.0)
    assert v is None and rule["separation_z"]["z"] == 2.0
    v, rule = decide([gain, spring], 0.0189, 0.006, s, separated=lambda t, r: 3.3)
    assert v is gain and "standard errors of the noise" in rule["reason"]
    # a structural lead is not judged this way: the statistic is nan for it
    st, train, val, proc, _, _ = two_dof_records([], 0.5, (1, 2))
    z = one_value_separation(train, val, proc, s.test_blocks)
    assert math.isnan(z(spring, gain)) and math.isnan(z(gain, gain))
    struct = _cand(EFFECTS["damper"], Location(1, -1, ("y", "ground")), 0.0189, 0.0085)
    v, _ = decide([struct, spring], 0.0189, 0.006, s, separated=z)
    assert v is None


def _with_gain(records, channel: str, g: float):
    return [dataclasses.replace(r, channels={**r.channels, channel: g * r.channels[channel]})
            for r in records]


def test_a_gain_under_an_explaining_structural_verdict_is_found():
    """A cubic spring x-ground (the verdict, at its true value) and a 6 % gain on acc_y:
    the scan at the spring's model finds the gain on acc_y; without the gain, or when the
    verdict leaves no more than twice the floor, nothing."""
    s = DiagnoseSettings()
    st, train, val, proc, gap, blocks = two_dof_records(
        [("cubic_spring", ("x", "ground"), {"k3": K3})], 1.0, (1, 2))
    v = _single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks)
    assert sensor_residue(v, train, proc, 1e-6, s) is None  # nothing left to find
    faulty = _with_gain(train, "acc_y", 0.94)
    fault = sensor_residue(v, faulty, proc, 1e-6, s)
    assert fault is not None and fault.label() == "accelerometer_gain acc_y"
    assert abs(fault.coefficients[fault.effect.magnitude] - 0.94) < 0.08
    assert sensor_residue(v, faulty, proc, v.gap_after, s) is None  # within 2 x the floor
    assert np.isfinite(fault.scan_cost)
