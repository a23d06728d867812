"""The frozen values a trainer publishes (issue 18: typed seams between service layers):
they pickle (the Ray executor ships them), and their JSON keeps the published shape."""
from __future__ import annotations

import dataclasses
import pickle

import pytest

from service.monitoring.drift import EstimateHistory, HistoryPoint
from service.trainer import DriftReport, Snapshot, base_snapshot
from service.trainer.published import DataView


def _point(epoch: int) -> HistoryPoint:
    return HistoryPoint(epoch, 100.0 + epoch, epoch > 2, {"k1": {"mean": 1.0 * epoch}},
                        "best", {"k1": {"mean": 2.0}}, "final", None)


def test_base_snapshot_json_has_only_the_keys_of_a_system_without_estimate() -> None:
    snap = base_snapshot("s", "starting")
    body = snap.to_json({"train": 2, "validation": 1})
    assert list(body)[:5] == ["parameters", "discriminator", "epoch", "converged",
                              "n_recordings"]
    assert body["n_recordings"] == {"train": 2, "validation": 1}
    assert set(body) == {"parameters", "discriminator", "epoch", "converged", "n_recordings",
                         "system", "state", "converged_at", "estimate_source", "error", "time",
                         "provisional"}
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.state = "running"  # type: ignore[misc]


def test_snapshot_blocks_appear_with_their_data() -> None:
    snap = Snapshot(system="s", state="training", epoch=7, ensemble={"k1": {"mean": 1.0}},
                    ensemble_source="approach_II", ensemble_state="provisional",
                    phase="output_error", ensemble_samples=3, fixed={}, anchor=None,
                    data=DataView(("r1",), ("r2",), 10, 5, None, 2, {}),
                    estimate={"source": "ensemble"}, modal=None, best=None,
                    alarms=({"parameter": "k1", "active": True},))
    body = snap.to_json()
    assert body["anchor"] is None and "losses" not in body and body["modal"] is None
    assert body["data"]["train"] == ["r1"] and body["alarms"][0]["parameter"] == "k1"
    assert "seconds_per_epoch" not in body and "best_error" not in body
    assert pickle.loads(pickle.dumps(snap)) == snap


def test_drift_report_limits_its_history_and_pickles() -> None:
    hist = EstimateHistory(limit=3)
    for e in range(5):
        hist.add(_point(e))
    assert [p.epoch for p in hist.last()] == [2, 3, 4]
    rep = DriftReport(n_records=4, history=hist.last(), young_baseline=None)
    body = rep.to_json(history_limit=2)
    assert [h["epoch"] for h in body["history"]] == [3, 4] and "young_baseline" not in body
    assert pickle.loads(pickle.dumps(rep)) == rep
    again = EstimateHistory(limit=3)
    again.load_state_dict(hist.state_dict())
    assert again.last() == hist.last()


def test_the_monitor_headline_becomes_the_same_best_as_its_json_did() -> None:
    """``best_from_headline`` (typed) gives the Best the old JSON view gave via best_from."""
    from service.monitoring.monitor_values import HeadlineEstimate
    from service.trainer.types import best_from, best_from_headline

    h = HeadlineEstimate(parameters={"k1": {"mean": 2.0, "std": 0.1, "ci95": [1.8, 2.2], "n": 4},
                                     "c1": {"mean": 0.5, "std": None, "ci95": None, "n": 1}},
                         modal={"f1": 3.0}, records=("r1", "r2"), n_records=2, first_index=0,
                         last_index=1, time=123.0, method="weighted mean")
    old_json = {"parameters": {p: {"value": s["mean"], "std": s["std"], "ci95": s["ci95"],
                                   "n": s.get("n")} for p, s in h.parameters.items()},
                "epoch": 9, "n_records": 2, "time": 123.0, "records": ["r1", "r2"],
                "output_error": None, "refined": True, "source": "records",
                "method": "weighted mean", "modal": {"f1": 3.0}}
    typed = best_from_headline(h, 9)
    assert typed is not None and typed == best_from(old_json)
    assert typed.to_json()["parameters"]["k1"]["ci95"] == [1.8, 2.2]
    assert best_from_headline(None, 9) is None
    assert HeadlineEstimate.from_json(h.to_json()) == h
