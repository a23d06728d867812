"""Streaming identification end to end on the real server, and the drift rule.

1. The paper's Duffing case through HTTP: the exact k = 300 and k_nl = 3e8 lie inside the
   reported 95 % intervals once the service has converged.
2. A stiffness loss (k 300 -> 240) streamed in afterwards raises a ``k decrease`` alarm,
   with the linear natural frequency falling accordingly (the CUSUM rule itself:
   tests/service/test_detector.py).
"""
from __future__ import annotations

import io
import math

import numpy as np
import pytest

from service.monitoring.drift import modal_quantities

TRUTH = {"b": 0.5, "b_nl": 4000.0, "k": 300.0, "k_nl": 3e8}
M = 0.05


@pytest.fixture(scope="module")
def srv(make_server):
    # a small replay buffer so that new records replace the old ones quickly (drift test)
    return make_server(env={"SIVA_REPLAY_WINDOW": "1", "SIVA_REPLAY_RESERVOIR": "0",
                            "SIVA_VALIDATION_WINDOW": "2", "SIVA_SNAPSHOT_EVERY": "2",
                            "SIVA_DRIFT_BASELINE_RECORDS": "3"})


def _register_and_upload(c, spec_of, duffing) -> None:
    r = c.put("/v1/systems/duffing", json=spec_of("duffing"))
    assert r.status_code in (200, 201), r.text
    for f, role in (("train_v5.csv", "train"), ("val_v3.csv", "validation"),
                    ("val_v8.csv", "validation")):
        r = c.post(f"/v1/systems/duffing/recordings?role={role}&name={f}", content=duffing(f),
                   headers={"content-type": "text/csv"})
        assert r.status_code == 202, r.text


def _converged_with(n: int):
    """Converged, and the Approach II ensemble holds at least ``n`` epochs."""
    return lambda e: (e["converged"] and e["ensemble_source"] == "approach_II"
                      and e.get("ensemble_state") == "final"
                      and all((s.get("n") or 0) >= n for s in e["ensemble"].values()))


@pytest.mark.heavy
def test_duffing_truth_inside_ci95(srv, spec_of, duffing, poll):
    with srv.client() as c:
        _register_and_upload(c, spec_of, duffing)
        # an upper bound, not a speed claim: idle CI passed within 240 s; on a loaded
        # machine (a benchmark beside CI, Ray's workers) 240 s was measured too short
        est = poll(c, "/v1/systems/duffing/estimate", _converged_with(60), timeout=600, every=1)
    assert est["ensemble_source"] == "approach_II"
    assert est["n_recordings"] == {"train": 1, "validation": 2}
    for p in ("k", "k_nl"):
        lo, hi = est["ensemble"][p]["ci95"]
        assert lo <= TRUTH[p] <= hi, (p, est["ensemble"][p])
    for p in ("b", "b_nl"):  # the damping terms: close, the paper's accuracy
        assert est["ensemble"][p]["mean"] == pytest.approx(TRUTH[p], rel=0.1), p
    # validation: the discriminator can no longer tell real from model (ln 4)
    assert est["discriminator"]["ln4_distance"] < 0.05
    f_true = math.sqrt(TRUTH["k"] / M) / (2 * math.pi)
    assert est["modal"]["frequency_hz"][0] == pytest.approx(f_true, rel=0.01)
    # healthy data: no drift alarm
    with srv.client() as c:
        assert c.get("/v1/systems/duffing/drift").json()["alarms"] == []


def _duffing_record(v0: float, k: float, T: float = 1.0, fs: float = 10_000.0) -> bytes:
    from scipy.integrate import solve_ivp

    b, bnl, knl = TRUTH["b"], TRUTH["b_nl"], TRUTH["k_nl"]

    def acc(x, v):
        return -(b * v + bnl * x * x * v + k * x + knl * x ** 3) / M

    t = np.arange(int(T * fs) + 1) / fs
    sol = solve_ivp(lambda _t, y: [y[1], acc(y[0], y[1])], (0, T), [0.0, v0], t_eval=t,
                    method="DOP853", rtol=1e-9, atol=1e-12)
    x, v = sol.y
    buf = io.StringIO()
    buf.write("time,disp_x,vel_x,acc_x\n")
    np.savetxt(buf, np.column_stack([t, x, v, acc(x, v)]), delimiter=",", fmt="%.10e")
    return buf.getvalue().encode()


def test_stiffness_loss_raises_an_alarm(srv, spec_of, duffing, poll):
    with srv.client() as c:
        _register_and_upload(c, spec_of, duffing)  # idempotent when the test above ran
        poll(c, "/v1/systems/duffing/drift", lambda d: d["reference"] is not None,
             timeout=240, every=1)
        ref = c.get("/v1/systems/duffing/drift").json()["reference"]
        assert ref["quantities"]["k"]["centre"] == pytest.approx(TRUTH["k"], rel=0.01)
        # the structure loses 20 % of its linear stiffness
        for v0, role in ((5.0, "train"), (3.0, "validation"), (8.0, "validation"),
                         (4.0, "train"), (6.0, "train")):
            r = c.post(f"/v1/systems/duffing/recordings?role={role}&name=damaged_v{v0:g}.csv",
                       content=_duffing_record(v0, k=240.0), headers={"content-type": "text/csv"})
            assert r.status_code == 202, r.text
        drift = poll(c, "/v1/systems/duffing/drift",
                     lambda d: "k" in d["active_alarms"], timeout=180, every=1)
    alarm = next(a for a in drift["alarms"] if a["parameter"] == "k")
    assert alarm["direction"] == "decrease"
    assert alarm["change_rel"] == pytest.approx(-0.2, abs=0.05)
    assert alarm["change_point"]["record_index"] == 4  # the first damaged record
    f_alarm = next(a for a in drift["alarms"] if a["parameter"] == "f1_hz")
    assert 1 + f_alarm["change_rel"] == pytest.approx(math.sqrt(0.8), rel=0.03)
    assert "k_nl" not in drift["active_alarms"]
    # the per-record series shows the move; reset forgets reference and alarms, keeps history
    ks = [r["parameters"]["k"] for r in drift["records"] if r["ok"]]
    assert max(ks) > 290 and min(ks) < 250
    with srv.client() as c:
        after = c.post("/v1/systems/duffing/drift/reset").json()
        assert after["reference"] is None and after["alarms"] == []
        assert len(after["history"]) >= len(drift["history"])


def test_modal_quantities_of_the_duffing_linearisation(spec_of):
    from siva_core import Structure

    s = Structure.from_dict(spec_of("duffing"))
    modes = modal_quantities(s, [TRUTH[p] for p in s.free])
    assert modes["frequency_hz"][0] == pytest.approx(math.sqrt(300 / M) / (2 * math.pi))
    assert modes["damping_ratio"][0] == pytest.approx(0.5 / (2 * math.sqrt(300 * M)))
    assert modal_quantities(s, [0.5, 4000.0, -300.0, 3e8]) is None  # no oscillatory mode
