"""The HTTP contract against a real server: systems, recordings, estimate, drift, reads."""
from __future__ import annotations

import hashlib
import json
import time

from siva_core import Recording


def test_healthz_and_openapi(client):
    r = client.get("/healthz")
    assert r.status_code == 200 and r.json()["status"] == "ok"
    doc = client.get("/openapi.json").json()
    for path in ("/v1/systems/{name}", "/v1/systems/{name}/recordings",
                 "/v1/systems/{name}/estimate", "/v1/systems/{name}/drift", "/healthz"):
        assert path in doc["paths"], path
    post = doc["paths"]["/v1/systems/{name}/recordings"]["post"]
    assert "202" in post["responses"]
    assert {"text/csv", "application/json", "multipart/form-data"} <= set(
        post["requestBody"]["content"])


def test_put_spec_created_same_conflict(client, server, spec_of):
    spec = spec_of("duffing")
    r = client.put("/v1/systems/api-duffing", json=spec)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["created"] is True and body["free_parameters"] == ["b", "b_nl", "k", "k_nl"]
    r = client.put("/v1/systems/api-duffing", json=spec)
    assert r.status_code == 200 and r.json()["created"] is False
    r = client.put("/v1/systems/api-duffing", json=dict(spec, mass={"x": 0.06}))
    assert r.status_code == 409 and "different spec" in r.json()["detail"]
    path = server.data_dir / "systems" / "api-duffing" / "spec.json"
    stored = json.loads(path.read_text())
    assert stored["mass"] == {"x": 0.05}  # the conflict did not overwrite
    assert "api-duffing" in [s["name"] for s in client.get("/v1/systems").json()["systems"]]
    got = client.get("/v1/systems/api-duffing").json()
    assert got["spec"] == stored and got["dofs"] == ["x"]


def test_toml_spec_is_accepted(client):
    toml = b'dofs = ["x"]\n[mass]\nx = 1.0\n[[elements]]\nkind = "spring"\n' \
           b'between = ["x", "ground"]\nparams = { k = "k" }\n'
    r = client.put("/v1/systems/api-toml", content=toml,
                   headers={"content-type": "application/toml"})
    assert r.status_code == 201, r.text
    assert r.json()["free_parameters"] == ["k"]


def test_upload_formats_and_listing(client, server, linear, oscillator):
    assert client.put("/v1/systems/api-linear", json=linear).status_code == 201
    csv = oscillator(v0=1.0)
    r = client.post("/v1/systems/api-linear/recordings", params={"role": "train"},
                    content=csv, headers={"content-type": "text/csv"})
    assert r.status_code == 202, r.text
    ack = r.json()
    assert ack["role"] == "train" and ack["role_source"] == "explicit" and ack["index"] == 1
    assert ack["sha256"] == hashlib.sha256(csv).hexdigest() and ack["duplicate"] is False

    # the JSON recording format
    rec = Recording.from_csv(oscillator(v0=2.0))
    r = client.post("/v1/systems/api-linear/recordings", params={"role": "validation"},
                    json=rec.to_columns())
    assert r.status_code == 202, r.text
    assert r.json()["fmt"] == "json" and r.json()["role"] == "validation"

    # multipart file upload; format from the file name
    r = client.post("/v1/systems/api-linear/recordings", params={"role": "validation"},
                    files={"file": ("hammer_3.csv", oscillator(v0=3.0), "text/csv")})
    assert r.status_code == 202, r.text
    assert r.json()["filename"] == "hammer_3.csv" and r.json()["fmt"] == "csv"

    listing = client.get("/v1/systems/api-linear/recordings").json()
    assert listing["n_recordings"] == {"train": 1, "validation": 2}
    assert [m["index"] for m in listing["recordings"]] == [1, 2, 3]
    one = client.get(f"/v1/systems/api-linear/recordings/{ack['id']}").json()
    assert one["id"] == ack["id"] and one["n_samples"] == 2000 and one["fs"] == 2000.0
    raw = client.get(f"/v1/systems/api-linear/recordings/{ack['id']}/raw")
    assert raw.status_code == 200 and raw.content == csv
    # durably on disk: raw bytes and a committed meta file, nothing temporary
    rdir = server.data_dir / "systems" / "api-linear" / "recordings"
    assert (rdir / f"{ack['id']}.data.csv").read_bytes() == csv
    assert json.loads((rdir / f"{ack['id']}.json").read_text())["sha256"] == ack["sha256"]
    assert not list(rdir.glob(".*"))


def test_duplicate_upload_is_idempotent(client, linear, oscillator):
    assert client.put("/v1/systems/api-dup", json=linear).status_code == 201
    csv = oscillator(v0=1.5)
    first = client.post("/v1/systems/api-dup/recordings?role=train", content=csv,
                        headers={"content-type": "text/csv"}).json()
    again = client.post("/v1/systems/api-dup/recordings?role=train", content=csv,
                        headers={"content-type": "text/csv"})
    assert again.status_code == 202
    assert again.json()["id"] == first["id"] and again.json()["duplicate"] is True
    clash = client.post("/v1/systems/api-dup/recordings?role=validation", content=csv,
                        headers={"content-type": "text/csv"})
    assert clash.status_code == 409 and first["id"] in clash.json()["detail"]
    assert client.get("/v1/systems/api-dup/recordings").json()["n_recordings"] == \
        {"train": 1, "validation": 0}


def test_automatic_split(client, linear, oscillator):
    """No role: 1st train, 2nd validation, then every 4th arrival validates."""
    assert client.put("/v1/systems/api-split", json=linear).status_code == 201
    roles = []
    for i in range(9):
        r = client.post("/v1/systems/api-split/recordings", content=oscillator(v0=1.0 + i),
                        headers={"content-type": "text/csv"})
        assert r.status_code == 202, r.text
        assert r.json()["role_source"] == "auto"
        roles.append(r.json()["role"][0])
    assert "".join(roles) == "tvtvtttvt"


def test_estimate_and_drift_shape_and_training(client, linear, oscillator, poll):
    assert client.put("/v1/systems/api-est", json=linear).status_code == 201
    est = client.get("/v1/systems/api-est/estimate").json()
    assert est["epoch"] == 0 and est["converged"] is False
    assert est["n_recordings"] == {"train": 0, "validation": 0}
    for v0, role in ((1.0, "train"), (2.0, "validation")):
        r = client.post(f"/v1/systems/api-est/recordings?role={role}",
                        content=oscillator(v0=v0), headers={"content-type": "text/csv"})
        assert r.status_code == 202
    # counts are live (from the store), not from the last snapshot
    assert client.get("/v1/systems/api-est/estimate").json()["n_recordings"] == \
        {"train": 1, "validation": 1}
    est = poll(client, "/v1/systems/api-est/estimate",
               lambda e: e["epoch"] >= 4 and e["parameters"], timeout=120, every=0.5)
    assert set(est) >= {"parameters", "discriminator", "epoch", "converged", "n_recordings",
                        "state", "modal", "data"}
    for p in ("c", "k"):
        s = est["parameters"][p]
        if est["provisional"]:  # nothing looks like a 95 % interval before it is one
            assert s["ci95"] is None and s["std"] >= 0
        else:
            assert s["ci95"][0] <= s["mean"] <= s["ci95"][1] and s["std"] >= 0
    assert "loss_d" in est["discriminator"]
    assert est["modal"]["frequency_hz"][0] > 0
    drift = client.get("/v1/systems/api-est/drift").json()
    assert drift["system"] == "api-est" and isinstance(drift["alarms"], list)
    assert drift["rule"]["baseline_records"] >= 1 and drift["rule"]["arl0_records"] > 0
    assert drift["history"] and {"epoch", "parameters", "ensemble"} <= set(drift["history"][-1])
    assert len(client.get("/v1/systems/api-est/drift?limit=1").json()["history"]) == 1


def test_reads_do_not_wait_for_training(client, server, spec_of, duffing, poll):
    """While a trainer runs full-tilt on 10 kHz records, every GET answers fast."""
    assert client.put("/v1/systems/api-busy", json=spec_of("duffing")).status_code == 201
    for f, role in (("train_v5.csv", "train"), ("val_v3.csv", "validation")):
        assert client.post(f"/v1/systems/api-busy/recordings?role={role}", content=duffing(f),
                           headers={"content-type": "text/csv"}).status_code == 202
    poll(client, "/v1/systems/api-busy/estimate", lambda e: e["epoch"] >= 1, timeout=120,
         every=0.5)
    worst = 0.0
    for _ in range(20):
        t0 = time.perf_counter()
        assert client.get("/v1/systems/api-busy/estimate").status_code == 200
        assert client.get("/v1/systems/api-busy/drift").status_code == 200
        worst = max(worst, time.perf_counter() - t0)
    assert worst < 1.0, f"a read pair took {worst:.2f} s while training"
    client.delete("/v1/systems/api-busy")  # free the CPU for the other tests


def test_delete_system(client, server, linear, oscillator):
    assert client.put("/v1/systems/api-del", json=linear).status_code == 201
    assert client.post("/v1/systems/api-del/recordings?role=train", content=oscillator(),
                       headers={"content-type": "text/csv"}).status_code == 202
    r = client.delete("/v1/systems/api-del")
    body = r.json()
    assert r.status_code == 200 and body["deleted"] == "api-del" and body["recordings"] == 1
    assert body["logs"]["action"] == "deleted" and body["logs"]["files"] >= 1, body
    assert client.get("/v1/systems/api-del/estimate").status_code == 404
    assert not (server.data_dir / "systems" / "api-del").exists()
    assert not (server.data_dir / "logs" / "api-del").exists()  # no MCAP log left behind
    assert client.delete("/v1/systems/api-del").status_code == 404
    # the name is free again, with another spec
    assert client.put("/v1/systems/api-del", json=dict(linear, mass={"x": 1.0})).status_code == 201


def test_event_log_written(client, server, linear, oscillator):
    assert client.put("/v1/systems/api-log", json=linear).status_code == 201
    assert client.post("/v1/systems/api-log/recordings?role=train", content=oscillator(),
                       headers={"content-type": "text/csv"}).status_code == 202
    from service.storage.eventlog import read_events

    files = list((server.data_dir / "logs" / "api-log").glob("*.mcap"))
    assert len(files) == 1
    topics = [e.topic for e in read_events(files[0])]
    assert topics[:2] == ["/siva/spec", "/siva/recording"]
