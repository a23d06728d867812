"""Durability: kill -9 after 202s, restart on the same data dir, everything is back and
training resumes from the checkpoint; the replay buffer is rebuilt identically."""
from __future__ import annotations

import re
import time

from service.storage.recordings import RecordingMeta
from service.trainer.replay_buffer import ReplayBuffer


def _meta(i: int, role: str) -> RecordingMeta:
    return RecordingMeta(id=f"r{i:06d}", system="s", index=i, role=role, role_source="auto",
                         sha256="0" * 64, fmt="csv", filename="f.csv", bytes=1, n_samples=1,
                         fs=1.0, duration_s=1.0, columns=("time",), received_at=0.0)


def test_replay_buffer_is_bounded_and_deterministic():
    metas = [_meta(i, "validation" if i % 5 == 0 else "train") for i in range(1, 201)]
    a = ReplayBuffer(window=4, reservoir=3, val_window=2, seed="42:s")
    a.extend(metas)
    assert len(a.train_ids) == 7 and len(a.val_ids) == 2
    train = [m.id for m in metas if m.role == "train"]
    assert a.train_ids[-4:] == train[-4:]                 # the most recent window
    assert set(a.train_ids[:3]) <= set(train[:-4])        # the reservoir: older records
    assert a.val_ids == ["r000195", "r000200"]
    # rebuilt after a restart from the same arrivals: the same buffer
    b = ReplayBuffer(window=4, reservoir=3, val_window=2, seed="42:s")
    b.extend(metas[:120])
    b.extend(metas)  # re-offering known records is a no-op
    assert b.train_ids == a.train_ids and b.val_ids == a.val_ids
    # the reservoir is a fair sample: over many seeds every old record can be kept
    kept = set()
    for seed in range(60):
        r = ReplayBuffer(window=4, reservoir=3, val_window=2, seed=str(seed))
        r.extend(metas)
        kept |= set(r.train_ids[:3])
    assert len(kept) > 60


def test_kill_9_and_restart(make_server, spec_of, duffing, linear, oscillator, poll):
    srv = make_server(env={"SIVA_CHECKPOINT_EVERY_S": "1"})
    with srv.client() as c:
        assert c.put("/v1/systems/duff", json=spec_of("duffing")).status_code == 201
        assert c.put("/v1/systems/idle", json=linear).status_code == 201
        acks = []
        for f, role in (("train_v5.csv", "train"), ("val_v3.csv", "validation")):
            r = c.post(f"/v1/systems/duff/recordings?role={role}", content=duffing(f),
                       headers={"content-type": "text/csv"})
            assert r.status_code == 202
            acks.append(r.json())
        r = c.post("/v1/systems/idle/recordings?role=train", content=oscillator(),
                   headers={"content-type": "text/csv"})
        assert r.status_code == 202
        idle_ack = r.json()
        est = poll(c, "/v1/systems/duff/estimate",
                   lambda e: (e.get("checkpoint_epoch") or 0) >= 6, timeout=150, every=0.5)
        ckpt_epoch = est["checkpoint_epoch"]
        # one more upload, then kill -9 the moment its 202 is back
        r = c.post("/v1/systems/duff/recordings?role=validation", content=duffing("val_v8.csv"),
                   headers={"content-type": "text/csv"})
        assert r.status_code == 202
        acks.append(r.json())
        srv.kill()

    # what a crash mid-upload leaves behind: a temp file and data without a committed meta
    rdir = srv.data_dir / "systems" / "duff" / "recordings"
    (rdir / ".r000009-x.data.csv.1234.tmp").write_bytes(b"partial")
    (rdir / "r000009-deadbeef00.data.csv").write_bytes(b"time,acc_x\n")
    on_disk_ckpt = srv.data_dir / "systems" / "duff" / "checkpoint.pt"
    assert on_disk_ckpt.exists()

    t0 = time.monotonic()
    srv.start()
    with srv.client() as c:
        names = [s["name"] for s in c.get("/v1/systems").json()["systems"]]
        assert names == ["duff", "idle"]
        recs = c.get("/v1/systems/duff/recordings").json()["recordings"]
        assert [(m["id"], m["sha256"], m["role"]) for m in recs] == \
            [(a["id"], a["sha256"], a["role"]) for a in acks]
        assert [m["id"] for m in c.get("/v1/systems/idle/recordings").json()["recordings"]] \
            == [idle_ack["id"]]
        assert sorted(p.name for p in rdir.iterdir()) == sorted(
            [f"{a['id']}.json" for a in acks] + [f"{a['id']}.data.csv" for a in acks])
        for a, f in zip(acks, ("train_v5.csv", "val_v3.csv", "val_v8.csv")):
            assert c.get(f"/v1/systems/duff/recordings/{a['id']}/raw").content == duffing(f)
        # the same spec again is "already there"; a different one still conflicts
        assert c.put("/v1/systems/duff", json=spec_of("duffing")).status_code == 200
        assert c.put("/v1/systems/duff", json=linear).status_code == 409
        # training resumes from the checkpoint, not from zero
        first = c.get("/v1/systems/duff/estimate").json()
        assert first["epoch"] >= ckpt_epoch, (first["epoch"], ckpt_epoch)
        assert first["n_recordings"] == {"train": 1, "validation": 2}
        later = poll(c, "/v1/systems/duff/estimate",
                     lambda e: e["epoch"] >= first["epoch"] + 4, timeout=120, every=0.5)
        assert later["epoch"] > ckpt_epoch
        assert sorted(later["data"]["validation"]) == sorted(a["id"] for a in acks[1:])
        # the drift history came back with the checkpoint
        hist = c.get("/v1/systems/duff/drift").json()["history"]
        assert hist and hist[0]["epoch"] < ckpt_epoch + 1
        # arrival indices continue after the restart
        r = c.post("/v1/systems/idle/recordings?role=validation", content=oscillator(v0=2.0),
                   headers={"content-type": "text/csv"})
        assert r.status_code == 202 and r.json()["index"] == 2
    assert time.monotonic() - t0 < 200
    srv.stop()  # graceful: writes a final checkpoint
    # threads: the trainers restarted with the front; ray: the detached actors trained on
    assert re.search("resumed from checkpoint|found running", srv.log_text())
