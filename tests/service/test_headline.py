"""The headline estimate: which source is published, and the per-record combination."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from service.trainer.estimate import headline
from service.monitoring.monitor import combine


@pytest.fixture
def structure():
    from siva_core import Structure

    return Structure.from_dict({
        "name": "osc", "dofs": ["x"], "mass": {"x": 0.05},
        "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                     {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]})


ENSEMBLE = {"c": {"mean": 0.4, "std": 0.01, "ci95": [0.38, 0.42], "ess": 5.0, "n": 60},
            "k": {"mean": 310.0, "std": 1.0, "ci95": [308.0, 312.0], "ess": 5.0, "n": 60}}


def test_ensemble_until_best_then_best(structure):
    h = headline(structure, ENSEMBLE, "approach_II", None)
    assert h["estimate_source"] == "ensemble" and h["parameters"] == ENSEMBLE
    assert "no output-error estimate" in h["estimate"]["note"]
    assert headline(structure, {}, "generator", None)["estimate_source"] == "generator"
    best = {"parameters": {"c": {"value": 0.5, "std": 0.001, "ci95": [0.498, 0.502], "n": 4},
                           "k": {"value": 300.0, "std": 0.1, "ci95": [299.8, 300.2], "n": 4}},
            "time": 1.0, "records": ["r1", "r2"], "method": "m"}
    h = headline(structure, ENSEMBLE, "approach_II", best)
    assert h["estimate_source"] == "best" and h["ensemble"] == ENSEMBLE
    assert h["parameters"]["k"] == {"mean": 300.0, "std": 0.1, "ci95": [299.8, 300.2], "n": 4}
    assert h["estimate"]["records"] == ["r1", "r2"] and h["estimate"]["age_s"] > 0


def test_combine_weights_and_honest_interval():
    # equal errors, scatter larger than they claim: the empirical error and t quantile win
    x = np.array([1.0, 1.2, 0.8, 1.1, 0.9])
    out = combine(x, np.full(5, 0.01))
    sd = np.std(x, ddof=1) / np.sqrt(5)
    assert out["mean"] == pytest.approx(1.0) and out["std"] == pytest.approx(sd)
    q = stats.t.ppf(0.975, 4)
    assert out["ci95"] == pytest.approx([1.0 - q * sd, 1.0 + q * sd])
    # errors that explain the scatter: precision weights, 1.96
    out = combine(np.array([1.0, 2.0]), np.array([1.0, 3.0]))
    w = np.array([1.0, 1 / 9])
    assert out["mean"] == pytest.approx((1.0 * w[0] + 2.0 * w[1]) / w.sum())
    assert out["std"] == pytest.approx(np.sqrt(1 / w.sum()))
    # one record, no error: no interval rather than a fake one
    assert combine(np.array([3.0]), np.array([np.nan]))["ci95"] is None
