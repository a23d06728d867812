"""Equation-error baselines (least squares, SINDy) recover exact parameters from exact states."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from siva_core import Processing, Recording, States, Structure
from siva_core import FitResult, least_squares, sindy


def _states(q, v, a, f, name="synthetic") -> States:
    t = np.arange(len(q)) * 1e-3
    return States(t, q, v, a, f, name)


def _random_states(structure: Structure, theta: np.ndarray, n: int, seed: int,
                   q_scale: float = 1e-3, v_scale: float = 0.1, f_scale: float = 1.0) -> States:
    """Samples (q, v, F) and the model's exact a: all equation error needs."""
    rng = np.random.default_rng(seed)
    q = q_scale * rng.standard_normal((n, structure.n_dof))
    v = v_scale * rng.standard_normal((n, structure.n_dof))
    f = f_scale * rng.standard_normal((n, structure.n_dof))
    a = structure.accelerations(theta, q, v, f)
    return _states(q, v, a, f)


@pytest.fixture(scope="module")
def duffing_states(shared_data, duffing_model):
    rec = Recording.read(shared_data / "duffing" / "train_v5.csv", duffing_model.dofs)
    truth = json.loads((shared_data / "duffing" / "truth.json").read_text())["truth"]
    return Processing().apply(rec, duffing_model.dofs), truth


@pytest.mark.parametrize("method", [least_squares, sindy])
def test_duffing_exact_within_half_percent(duffing_model, duffing_states, method):
    states, truth = duffing_states
    fit = method(duffing_model, [states])
    assert isinstance(fit, FitResult) and list(fit) == duffing_model.free
    assert fit.fit_time_s > 0
    for k, v in truth.items():
        assert fit[k] == pytest.approx(v, rel=5e-3), (method.__name__, k, fit[k], v)


@pytest.mark.parametrize("method", [least_squares, sindy])
def test_lono_free_response_with_beta(shared_data, lono_model, method):
    """Two DOFs, a power-law spring (beta nonlinear), exact states after the impact."""
    truth = json.loads((shared_data / "lono" / "truth.json").read_text())["truth"]
    clean = Recording.read(shared_data / "lono" / "impact_899N_clean.csv", lono_model.dofs)
    noisy = Recording.read(shared_data / "lono" / "impact_899N.csv", lono_model.dofs)
    rec = Recording(clean.time, {**clean.channels, "force_NO": noisy.channels["force_NO"]}, "x")
    states = Processing(start="impact", gate_force=True).apply(rec, lono_model.dofs)
    assert np.all(states.f == 0)
    fit = method(lono_model, [states])
    for k, v in truth.items():
        assert fit[k] == pytest.approx(v, rel=5e-3), (method.__name__, k, fit[k], v)


def test_columns_normalised_scale_and_force_gain(silverbox_model):
    """Mass-normalised model, parameters from 1e-1 to 1e6 and an identified force gain."""
    theta = np.array([3.0, 2.5e5, -3.0e3, 1.2e6, 40.0])  # c, k1, k2, k3, g
    states = _random_states(silverbox_model, theta, 3000, seed=2, q_scale=1e-2,
                            v_scale=5.0, f_scale=0.1)
    for method in (least_squares, sindy):
        fit = method(silverbox_model, [states])
        np.testing.assert_allclose(silverbox_model.vector(fit), theta, rtol=1e-8)


def test_clearance_gap_is_found():
    spec = {"name": "gap", "dofs": ["x"], "mass": {"x": 0.5}, "elements": [
        {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
        {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
        {"kind": "clearance", "between": ["x", "ground"], "params": {"k": "k_c", "gap": "gap"}}]}
    s = Structure.from_dict(spec)
    theta = np.array([1.0e3, 2.0, 5.0e4, 1.5e-3])  # k, c, k_c, gap
    states = _random_states(s, theta, 4000, seed=3, q_scale=2e-3)
    fit = least_squares(s, [states])
    np.testing.assert_allclose(s.vector(fit), theta, rtol=1e-3)


def test_fixed_and_shared_parameters():
    spec = {"name": "chain", "dofs": ["a", "b"], "mass": {"a": 1.0, "b": 3.0}, "elements": [
        {"kind": "spring", "between": ["a", "ground"], "params": {"k": "k"}},
        {"kind": "spring", "between": ["a", "b"], "params": {"k": "k"}},
        {"kind": "damper", "between": ["a", "b"], "params": {"c": "c"}},
        {"kind": "cubic_spring", "between": ["b", "ground"], "params": {"k3": "k3"}}],
        "parameters": {"c": {"fixed": 0.7}}}
    s = Structure.from_dict(spec)
    assert s.free == ["k", "k3"]
    theta = np.array([500.0, 2e7])
    states = [_random_states(s, theta, 500, seed=k) for k in range(3)]
    for method in (least_squares, sindy):
        fit = method(s, states)
        assert list(fit) == ["k", "k3"]
        np.testing.assert_allclose(s.vector(fit), theta, rtol=1e-8)
    per_eq = sindy(s, states).extra["per_equation"]
    assert set(per_eq["k"]) == {"a", "b"}  # k seen in both equations, averaged


def test_noisy_accelerations_unbiased_on_average(sdof_model):
    """Noise on a (not on q, v) leaves least squares unbiased."""
    theta = np.array([2.0e3, 4.0])
    states = _random_states(sdof_model, theta, 20000, seed=5)
    rng = np.random.default_rng(6)
    states.a = states.a + 0.05 * np.std(states.a) * rng.standard_normal(states.a.shape)
    fit = least_squares(sdof_model, [states])
    np.testing.assert_allclose(sdof_model.vector(fit), theta, rtol=2e-2)
    assert fit.residual_rms > 0


def test_beta_from_a_poor_start(lono_model):
    """beta far from the middle of the scan is still found (grid then refinement)."""
    theta = np.array([3.8, 1.9e4, 0.8, 1.9e3, 4.0e4, 0.6])
    states = _random_states(lono_model, theta, 3000, seed=7, q_scale=2e-2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = least_squares(lono_model, [states])
    np.testing.assert_allclose(lono_model.vector(fit), theta, rtol=1e-4)
