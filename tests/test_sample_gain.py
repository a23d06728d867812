"""The gain of the hit's accelerations at the pulse samples, profiled out when a force
multiplier is fitted (issue 20, docs/perf.md 6.7): chain3_end_1k's c1 shift."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from siva_core import (OutputErrorProblem, choose_processing, refine,
                       set_sample_gain_profiling)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from cases import CHAIN3_END_1K  # noqa: E402


def _clean_hit(gain: float = 1.0):
    """Noise-free record of the issue's chain (end mass, 1024 Hz, 4-sample exact pulse,
    the coverage benchmark's sampling phase), its force channel read ``gain`` x the truth;
    the chain with the 95 Hz low-pass that the benchmark's noisy records get (no
    decimation)."""
    case = replace(CHAIN3_END_1K, noise=0.0, force_noise=0.0, hum=0.0)
    st = case.structure()
    rec = case.record(150.0, np.random.default_rng(0), name="hit")
    rec.channels["force_m3"] = rec.channels["force_m3"] * gain
    proc = choose_processing("auto", [rec], st.dofs)
    proc = replace(proc, bandpass=(proc.bandpass[0], 95.0), decimate_to=None)
    return st, case.theta(), rec, proc


def _refined(on: bool, gain: float = 1.0) -> np.ndarray:
    st, truth, rec, proc = _clean_hit(gain)
    old = set_sample_gain_profiling(on)
    try:
        res = refine(st, truth, [rec], proc, fit_force_scale=True, uncertainty="gauss-newton")
    finally:
        set_sample_gain_profiling(old)
    assert res.force_kick is not None  # the kick is fitted, as in ``best``
    return res.theta / truth - 1


def test_profiling_the_sample_gain_removes_the_damping_shift() -> None:
    """Refined from the truth on the noise-free record: with the multiplier (0.98 here)
    applied to the force samples in the simulated accelerations, the pulse's four samples
    are 2 % off, the low-pass spreads that into the decay and c1 comes out +0.1 %; with
    that gain profiled, every parameter within 0.01 %."""
    before = _refined(False)
    after = _refined(True)
    assert before[1] > 5e-4, before                       # c1: the shift is there before
    assert np.abs(after).max() < 1e-4, after
    assert np.abs(after).max() < 0.1 * np.abs(before).max(), (before, after)


def test_a_force_sensor_gain_error_still_leaves_the_estimate_unchanged() -> None:
    """A force channel 3 % high is absorbed by the multiplier and the profiled sample gain
    together (the estimate equals the one with a right sensor); taking the force samples
    unscaled instead -- the naive fix -- would not be."""
    right = _refined(True, 1.0)
    high = _refined(True, 1.03)
    np.testing.assert_allclose(high, right, atol=2e-6)


def test_projected_residuals_are_orthogonal_to_the_sample_pattern() -> None:
    """With a multiplier given, the hit column of the residuals has no component along
    the processed pulse samples, and the cost never exceeds the unprojected one."""
    from siva_core._impl.output_error.sample_gain import sample_gain_pattern

    st, truth, rec, proc = _clean_hit()
    prob = OutputErrorProblem.build(st, [rec], proc, theta_ref=truth[None])
    thetas = truth[None] * np.array([[1.0] * 7, [1.01] + [1.0] * 6])
    scales = np.array([0.97, 1.02])
    pattern = sample_gain_pattern(prob, 0)
    assert pattern is not None and np.any(pattern)
    old = set_sample_gain_profiling(False)
    try:
        raw, _ = prob.record_residuals(thetas, 0, scales)
    finally:
        set_sample_gain_profiling(old)
    proj, _ = prob.record_residuals(thetas, 0, scales)
    hit = prob.records[0].hit_dof
    n = st.n_dof
    col = proj.reshape(2, -1, n)[:, :, hit]
    assert np.abs(col @ pattern).max() < 1e-9 * np.linalg.norm(pattern) * np.abs(col).max() * col.shape[1]
    assert np.all(np.sum(proj ** 2, axis=1) <= np.sum(raw ** 2, axis=1) + 1e-15)
    # without a multiplier (a plain output error) nothing is projected
    plain, _ = prob.record_residuals(thetas, 0)
    old = set_sample_gain_profiling(False)
    try:
        plain_off, _ = prob.record_residuals(thetas, 0)
    finally:
        set_sample_gain_profiling(old)
    np.testing.assert_array_equal(plain, plain_off)


@pytest.mark.parametrize("sensors", ["disp"])
def test_nothing_is_projected_when_the_hit_dof_is_not_an_accelerometer(sensors: str) -> None:
    """Displacement sensors: the simulated accelerations are not compared, no pattern."""
    from siva_core._impl.output_error.sample_gain import sample_gain_pattern

    case = replace(CHAIN3_END_1K, sensors=sensors, noise=0.0, force_noise=0.0, hum=0.0)
    st = case.structure()
    rec = case.record(150.0, np.random.default_rng(0), name="hit")
    prob = OutputErrorProblem.build(st, [rec], choose_processing("auto", [rec], st.dofs),
                                    theta_ref=case.theta()[None])
    assert sample_gain_pattern(prob, 0) is None
