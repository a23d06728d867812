"""Disk full and read-only data directory: 507 (never 500), nothing half-applied, the
trainer keeps running, /healthz says what is wrong, and everything recovers when the disk
does.  On a real (small) tmpfs when the machine allows mounts; the store-level tests
inject the same OSErrors everywhere else."""
from __future__ import annotations

import errno
import time
from pathlib import Path

import pytest

from service.storage import store as store_mod
from service.storage.recordings import UploadFacts
from service.storage.store import Store

CSV = {"content-type": "text/csv"}


def _health(c):
    r = c.get("/healthz")
    return r.status_code, r.json()


def _wait_health(c, code: int, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        last = _health(c)
        if last[0] == code:
            return last[1]
        time.sleep(0.3)
    raise AssertionError(f"/healthz did not become {code} in {timeout} s: {last}")


def _start_training(c, oscillator) -> None:
    assert c.put("/v1/systems/osc", json={
        "name": "osc", "dofs": ["x"], "mass": {"x": 0.05}, "elements": [
            {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
            {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
    ).status_code == 201
    for k, role in ((300.0, "train"), (310.0, "validation")):
        r = c.post(f"/v1/systems/osc/recordings?role={role}", content=oscillator(k=k), headers=CSV)
        assert r.status_code == 202, r.text


def _epoch(c) -> int:
    return c.get("/v1/systems/osc/estimate").json()["epoch"]


def test_disk_full_gives_507_and_everything_recovers(make_server, tmpfs, oscillator, linear,
                                                     lenient_client):
    disk = tmpfs(48)
    srv = make_server(data_dir=disk.path, env={"SIVA_CHECKPOINT_EVERY_S": "0.5"})
    with lenient_client(srv) as c:
        _start_training(c, oscillator)
        deadline = time.monotonic() + 60
        while _epoch(c) < 2 and time.monotonic() < deadline:
            time.sleep(0.3)
        n_before = len(c.get("/v1/systems/osc/recordings").json()["recordings"])
        disk.fill()
        # every write path: 507 with a message, never a 5xx other than 507
        r = c.post("/v1/systems/osc/recordings?role=train", content=oscillator(k=320.0),
                   headers=CSV)
        assert r.status_code == 507, r.text
        assert "disk is full" in r.json()["detail"]
        r = c.put("/v1/systems/other", json=linear)
        assert r.status_code == 507, r.text
        # /healthz is honest: checkpoints fail -> 503 with the reason, trainer still alive
        body = _wait_health(c, 503)
        assert any("cannot write checkpoints" in p for p in body["problems"]), body
        assert body["workers_alive"] == 1
        e0 = _epoch(c)
        time.sleep(2.0)
        assert _epoch(c) > e0, "the trainer stopped while the disk was full"
        assert len(c.get("/v1/systems/osc/recordings").json()["recordings"]) == n_before
        assert c.get("/v1/systems/other").status_code == 404
        # space returns: healthy again, uploads accepted, the worker never died
        disk.free()
        _wait_health(c, 200)
        r = c.post("/v1/systems/osc/recordings?role=train", content=oscillator(k=320.0),
                   headers=CSV)
        assert r.status_code == 202, r.text
        assert c.put("/v1/systems/other", json=linear).status_code == 201
    srv.stop()
    # the log holds every acknowledged recording, readable past the failed writes
    from service.storage.eventlog import read_events

    logged = {e.event.id for p in (disk.path / "logs" / "osc").glob("*.mcap")
              for e in read_events(p) if e.topic == "/siva/recording"}
    stored = {p.name.split(".")[0] for p in (disk.path / "systems" / "osc" / "recordings").glob("*.json")}
    assert stored and stored <= logged


@pytest.mark.slow
def test_read_only_gives_507_and_delete_is_not_half_applied(make_server, tmpfs, oscillator,
                                                            lenient_client):
    disk = tmpfs(48)
    srv = make_server(data_dir=disk.path, env={"SIVA_CHECKPOINT_EVERY_S": "0.5"})
    with lenient_client(srv) as c:
        _start_training(c, oscillator)
        disk.read_only()
        try:
            r = c.delete("/v1/systems/osc")
            assert r.status_code == 507, r.text
            assert "read-only" in r.json()["detail"]
            # not half-applied: still listed, still training
            assert c.get("/v1/systems/osc").status_code == 200
            r = c.post("/v1/systems/osc/recordings?role=train", content=oscillator(k=330.0),
                       headers=CSV)
            assert r.status_code == 507, r.text
            assert c.put("/v1/systems/x2", json={"name": "x"}).status_code in (422, 507)
            body = _wait_health(c, 503)
            assert body["workers_alive"] == 1
        finally:
            disk.read_only(False)
        _wait_health(c, 200)
    srv.kill()
    srv.start()
    with lenient_client(srv) as c:
        assert c.get("/v1/systems/osc").status_code == 200  # DELETE failed: still there
        assert c.delete("/v1/systems/osc").status_code == 200
    srv.kill()
    srv.start()
    with lenient_client(srv) as c:
        assert c.get("/v1/systems/osc").status_code == 404  # DELETE succeeded: gone for good


# --------------------------------------------------------------------------- fault injection
def _failing_writes(monkeypatch, err: int) -> None:
    def boom(path: Path, data: bytes) -> None:
        raise OSError(err, "injected")

    monkeypatch.setattr(store_mod, "atomic_write", boom)


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EROFS])
def test_store_write_failures_change_nothing(tmp_path, monkeypatch, err):
    st = Store(tmp_path)
    st.put_spec("a", {"name": "a"})
    with monkeypatch.context() as m:
        _failing_writes(m, err)
        with pytest.raises(OSError):
            st.put_spec("b", {"name": "b"})
        with pytest.raises(OSError):
            st.add_recording("a", b"x", role="train", fmt="csv", filename="f", info=UploadFacts())
    assert st.systems() == ["a"] and st.recordings("a") == []
    assert not (tmp_path / "systems" / "b").exists()
    # a failing write-ahead log aborts the upload: nothing committed, no orphan raw file
    def log_fails(meta):
        raise OSError(errno.ENOSPC, "log full")

    with pytest.raises(OSError):
        st.add_recording("a", b"x", role="train", fmt="csv", filename="f", info=UploadFacts(),
                         before_commit=log_fails)
    assert st.recordings("a") == []
    assert list((tmp_path / "systems" / "a" / "recordings").iterdir()) == []
    # a rename the disk refuses: DELETE changes nothing
    def no_rename(a, b):
        raise OSError(errno.EROFS, "read-only")

    monkeypatch.setattr(store_mod.os, "replace", no_rename)
    with pytest.raises(OSError):
        st.delete_system("a")
    assert st.systems() == ["a"]
    monkeypatch.undo()
    st.delete_system("a")
    assert Store(tmp_path).load() == []
