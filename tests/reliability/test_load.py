"""A bounded load test on loopback: 20 clients uploading ~1 MB recordings while others
read, for a fixed number of requests.  Every request is answered (no 5xx, no timeout),
reads stay fast while uploads are parsed, and the server's memory stays bounded."""
from __future__ import annotations

import statistics
import threading
import time

import httpx
import numpy as np
import pytest
from procmem import growth_mb, mem_mb

UPLOADERS = 20
UPLOADS_EACH = 5
READERS = 5
MB_SAMPLES = 14_000  # rows of a 4-column CSV of ~1 MB


def one_mb_csv(seed: int) -> bytes:
    rnd = np.random.default_rng(seed)
    fs = 2000.0
    t = np.arange(MB_SAMPLES) / fs
    k, m, c = rnd.uniform(280, 320), 0.05, 0.5
    wn = np.sqrt(k / m)
    zeta = c / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - zeta ** 2)
    v0 = rnd.uniform(0.5, 2.0)
    env = np.exp(-zeta * wn * t)
    q = v0 / wd * env * np.sin(wd * t)
    v = v0 * env * (np.cos(wd * t) - zeta * wn / wd * np.sin(wd * t))
    a = -(k * q + c * v) / m
    rows = "\n".join(f"{ti:.6f},{qi:.12e},{vi:.12e},{ai:.12e}" for ti, qi, vi, ai in zip(t, q, v, a))
    return ("time,disp_x,vel_x,acc_x\n" + rows + "\n").encode()


@pytest.mark.slow
def test_load_20_uploaders_1mb_with_concurrent_reads(make_server, linear):
    srv = make_server(env={"SIVA_REFINE_EVERY_S": "0", "SIVA_LOG_LEVEL": "WARNING"})
    with srv.client() as c:
        assert c.put("/v1/systems/load", json={**linear, "name": "load"}).status_code == 201
    bodies = [one_mb_csv(i) for i in range(UPLOADERS * UPLOADS_EACH)]
    assert 0.8e6 < len(bodies[0]) < 1.3e6, len(bodies[0])
    # one 1 MB upload alone: the server must not grow by more than 200 MB (issue 9)
    single = one_mb_csv(10_000)
    m0 = mem_mb(srv.proc.pid)
    with srv.client() as c:
        assert c.post("/v1/systems/load/recordings", content=single,
                      headers={"content-type": "text/csv"}).status_code == 202
    m1 = mem_mb(srv.proc.pid)
    single_growth = growth_mb(m0, m1)
    assert single_growth < 200, f"one 1 MB upload grew the server by {single_growth:.0f} MB"
    m0 = mem_mb(srv.proc.pid)
    upload_s: list[float] = []
    read_s: list[float] = []
    errors: list[str] = []
    done = threading.Event()

    def uploader(i: int) -> None:
        with httpx.Client(base_url=srv.base_url, timeout=300) as c:
            for j in range(UPLOADS_EACH):
                body = bodies[i * UPLOADS_EACH + j]
                t0 = time.perf_counter()
                r = c.post("/v1/systems/load/recordings", content=body,
                           headers={"content-type": "text/csv"})
                upload_s.append(time.perf_counter() - t0)
                if r.status_code != 202:
                    errors.append(f"upload {r.status_code} {r.text[:200]}")

    def reader() -> None:
        with httpx.Client(base_url=srv.base_url, timeout=60) as c:
            while not done.is_set():
                for path in ("/v1/systems/load/estimate", "/v1/systems", "/healthz",
                             "/v1/systems/load/recordings"):
                    t0 = time.perf_counter()
                    r = c.get(path)
                    read_s.append(time.perf_counter() - t0)
                    if r.status_code != 200:
                        errors.append(f"read {path} {r.status_code}")
                time.sleep(0.05)

    t_start = time.perf_counter()
    ups = [threading.Thread(target=uploader, args=(i,)) for i in range(UPLOADERS)]
    rds = [threading.Thread(target=reader) for _ in range(READERS)]
    for t in ups + rds:
        t.start()
    for t in ups:
        t.join(900)
    done.set()
    for t in rds:
        t.join(60)
    wall = time.perf_counter() - t_start
    m1 = mem_mb(srv.proc.pid)
    grew = growth_mb(m0, m1)
    with srv.client() as c:
        n = len(c.get("/v1/systems/load/recordings").json()["recordings"])
    print(f"\nload: {len(upload_s)} uploads of ~1 MB by {UPLOADERS} clients in {wall:.0f} s; "
          f"upload median {statistics.median(upload_s):.2f} s, max {max(upload_s):.2f} s; "
          f"{len(read_s)} reads, median {1000 * statistics.median(read_s):.0f} ms, "
          f"p99 {1000 * sorted(read_s)[int(0.99 * len(read_s))]:.0f} ms; "
          f"server RSS {m0[0]:.0f} -> {m1[0]:.0f} MB (peak growth {grew:.0f} MB; one upload "
          f"alone: {single_growth:.0f} MB)")
    assert not errors, errors[:10]
    assert n == UPLOADERS * UPLOADS_EACH + 1
    # 20 uploads parsed at once (the thread pool): bounded by 20 x the single-upload cost
    assert grew < 20 * 200, f"server grew by {grew:.0f} MB under 20 concurrent 1 MB uploads"
    assert statistics.median(read_s) < 1.0
    srv.assert_no_bugs()
