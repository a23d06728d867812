"""GET .../diagnosis?quick=true|false alternated must not pile up diagnosis threads
(issue 19: six requests kept both cores busy): one run per system, the superseded one
cancelled, and only a writer (the token) may start one.  In-process (TestClient) so the
test can see the threads themselves."""
from __future__ import annotations

import threading
import time

from fastapi.testclient import TestClient
from synthetic import free_decay

from service.api.app import create_app
from service.settings import Settings


def _decay(v0: float) -> bytes:
    return free_decay(v0, 1500, 1000.0, m=0.05, k=300.0, c=0.3).to_csv().encode()


class Anonymous:
    """The same client without the token (one TestClient: the app starts once)."""

    def __init__(self, client: TestClient) -> None:
        self.client = client

    def get(self, path: str):
        return self.client.get(path, headers={"Authorization": ""})


def _diagnosis_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("diagnosis-")]


def test_alternating_quick_runs_one_diagnosis_at_a_time(tmp_path, linear):
    app = create_app(Settings(data_dir=tmp_path / "data", refine_every_s=0, torch_threads=1,
                              api_token="tok"))
    with TestClient(app, headers={"Authorization": "Bearer tok"}) as c:
        anon = Anonymous(c)
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
        for role, v0 in (("train", 1.0), ("validation", 0.6)):
            assert c.post(f"/v1/systems/h/recordings?role={role}", content=_decay(v0),
                          headers={"content-type": "text/csv"}).status_code == 202
        # reads are open here (no SIVA_API_TOKEN_READS), but starting a run is a write
        r = anon.get("/v1/systems/h/diagnosis?quick=true")
        assert r.status_code == 401 and "writes need" in r.json()["detail"], r.text
        assert not _diagnosis_threads()
        assert anon.get("/v1/systems/h/diagnosis/report?quick=true").status_code == 404
        cross = c.get("/v1/systems/h/diagnosis?quick=true",
                      headers={"Origin": "http://evil.example", "Sec-Fetch-Site": "cross-site"})
        assert cross.status_code == 403, cross.text
        most = 0
        states = []
        for k in range(6):
            r = c.get(f"/v1/systems/h/diagnosis?quick={'true' if k % 2 == 0 else 'false'}")
            assert r.status_code in (200, 202), r.text
            states.append(r.json()["state"])
            most = max(most, len(_diagnosis_threads()))
        assert most <= 1, f"{most} diagnosis threads at once (states {states})"
        # once a run exists, its progress is a read: no token needed
        assert anon.get("/v1/systems/h/diagnosis?quick=false").status_code in (200, 202)
        jobs = app.state.diagnosis_jobs
        current = jobs.by_system["h"]
        assert current.quick is False  # the last request's run is the one kept
        # the superseded runs stop at their next progress report; the last one is cancelled
        # here so the test leaves no CPU behind
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and current.state == "queued":
            time.sleep(0.2)
            assert len(_diagnosis_threads()) <= 1
        current.cancel.set()
        for t in _diagnosis_threads():
            t.join(timeout=120)
        assert not _diagnosis_threads()
        assert current.state in ("cancelled", "done", "failed")
        # a cancelled run is not served: the next request (a writer's) starts a fresh one
        again = c.get("/v1/systems/h/diagnosis?quick=false")
        assert again.status_code == 202 and again.json()["state"] == "running"
        jobs.by_system["h"].cancel.set()
        for t in _diagnosis_threads():
            t.join(timeout=120)
