"""Monitoring on the real server: the headline estimate, drift alarms, idling.

A linear oscillator (cheap free decays with 0.5 % noise) streamed into ``siva serve`` with
a small baseline (4 records):
1. ``parameters`` is the output-error ``best`` once there is one (source and records
   stated), the ensemble stays under ``ensemble``; ``siva-client wait --for best`` waits
   for it.
2. No change: no alarm.  A 15 % stiffness loss: an alarm naming k (and the mode's
   frequency), not c; with a change point at the first damaged record; ``/drift`` carries
   the headline and the alarm history; reset starts a new baseline.
3. Idle: converged, nothing new -> the server process uses < 5 % of a core.
"""
from __future__ import annotations

import io
import json
import time

import numpy as np
import psutil
import pytest

from synthetic import free_decay

M, K, C = 0.05, 300.0, 0.5


def noisy_decay(v0: float, k: float, seed: int, noise: float = 0.005) -> bytes:
    rec = free_decay(v0, 2000, 2000.0, m=M, k=k, c=C)
    rng = np.random.default_rng(seed)
    for name, x in rec.channels.items():
        rec.channels[name] = x + noise * np.max(np.abs(x)) * rng.standard_normal(len(x))
    return rec.to_csv().encode()


def spec() -> dict:
    return {"name": "osc", "dofs": ["x"], "mass": {"x": M},
            "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                         {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}


@pytest.fixture(scope="module")
def srv(make_server):
    return make_server(env={"SIVA_DRIFT_BASELINE_RECORDS": "4", "SIVA_IDLE_AFTER_EPOCHS": "20",
                            "SIVA_SNAPSHOT_EVERY": "5"})


def _upload(c, k: float, i: int, role: str) -> None:
    r = c.post(f"/v1/systems/osc/recordings?role={role}&name=r{i}.csv",
               content=noisy_decay(0.5 + 0.05 * (i % 7), k, seed=i),
               headers={"content-type": "text/csv"})
    assert r.status_code == 202, r.text


@pytest.mark.heavy
def test_headline_drift_and_idle(srv, poll):
    with srv.client() as c:
        assert c.put("/v1/systems/osc", json=spec()).status_code in (200, 201)
        est = c.get("/v1/systems/osc/estimate").json()
        assert est["best"] is None and est["estimate_source"] in (None, "ensemble", "generator")
        for i in range(6):
            _upload(c, K, i, "validation" if i % 3 == 2 else "train")
        # ``wait --for best`` returns once the headline is best, not merely at convergence
        from clients.cli import build_parser, run

        buf = io.StringIO()
        assert run(build_parser().parse_args(["--url", srv.base_url, "wait", "osc", "--for",
                                              "best", "--max-wait", "150", "--json"]), out=buf) == 0
        waited = json.loads(buf.getvalue())
        assert waited["estimate_source"] == "best" and waited["best"] is not None
        # headline: best, with its source, records and interval; ensemble kept apart
        est = poll(c, "/v1/systems/osc/estimate",
                   lambda e: e["estimate_source"] == "best" and e["best"]["source"] == "records"
                   and e["monitoring"]["processed_index"] >= 6, timeout=150, every=1)
        assert est["estimate"]["records"] and est["estimate"]["time"] > 0
        assert set(est["ensemble"]) == {"c", "k"}
        for p, truth in (("k", K), ("c", C)):
            s = est["parameters"][p]
            assert s["mean"] == pytest.approx(truth, rel=0.02), (p, s)
            assert s["ci95"][0] <= truth <= s["ci95"][1], (p, s)
        drift = c.get("/v1/systems/osc/drift").json()
        assert drift["reference"] is not None and drift["alarms"] == []
        assert drift["headline"]["estimate_source"] == "best"
        assert len(drift["records"]) == 6
        # idle: converged, records fitted, nothing new -> (almost) no CPU
        poll(c, "/v1/systems/osc/estimate", lambda e: e["state"] == "idle", timeout=120, every=1)
        proc = psutil.Process(srv.proc.pid)
        t0, cpu0 = time.monotonic(), sum(proc.cpu_times()[:2])
        time.sleep(5.0)
        used = (sum(proc.cpu_times()[:2]) - cpu0) / (time.monotonic() - t0)
        assert used < 0.05, f"idle server used {used:.1%} of a core"
        # 15 % stiffness loss: an alarm on k (and the frequency), none on c
        for i in range(6, 12):
            _upload(c, 0.85 * K, i, "train")
        drift = poll(c, "/v1/systems/osc/drift", lambda d: d["processed_index"] >= 12,
                     timeout=120, every=1)
        est = c.get("/v1/systems/osc/estimate").json()
    alarmed = {a["parameter"] for a in drift["alarms"]}
    assert "k" in alarmed and "f1_hz" in alarmed and "c" not in alarmed, drift["alarms"]
    k_alarm = next(a for a in drift["alarms"] if a["parameter"] == "k")
    assert k_alarm["direction"] == "decrease" and k_alarm["state"] in ("raised", "confirmed")
    assert k_alarm["change_rel"] == pytest.approx(-0.15, abs=0.02)
    assert k_alarm["change_point"]["record_index"] == 7  # store index (1-based) of the first damaged
    assert "k" in [a["parameter"] for a in est["alarms"]]
    # the headline follows the change (window restarts at the change point)
    assert est["parameters"]["k"]["mean"] == pytest.approx(0.85 * K, rel=0.02)
    with srv.client() as c:
        after = c.post("/v1/systems/osc/drift/reset").json()
    assert after["reference"] is None and after["alarms"] == []
    srv.assert_no_bugs()
    # ``siva replay`` of the event log carries the logged headline and the alarm history
    from service.replay.run import replay

    srv.stop()
    logs = sorted(srv.data_dir.rglob("*osc*.mcap")) or sorted(srv.data_dir.rglob("*.mcap"))
    rep = replay(logs)
    assert rep["estimate_source"] == "best" and rep["best"] is not None
    assert rep["ensemble"] and set(rep["ensemble"]) == {"c", "k"}
    assert "k" in {a["parameter"] for a in rep["alarm_history"]}
    print(f"\nidle CPU {used:.2%} of a core; alarms: "
          + "; ".join(a["message"] for a in drift["alarms"]))
