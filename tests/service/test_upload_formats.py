"""Uploads in every registered format reach the store (202), and oversized or odd archives are
refused by the live server (413/422) without the server's memory growing."""
from __future__ import annotations

import io
import re
import zipfile

import numpy as np
import pytest

from siva_core import Recording
from siva_core import RECORDING_FORMATS as REGISTRY

TOKEN = "fmt-token"


@pytest.fixture(scope="module")
def srv(make_server, linear):
    s = make_server(env={"SIVA_API_TOKEN": TOKEN})
    with s.client() as c:
        assert c.put("/v1/systems/fmt", json=linear).status_code == 201
    return s


@pytest.fixture(scope="module")
def record(oscillator) -> Recording:
    return Recording.read(oscillator(n=400), ["x"], fmt="csv")


def _hwm_mb(pid: int) -> float:
    text = open(f"/proc/{pid}/status").read()
    return int(re.search(r"VmHWM:\s*(\d+)", text)[1]) / 1024


@pytest.mark.parametrize("fmt", [f for f in REGISTRY if f not in ("csv",)])
def test_every_format_is_accepted(srv, record, fmt):
    raw = record.to_bytes(fmt)
    suffix = REGISTRY[fmt].suffixes[0]
    with srv.client() as c:
        # as a file part with a generic type: the suffix (or the content) decides
        r = c.post("/v1/systems/fmt/recordings?role=train",
                   files={"file": (f"rec{suffix}", raw, "application/octet-stream")})
        assert r.status_code == 202, r.text
        rid = r.json()["id"]
        info = c.get(f"/v1/systems/fmt/recordings/{rid}").json()
    assert info["fmt"] == fmt, info


def test_lvm_sent_as_text_plain_is_read_as_lvm(srv, record):
    other = Recording(record.time, {"disp_x": 0.5 * record.channels["disp_x"]}, "half")
    with srv.client() as c:
        r = c.post("/v1/systems/fmt/recordings?role=validation", content=other.to_bytes("lvm"),
                   headers={"Content-Type": "text/plain"})
        assert r.status_code == 202, r.text
        assert c.get(f"/v1/systems/fmt/recordings/{r.json()['id']}").json()["fmt"] == "lvm"


def test_npz_bomb_is_413_and_the_server_does_not_grow(srv):
    n = 40_000_000  # 320 MB of float64 zeros in ~0.3 MB
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("acc_x.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(
                fh, {"descr": "<f8", "fortran_order": False, "shape": (n,)})
            zeros = bytes(1 << 20)
            left = 8 * n
            while left:
                fh.write(zeros[:min(left, len(zeros))])
                left -= min(left, len(zeros))
        z.writestr("time.npy", b"")
    before = _hwm_mb(srv.proc.pid)
    with srv.client() as c:
        r = c.post("/v1/systems/fmt/recordings?role=train", content=buf.getvalue(),
                   headers={"Content-Type": "application/x-npz"})
    assert r.status_code == 413 and "would decompress to" in r.json()["detail"], r.text
    assert _hwm_mb(srv.proc.pid) - before < 50


def test_complex_npz_is_422(srv, record):
    buf = io.BytesIO()
    np.savez(buf, time=record.time, disp_x=record.channels["disp_x"] * (1 + 1j))
    with srv.client() as c:
        r = c.post("/v1/systems/fmt/recordings?role=train", content=buf.getvalue(),
                   headers={"Content-Type": "application/x-npz"})
    assert r.status_code == 422 and "is complex" in r.json()["detail"]
