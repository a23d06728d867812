"""Intervals that hold: block bootstrap, parametric noise replicates, the validation test."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import Recording, Structure
from siva_core._impl.bootstrap import (block_weights, bootstrap_covariance, phase_randomized,
                                       series_of)
from siva_core._impl.validation import validation_score, white_noise_sigma

SDOF = {"name": "sdof", "dofs": ["x"], "mass": {"x": 1.0}, "elements": [
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
    {"kind": "cubic_spring", "between": ["x", "ground"], "params": {"k3": "k3"}}]}
TRUTH = {"k": 1.0e4, "c": 3.0, "k3": 2.0e9}


def test_block_weights_keep_each_record_weight_and_blocks():
    series = series_of([(100, 2), (37, 1)])
    w = block_weights(series, 10, np.random.default_rng(0))
    assert w.shape == (237,)
    first = w[:200].reshape(100, 2)
    np.testing.assert_allclose(first[:, 0], first[:, 1])  # DOFs of a time go together
    assert first.sum() == pytest.approx(200) and w[200:].sum() == pytest.approx(37)


def test_block_bootstrap_sees_correlated_noise_that_gauss_newton_misses():
    """A straight-line fit to AR(1) noise (rho 0.95): the iid formula is ~6x too narrow;
    the block bootstrap's std must be within 35 % of the Monte-Carlo truth."""
    rng = np.random.default_rng(1)
    T = 2000
    t = np.linspace(-1, 1, T)
    J = np.stack([np.ones(T), t], axis=1)

    def ar1() -> np.ndarray:
        e = np.zeros(T)
        z = rng.standard_normal(T)
        for i in range(1, T):
            e[i] = 0.95 * e[i - 1] + z[i]
        return e

    fits = np.array([np.linalg.lstsq(J, ar1(), rcond=None)[0] for _ in range(300)])
    mc_std = fits.std(axis=0)
    e = ar1()
    r = e - J @ np.linalg.lstsq(J, e, rcond=None)[0]
    iid_std = np.sqrt(np.diag(np.linalg.inv(J.T @ J)) * (r @ r) / (T - 2))
    cov, L = bootstrap_covariance(J, r, series_of([(T, 1)]), n_boot=300, seed=2)
    boot_std = np.sqrt(np.diag(cov))
    assert np.all(iid_std < 0.4 * mc_std)
    np.testing.assert_allclose(boot_std, mc_std, rtol=0.35)
    assert L > 10


def test_phase_randomised_residuals_keep_the_spectrum():
    rng = np.random.default_rng(3)
    r = np.convolve(rng.standard_normal(4096), np.ones(8) / 8, mode="same")
    s = phase_randomized(r, series_of([(4096, 1)]), rng)
    assert np.std(s) == pytest.approx(np.std(r), rel=1e-6)
    np.testing.assert_allclose(np.abs(np.fft.rfft(s))[1:], np.abs(np.fft.rfft(r - r.mean()))[1:],
                               rtol=1e-6)
    assert abs(np.corrcoef(r, s)[0, 1]) < 0.1


def test_white_noise_level_is_read_under_a_smooth_response():
    t = np.arange(8192) / 1024
    rng = np.random.default_rng(4)
    signal = 3.0 * np.exp(-t) * np.sin(2 * np.pi * 12 * t) + 0.5 * np.sin(2 * np.pi * 60 * t)
    assert white_noise_sigma(signal + 0.01 * rng.standard_normal(t.size)) == pytest.approx(0.01, rel=0.1)


def _impact(st: Structure, truth: dict, amp: float, rng: np.random.Generator) -> Recording:
    from siva_core import simulate

    fs, n = 1024.0, 2048
    t = np.arange(n) / fs
    f = np.zeros((n, 1))
    x = (t - 0.05) / 5e-3
    f[:, 0] = np.where((x >= 0) & (x <= 1), amp * np.sin(np.pi * np.clip(x, 0, 1)), 0)
    sim = simulate(st, st.vector(truth), t, np.zeros(1), np.zeros(1), f, substeps="auto")
    a = np.asarray(sim.a)[:, 0]
    return Recording(t, {"acc_x": a + 0.003 * np.abs(a).max() * rng.standard_normal(n),
                         "force_x": f[:, 0] + 0.002 * amp * rng.standard_normal(n)}, f"imp{amp:g}")


@pytest.fixture(scope="module")
def sdof_fit():
    from siva_core import refine
    from siva_core import choose_processing

    st = Structure.from_dict(SDOF)
    rng = np.random.default_rng(5)
    recs = [_impact(st, TRUTH, a, rng) for a in (120.0, 60.0, 200.0)]
    proc = choose_processing("auto", recs, st.dofs)
    res = refine(st, st.vector(TRUTH) * 1.02, recs[:1], proc, fit_force_scale=True)
    return st, recs, proc, res


def test_best_interval_is_bootstrap_and_covers(sdof_fit):
    st, _, _, res = sdof_fit
    truth = st.vector(TRUTH)
    assert res.uncertainty == "bootstrap"
    assert np.all(res.std > 0) and np.all(res.std >= 0.5 * res.std_gauss_newton)
    assert np.all((res.ci95[:, 0] < truth) & (truth < res.ci95[:, 1])), (res.ci95, truth)
    corr = res.correlation
    np.testing.assert_allclose(np.diag(corr), 1.0, atol=1e-9)


def test_validation_accepts_the_right_model_and_rejects_a_wrong_one(sdof_fit):
    st, recs, proc, res = sdof_fit
    right = validation_score(st, res.theta, recs[1:], proc)
    assert right["accepted"] and right["statistic"] < 1.5, right
    assert set(right["records"]) == {"imp60", "imp200"}
    wrong = res.theta * np.array([1.0, 1.0, 0.5])  # half the cubic stiffness
    bad = validation_score(st, wrong, recs[1:], proc)
    assert not bad["accepted"] and bad["statistic"] > 5 * right["statistic"], bad


def test_approach_ii_interval_is_widened_to_a_floor_never_narrowed():
    from siva_core._impl.ensemble import normal_summary, widened_to

    rng = np.random.default_rng(3)
    samples = rng.normal([1.0, 10.0], [0.01, 0.5], size=(400, 2))
    summ = normal_summary(samples, ["a", "b"], ess=False)
    out = widened_to(summ, ["a", "b"], np.array([0.05, 0.1]))
    assert out["a"]["std"] == 0.05 and out["a"]["std_samples"] == summ["a"]["std"]
    lo, hi = out["a"]["ci95"]
    assert abs((hi - lo) / 2 - 1.959963984540054 * 0.05) < 1e-12
    assert out["b"] == summ["b"]  # already wider than its floor: unchanged
    assert "std_samples" not in summ["a"]  # the input is not modified
