"""The service runs ``siva identify``'s two-phase SIVA, and says what it can judge.

Live (a real ``siva serve``): the trainer goes equation error -> first ``best`` -> the
output-error phase anchored at it; the ensemble has no ``ci95`` until it is final; the
validation verdict (T, p-value) is published in the estimate and in /metrics; the event
log holds the anchor and ``siva replay`` reproduces the live ensemble exactly.
Units: the forming-baseline change test of the drift detector, the read-outs.
"""
from __future__ import annotations

import time
from pathlib import Path

import importlib.util

import numpy as np
import pytest

# this folder's conftest by path: ``from conftest import`` takes whichever conftest pytest
# imported last (tests/instruments has one too)
_spec = importlib.util.spec_from_file_location("_service_conftest",
                                               Path(__file__).with_name("conftest.py"))
_conftest = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_conftest)
linear_spec, oscillator_csv = _conftest.linear_spec, _conftest.oscillator_csv

from service.monitoring.detector import YOUNG_Z, ChangeDetector, DetectorSettings
from service.trainer.readout import ENSEMBLE_MIN_SAMPLES, read_ensemble
from service.trainer.validation import validation_view


# --------------------------------------------------------------------------- live
@pytest.mark.slow  # ~40 s on an idle 2-core machine (both phases, validation, a replay)
def test_two_phases_provisional_validation_and_exact_replay(make_server, tmp_path: Path):
    from service.storage.eventlog import TOPIC_ANCHOR, read_events
    from service.replay.run import replay

    srv = make_server(env={"SIVA_SNAPSHOT_EVERY": "5", "SIVA_IDLE_AFTER_EPOCHS": "40"},
                      data_dir=tmp_path / "data")
    with srv.client() as c:
        assert c.put("/v1/systems/osc", json=linear_spec()).status_code == 201
        for role, v0 in (("train", 1.0), ("validation", 0.7)):
            r = c.post("/v1/systems/osc/recordings", params={"role": role},
                       content=oscillator_csv(v0=v0), headers={"content-type": "text/csv"})
            assert r.status_code == 202, r.text
        seen_provisional = False
        deadline = time.monotonic() + 400
        while True:
            est = c.get("/v1/systems/osc/estimate").json()
            ens = est.get("ensemble") or {}
            if est.get("ensemble_state") == "provisional":
                seen_provisional = True
                # nothing looks like a 95 % interval before it is one
                assert all("ci95" not in s for s in ens.values()), ens
                if est.get("estimate_source") != "best":
                    assert est["provisional"] is True
                    # (the contract keeps the key: null)
                    assert all(s.get("ci95") is None for s in est["parameters"].values())
            if (est.get("ensemble_state") == "final" and est.get("phase") == "output_error"
                    and (est.get("validation") or {}).get("status") == "done"
                    and est.get("state") == "idle"):
                break
            assert time.monotonic() < deadline, f"not final: {est.get('phase')} " \
                f"{est.get('ensemble_state')} {est.get('validation', {}).get('status')}"
            time.sleep(0.5)
        assert seen_provisional
        assert all(len(s["ci95"]) == 2 for s in est["ensemble"].values())
        assert est["ensemble_samples"] >= ENSEMBLE_MIN_SAMPLES
        assert est["anchor"]["source"] == "headline"  # after the per-record fits, settled
        val = est["validation"]
        assert val["verdict"] in ("accepted", "rejected") and val["of"] == "headline"
        assert val["T"] is not None and 0.0 <= val["p_value"] <= 1.0
        assert val["per_record"] and val["per_record"][0]["T"] is not None
        assert val["ensemble"]["verdict"] in ("accepted", "rejected")
        assert "not a validation" in val["discriminator"]["what"]
        assert est["model_rejected"] is (val["verdict"] == "rejected")
        assert est["agreement"]["status"] in ("agree", "differ") and est["agreement"]["why"]
        # a new record: the refiner fits it, then re-anchors at the headline (networks warm)
        first_anchor = est["anchor"]
        r = c.post("/v1/systems/osc/recordings", params={"role": "train"},
                   content=oscillator_csv(v0=1.3), headers={"content-type": "text/csv"})
        assert r.status_code == 202
        while True:
            est = c.get("/v1/systems/osc/estimate").json()
            a = est.get("anchor") or {}
            if (a.get("source") == "headline" and a["data_version"] > first_anchor["data_version"]
                    and est.get("ensemble_state") == "final"
                    and (est.get("validation") or {}).get("status") == "done"):
                break
            assert time.monotonic() < deadline + 200, f"no re-anchor: {a}"
            time.sleep(0.5)
        assert len(a["train"]) == 2 and est["epoch"] > 0
        metrics = c.get("/metrics").text
        assert 'siva_validation_statistic{of="headline",record="all",system="osc"}' in metrics
        assert 'siva_ensemble_final{system="osc"} 1.0' in metrics
        assert "siva_model_rejected{" in metrics
    srv.stop()
    logs = sorted((tmp_path / "data" / "logs" / "osc").glob("*.mcap"))
    anchors = [e.event for f in logs for e in read_events(f) if e.topic == TOPIC_ANCHOR]
    assert [a.source for a in anchors][:2] == ["headline", "headline"] and anchors[0].n_noise > 0
    out = replay(logs)
    cmp = out["replay"]["compared_to_log"]
    assert cmp["identical"], cmp
    assert out["phase"] == "output_error" and out["ensemble_state"] == "final"


# --------------------------------------------------------------------------- units
def _detector() -> ChangeDetector:
    return ChangeDetector(["k1", "b1"], DetectorSettings(baseline_records=10))


def _feed(det: ChangeDetector, rng: np.random.Generator, n: int, k1: float) -> list[dict]:
    out = []
    for _ in range(n):
        i = len(det.records)
        out += det.observe({"id": f"r{i}", "index": i},
                           {"k1": k1 * (1 + 2e-4 * rng.standard_normal()),
                            "b1": 3.84 * (1 + 0.01 * rng.standard_normal())},
                           {"k1": 2.0, "b1": 0.04})
    return out


def test_change_inside_the_forming_baseline_is_alarmed():
    rng = np.random.default_rng(7)
    det = _detector()
    assert _feed(det, rng, 3, 19273.0) == []
    assert _feed(det, rng, 1, 19273.0 * 0.85) == []   # one record after: not yet
    (alarm,) = _feed(det, rng, 1, 19273.0 * 0.85)      # the second confirms
    assert alarm["parameter"] == "k1" and alarm["young"] and alarm["direction"] == "decrease"
    assert alarm["change_point"]["record_index"] == 3
    assert alarm["change_rel"] == pytest.approx(-0.15, abs=0.01)
    assert "baseline was still forming" in alarm["message"]
    assert det.baseline is None and len(det.base["k1"]) == 2  # restarts after the change
    # the young alarm stays active through the baseline that forms after it
    _feed(det, rng, 12, 19273.0 * 0.85)
    assert det.baseline is not None and [a["active"] for a in det.alarms] == [True]


def test_forming_baseline_static_and_too_short():
    rng = np.random.default_rng(11)
    alarms = 0
    for _ in range(50):
        det = _detector()
        alarms += len(_feed(det, rng, 12, 19273.0))
    assert alarms == 0
    det = _detector()
    _feed(det, rng, 1, 19273.0)
    assert _feed(det, rng, 3, 19273.0 * 0.85) == []  # one reference record: cannot judge
    assert det.report()["young_baseline"]["threshold_z"] == YOUNG_Z


class _Ens:
    def __init__(self, n: int) -> None:
        rng = np.random.default_rng(0)
        self.samples = np.array([1.0, 300.0]) * (1 + 0.01 * rng.standard_normal((n, 2)))

    def __len__(self) -> int:
        return len(self.samples)


class _Trainer:
    def __init__(self, n: int, converged: bool, oe: bool) -> None:
        self.ensemble, self.converged, self.epoch = _Ens(n), converged, 100
        self.oe = object() if oe else None
        self.settings = type("S", (), {"fit_target": "output"})()


def test_ensemble_is_provisional_until_final(make_structure=None):
    from siva_core import Structure

    st = Structure.from_dict(linear_spec())
    for n, conv, oe, final in ((50, True, False, False), (10, True, True, False),
                               (50, False, True, False), (50, True, True, True)):
        r = read_ensemble(st, _Trainer(n, conv, oe))
        assert r.final is final
        assert all(("ci95" in s) is final for s in r.to_json().values())


def test_validation_view_before_and_after():
    v = validation_view(None, None, {"loss_d": 1.38}, "waiting")
    assert v["verdict"] is None and v["status"] == "pending" and v["reason"] == "waiting"
    assert v["discriminator"]["loss_d"] == 1.38
