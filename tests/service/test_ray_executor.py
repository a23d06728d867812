"""SIVA_EXECUTOR=ray on a real local Ray cluster (two nodes on loopback): the trainer
actors survive kill -9 of their process and of the front, placement spreads them.

Marked ``ray``: not in `make test`; `make test-ray` starts the cluster, sets
SIVA_RAY_ADDRESS and runs these with the service's API tests.  Run alone, the module
starts (and stops) its own cluster with scripts/ray-local-cluster.sh.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import pytest

pytestmark = [pytest.mark.ray, pytest.mark.timeout(600)]
REPO = Path(__file__).resolve().parents[2]
CLUSTER = REPO / "scripts" / "ray-local-cluster.sh"


@pytest.fixture(scope="module")
def ray_address() -> Iterator[str]:
    pytest.importorskip("ray", reason="the ray extra is not installed: pip install '.[ray]'")
    given = os.environ.get("SIVA_RAY_ADDRESS")
    if given:
        yield given
        return
    env = {**os.environ, "SIVA_RAY_PORT": "6392"}
    out = subprocess.run(["bash", str(CLUSTER), "start"], env=env, capture_output=True,
                         text=True, timeout=180)
    assert out.returncode == 0, out.stderr
    try:
        yield out.stdout.strip().splitlines()[-1]
    finally:
        subprocess.run(["bash", str(CLUSTER), "stop"], env=env, timeout=120)


def _ray_env(address: str, **extra: str) -> dict[str, str]:
    return {"SIVA_EXECUTOR": "ray", "SIVA_RAY_ADDRESS": address, "SIVA_RAY_POLL_S": "0.2",
            **extra}


def _hosts(c: Any) -> list[dict[str, Any]]:
    """The executor's hosts from /healthz, read without the client's no-5xx hook: while a
    killed actor restarts (longer than UNREACHABLE_AFTER_S on a loaded machine) /healthz
    answers 503 "unhealthy" by design, and its body still lists the hosts."""
    r = httpx.get(f"{c.base_url}/healthz", headers=c.headers, timeout=c.timeout)
    assert r.status_code in (200, 503), r.text
    return r.json()["executor"]["hosts"]



def _pid_gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_first_put_does_not_wait_for_a_cold_actor(make_server, ray_address, linear,
                                                  oscillator, poll) -> None:
    """The trainer host takes 20 s to come up (SIVA_RAY_START_DELAY_S, a cold actor on a
    loaded cluster): the PUT answers at once, the system is ``starting`` meanwhile, the
    contract's answers and uploads work, then it trains (test_ray_start.py: the same
    without a cluster, plus DELETE while starting)."""
    srv = make_server(env=_ray_env(ray_address, SIVA_RAY_START_DELAY_S="20"))
    with srv.client(timeout=10.0) as c:
        t0 = time.monotonic()
        r = c.put("/v1/systems/cold", json=linear)
        assert r.status_code == 201, r.text
        assert time.monotonic() - t0 < 5.0
        assert c.get("/v1/systems/cold/estimate").json()["state"] == "starting"
        assert c.put("/v1/systems/cold", json=linear).status_code == 200
        assert c.put("/v1/systems/cold", json=dict(linear, mass={"x": 0.06})).status_code == 409
        for role, v0 in (("train", 1.0), ("validation", 0.6)):
            up = c.post(f"/v1/systems/cold/recordings?role={role}", content=oscillator(v0=v0),
                        headers={"content-type": "text/csv"})
            assert up.status_code == 202, up.text
        assert c.get("/healthz").status_code == 200  # starting is not a failure
        est = poll(c, "/v1/systems/cold/estimate", lambda b: b["epoch"] >= 3, timeout=300)
        assert est["n_recordings"] == {"train": 1, "validation": 1}
        assert len(est["data"]["train"]) == 1 and len(est["data"]["validation"]) == 1
    srv.stop()


def test_actor_killed_resumes_from_checkpoint_and_replays(until, make_server, ray_address, linear,
                                                          oscillator, poll) -> None:
    srv = make_server(env=_ray_env(ray_address))
    with srv.client() as c:
        assert c.put("/v1/systems/osc", json=linear).status_code == 201
        first = c.post("/v1/systems/osc/recordings?role=train", content=oscillator(),
                       headers={"content-type": "text/csv"}).json()
        c.post("/v1/systems/osc/recordings?role=validation", content=oscillator(v0=0.7),
               headers={"content-type": "text/csv"})
        est = poll(c, "/v1/systems/osc/estimate",
                   lambda b: (b.get("checkpoint_epoch") or 0) >= 10, timeout=300)
        (host,) = _hosts(c)
        assert host["systems"] == ["osc"] and host["restarts"] == 0
        os.kill(host["pid"], signal.SIGKILL)
        # acknowledged while the actor is down: stored, and trained on after the restart
        late = c.post("/v1/systems/osc/recordings?role=train", content=oscillator(v0=1.3),
                      headers={"content-type": "text/csv"})
        assert late.status_code == 202, late.text
        late_id = late.json()["id"]
        new = until(lambda: [h for h in _hosts(c) if h["restarts"] >= 1 and h["reachable"]],
                     180, "the trainer actor restarted")[0]
        assert new["pid"] != host["pid"] and new["incarnation"] != host["incarnation"]
        resumed = poll(c, "/v1/systems/osc/estimate",
                       lambda b: late_id in (b.get("data") or {}).get("train", [])
                       and b["epoch"] > est["checkpoint_epoch"] + 5, timeout=300)
        assert resumed["n_recordings"] == {"train": 2, "validation": 1}
        assert first["id"] in resumed["data"]["train"]
        assert c.get("/healthz").status_code == 200
    srv.stop()
    # the log of the front, across the actor's restart, replays to the published estimate
    out = subprocess.run([sys.executable, "-m", "siva_cli", "replay",
                          str(srv.data_dir / "logs" / "osc")], cwd=REPO, capture_output=True,
                         text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert out.returncode == 0, out.stderr[-2000:]
    cmp = json.loads(out.stdout)["replay"]["compared_to_log"]
    assert cmp["identical"], cmp


def test_front_killed_finds_its_actors_again(until, make_server, ray_address, linear, oscillator,
                                             poll) -> None:
    srv = make_server(env=_ray_env(ray_address))
    with srv.client() as c:
        c.put("/v1/systems/osc", json=linear)
        c.post("/v1/systems/osc/recordings?role=train", content=oscillator(),
               headers={"content-type": "text/csv"})
        c.post("/v1/systems/osc/recordings?role=validation", content=oscillator(v0=0.6),
               headers={"content-type": "text/csv"})
        before = poll(c, "/v1/systems/osc/estimate", lambda b: b["epoch"] >= 10, timeout=300)
        (host,) = _hosts(c)
    srv.kill()  # the front only: the detached actor trains on
    time.sleep(2.0)
    assert not _pid_gone(host["pid"])
    srv.start()
    with srv.client() as c:
        (again,) = until(lambda: [h for h in _hosts(c) if h["pid"]], 60, "host found")
        assert (again["pid"], again["incarnation"]) == (host["pid"], host["incarnation"])
        after = poll(c, "/v1/systems/osc/estimate", lambda b: b["epoch"] > before["epoch"],
                     timeout=120)
        assert after["n_recordings"] == {"train": 1, "validation": 1}
    srv.stop()  # a clean stop removes the actors
    until(lambda: _pid_gone(host["pid"]), 60, "the actor's process ended after a clean stop")


def test_systems_are_packed_per_actor_and_spread(until, make_server, ray_address, linear,
                                                 oscillator, poll) -> None:
    srv = make_server(env=_ray_env(ray_address, SIVA_RAY_SYSTEMS_PER_ACTOR="2",
                                   SIVA_RAY_CPUS_PER_ACTOR="0.5"))
    names = ["a", "b", "c"]
    with srv.client() as c:
        for k, name in enumerate(names):
            c.put(f"/v1/systems/{name}", json=linear)
            c.post(f"/v1/systems/{name}/recordings?role=train",
                   content=oscillator(k=250.0 + 50 * k), headers={"content-type": "text/csv"})
            c.post(f"/v1/systems/{name}/recordings?role=validation",
                   content=oscillator(k=250.0 + 50 * k, v0=0.5),
                   headers={"content-type": "text/csv"})
        hosts = until(lambda: [h for h in _hosts(c) if h["pid"]] if len(
            [h for h in _hosts(c) if h["pid"]]) == 2 else None, 120, "two hosts")
        assert sorted(sum((h["systems"] for h in hosts), [])) == names
        assert sorted(len(h["systems"]) for h in hosts) == [1, 2]
        assert len({h["node"] for h in hosts}) == 2, "SPREAD placed both hosts on one node"
        for k, name in enumerate(names):
            est = poll(c, f"/v1/systems/{name}/estimate", lambda b: b["epoch"] >= 20, 300)
            k_est = est["parameters"]["k"]["mean"]
            assert abs(k_est / (250.0 + 50 * k) - 1) < 0.05, (name, k_est)
        assert c.delete("/v1/systems/b").status_code == 200
        assert sorted(sum((h["systems"] for h in _hosts(c)), [])) == ["a", "c"]
