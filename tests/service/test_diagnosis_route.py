"""GET /v1/systems/{name}/diagnosis against a real server: progress while it runs in the
background, the result when done, cached until the records change, 409 without data."""
from __future__ import annotations

import time
from typing import Any

from synthetic import free_decay


def _decay(v0: float, n: int = 1500, fs: float = 1000.0) -> bytes:
    return free_decay(v0, n, fs, m=0.05, k=300.0, c=0.3).to_csv().encode()


def _poll(client: Any, path: str, timeout: float) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    body: dict[str, Any] = {}
    seen_running = False
    while time.monotonic() < deadline:
        r = client.get(path)
        assert r.status_code in (200, 202), r.text
        body = r.json()
        if body["state"] == "running":
            seen_running = True
            assert r.status_code == 202 and 0.0 <= body["fraction"] < 1.0
        else:
            body["_seen_running"] = seen_running
            return body
        time.sleep(0.5)
    raise AssertionError(f"diagnosis did not finish in {timeout} s: {body}")


def test_diagnosis_runs_in_background_and_is_cached(client, linear):
    name = "diag-lin"
    assert client.put(f"/v1/systems/{name}", json=linear).status_code in (200, 201)
    path = f"/v1/systems/{name}/diagnosis?quick=true"
    r = client.get(path)
    assert r.status_code == 409 and "train" in r.json()["detail"]
    for v0, role in ((1.0, "train"), (0.6, "validation")):
        assert client.post(f"/v1/systems/{name}/recordings?role={role}",
                           content=_decay(v0), headers={"Content-Type": "text/csv"}
                           ).status_code == 202
    first = client.get(path)
    assert first.status_code == 202, first.text  # started, not run in the request
    assert first.json()["state"] == "running"
    done = _poll(client, path, timeout=240)
    assert done["state"] == "done", done
    assert done["fraction"] == 1.0 and done["result"] is not None
    # the records come from a linear oscillator = the model: nothing is named
    assert done["result"]["verdicts"] == [] and done["result"]["verdict"] is None
    key = done["data_key"]
    again = client.get(path)
    assert again.status_code == 200 and again.json()["data_key"] == key  # cached
    report = client.get(f"/v1/systems/{name}/diagnosis/report?quick=true")
    assert report.status_code == 200 and "<html" in report.text
    # new data -> new key and a new run
    assert client.post(f"/v1/systems/{name}/recordings?role=train", content=_decay(0.8),
                       headers={"Content-Type": "text/csv"}).status_code == 202
    fresh = client.get(path)
    assert fresh.json()["data_key"] != key
    assert fresh.json()["state"] in ("running", "done")


def test_diagnosis_of_unknown_system_is_404(client):
    r = client.get("/v1/systems/nope-diag/diagnosis")
    assert r.status_code == 404 and "nope-diag" in r.json()["detail"]



def test_a_failed_run_is_answered_once_then_retried(monkeypatch):
    """A polling client sees ``failed`` with its error (it used to be restarted on every
    request, so the client saw a run at 0 % forever)."""
    import importlib
    from types import SimpleNamespace

    route = importlib.import_module("service.api.routes.diagnosis")  # the module, not its router

    metas = [SimpleNamespace(id="r1", role="train"), SimpleNamespace(id="r2", role="validation")]
    store = SimpleNamespace(recordings=lambda name: metas, spec=lambda name: {"name": name})
    svc = SimpleNamespace(store=store)
    jobs = route._Jobs()
    request = SimpleNamespace(app=SimpleNamespace(state=SimpleNamespace(diagnosis_jobs=jobs)))
    monkeypatch.setattr(route, "require_write_rights", lambda *a, **k: None)
    monkeypatch.setattr(route, "_run_system", lambda *a, **k: None)  # no thread work
    key = route._data_key(store.spec("s"), ["r1"], ["r2"], True)
    failed = route.DiagnosisJob(key, ["r1"], ["r2"], True, state="failed", error="boom")
    jobs.by_system["s"] = failed
    first = route._current(request, svc, "s", True, start=True)
    assert first is failed and first.status("s")["error"] == "boom"
    second = route._current(request, svc, "s", True, start=True)
    assert second is not failed and second.state == "running" and second.key == key
