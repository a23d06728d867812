"""Bounded parsing (issue 19): what one hostile upload costs a real server, measured by
sampling its RSS (psutil) while the request runs.

Must hold for every format's worst case: peak growth <= 10 x the body and <= 300 MB for any
single upload (plus :data:`FLOOR_MB` for what any request costs: a few-KB bomb cannot be
measured against 10 x its size), and <= 1 GB for 10 such uploads in parallel.  The default
run uses 8 MB bodies; ``-m slow`` the issue's sizes (60 MB) and the parallel case.
The servers run with ``MALLOC_MMAP_THRESHOLD_`` fixed so that freed buffers go back to the
system and each measurement starts from a true baseline (glibc otherwise keeps them, and a
second upload would reuse them unseen).
"""
from __future__ import annotations

import concurrent.futures as cf

import httpx
import pytest
from hostile import BIG_UPLOADS
from procmem import PeakRss

#: what any request may cost whatever its size (threads, buffers, the JSON answer)
FLOOR_MB = 24.0
ENV = {"SIVA_REFINE_EVERY_S": "0", "MALLOC_MMAP_THRESHOLD_": "131072",
       "SIVA_LOG_LEVEL": "WARNING"}


@pytest.fixture(scope="module")
def srv(make_server, linear):
    s = make_server(env=ENV)
    with s.client() as c:
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
    return s


def upload(srv, body: bytes, ctype: str) -> httpx.Response:
    with httpx.Client(base_url=srv.base_url, timeout=300) as c:
        return c.post("/v1/systems/h/recordings?role=train", content=body,
                      headers={"content-type": ctype})


def check_one(srv, case: str, ctype: str, body: bytes) -> float:
    with PeakRss(srv.proc.pid) as mem:
        r = upload(srv, body, ctype)
    mb = len(body) / 2**20
    print(f"{case}: body {mb:.2f} MB -> {r.status_code}, server peak growth "
          f"{mem.growth_mb:.0f} MB ({mem.growth_mb / max(mb, 1e-9):.1f} x body)")
    assert r.status_code in (413, 422), (case, r.status_code, r.text[:300])
    assert mem.growth_mb <= 10 * mb + FLOOR_MB, (case, mem.growth_mb, mb)
    assert mem.growth_mb <= 300, (case, mem.growth_mb)
    return mem.growth_mb


@pytest.mark.parametrize("case,ctype,build", BIG_UPLOADS, ids=[c[0] for c in BIG_UPLOADS])
def test_one_hostile_upload_is_bounded(srv, case, ctype, build):
    check_one(srv, case, ctype, build(8))


@pytest.mark.slow
@pytest.mark.parametrize("case,ctype,build", BIG_UPLOADS, ids=[c[0] for c in BIG_UPLOADS])
def test_one_hostile_60mb_upload_is_bounded(srv, case, ctype, build):
    check_one(srv, case, ctype, build(60))


@pytest.mark.slow
def test_ten_parallel_hostile_uploads_stay_under_1gb(make_server, linear):
    s = make_server(env=ENV)
    with s.client() as c:
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
    bodies = [(ctype, build(60)) for _, ctype, build in BIG_UPLOADS]
    bodies = [bodies[k % len(bodies)] for k in range(10)]
    with PeakRss(s.proc.pid) as mem, cf.ThreadPoolExecutor(10) as pool:
        codes = list(pool.map(lambda b: upload(s, b[1], b[0]).status_code, bodies))
    total = sum(len(b) for _, b in bodies) / 2**20
    print(f"10 parallel hostile uploads ({total:.0f} MB in all): statuses {codes}, "
          f"server peak growth {mem.growth_mb:.0f} MB")
    assert all(code in (413, 422, 503) for code in codes), codes
    assert mem.growth_mb <= 1024, mem.growth_mb


def test_concurrent_parses_are_bounded_503_with_retry_after(make_server, linear, oscillator):
    """One slot, no queue: while an upload holds the slot (its body still arriving), the
    next is answered 503 with Retry-After; once the first finishes, uploads go through."""
    import socket

    s = make_server(env={**ENV, "SIVA_MAX_CONCURRENT_UPLOADS": "1",
                         "SIVA_UPLOAD_QUEUE_S": "0"})
    with s.client() as c:
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
    body = oscillator()
    with socket.create_connection(("127.0.0.1", s.port), timeout=60) as slow:
        slow.sendall(b"POST /v1/systems/h/recordings?role=train HTTP/1.1\r\n"
                     b"Host: 127.0.0.1\r\nContent-Type: text/csv\r\n"
                     + f"Content-Length: {len(body)}\r\n\r\n".encode() + body[:100])
        with httpx.Client(base_url=s.base_url, timeout=60) as c:
            for _ in range(100):  # until the slow request holds the slot
                r = c.post("/v1/systems/h/recordings?role=train", content=oscillator(v0=0.7),
                           headers={"content-type": "text/csv"})
                if r.status_code == 503:
                    break
            assert r.status_code == 503, r.text
            assert int(r.headers["retry-after"]) > 0
            assert "SIVA_MAX_CONCURRENT_UPLOADS" in r.json()["detail"]
            slow.sendall(body[100:])
            answer = slow.recv(65536)
            assert b" 202 " in answer.split(b"\r\n")[0], answer[:200]
            r = c.post("/v1/systems/h/recordings?role=train", content=oscillator(v0=0.9),
                       headers={"content-type": "text/csv"})
            assert r.status_code == 202, r.text
