"""Candidate work on the cores (issue 16, speed): the scans, fits, judgements and pair fits
that do not read each other run in threads, on schedules fixed by the settings, so the
diagnosis is the same with any number of workers."""
from __future__ import annotations

import json
import warnings

import pytest

from siva_core import DiagnoseSettings, Structure, diagnose, synthetic_impacts, with_effect
from siva_core._impl.diagnose.parallel import ENV, run_each, waves, worker_count

TWO = {"name": "two", "dofs": ["a", "b"], "mass": {"a": 1.0, "b": 0.5},
       "elements": [{"kind": "spring", "between": ["a", "ground"], "params": {"k": "k1"}},
                    {"kind": "damper", "between": ["a", "ground"], "params": {"c": "c1"}},
                    {"kind": "spring", "between": ["a", "b"], "params": {"k": "k2"}},
                    {"kind": "damper", "between": ["a", "b"], "params": {"c": "c2"}}]}
NOMINAL = {"k1": 4000.0, "c1": 0.8, "k2": 3000.0, "c2": 0.4}


def test_waves_are_fixed_by_the_size_not_the_workers():
    assert waves(list("abcdefg"), 4) == [["a"], ["b", "c", "d", "e"], ["f", "g"]]
    assert waves(list("abc"), 2, first_alone=False) == [["a", "b"], ["c"]]
    assert waves([], 3) == []


def test_run_each_keeps_the_order_and_raises(monkeypatch):
    assert run_each(lambda x: x * x, range(7), 3) == [x * x for x in range(7)]
    with pytest.raises(ZeroDivisionError):
        run_each(lambda x: 1 / x, [1, 0, 2], 2)
    monkeypatch.setenv(ENV, "3")
    assert worker_count(DiagnoseSettings()) == 3
    assert worker_count(DiagnoseSettings(workers=1)) == 1
    monkeypatch.setenv(ENV, "x")
    assert worker_count(DiagnoseSettings()) >= 1


def _run(model, train, val, workers: int) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = diagnose(model, train, val, "auto",
                       settings=DiagnoseSettings(workers=workers)).to_json()
    return _untimed(out)


def _untimed(x):
    """The diagnosis without its wall-clock entries (``timing_s``, ``fit_time_s``)."""
    if isinstance(x, dict):
        return {k: _untimed(v) for k, v in x.items() if not k.endswith("time_s")
                and k != "timing_s"}
    if isinstance(x, list):
        return [_untimed(v) for v in x]
    return x


def test_the_diagnosis_does_not_depend_on_the_worker_count():
    """A hardening spring a-b on a 2-DOF model: every ranked candidate's closure and
    train cost, the verdict and its coefficients are the same with 1 and 2 workers."""
    model = Structure.from_dict(TWO)
    gen = with_effect(model, "cubic_spring", ("a", "b"), {"k3": 2.0e6})
    theta = gen.vector(NOMINAL)
    recs = synthetic_impacts(gen, theta, [150.0, 300.0, 220.0], dof="a", fs=400.0,
                             duration=1.5, seed=3)
    train, val = recs[:2], recs[2:]
    one, two = _run(model, train, val, 1), _run(model, train, val, 2)
    assert one["verdict"] is not None, one["rule"]
    assert (one["verdict"]["kind"], one["verdict"]["between"]) == ("cubic_spring", ["a", "b"])
    assert len(one["ranking"]) >= 3  # several candidates were fitted (in parallel)
    assert json.dumps(one, sort_keys=True, default=str) == \
        json.dumps(two, sort_keys=True, default=str)
