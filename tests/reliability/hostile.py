"""The catalogue of hostile inputs: every request an attacker or a careless client sent
that once ended in a 5xx, a hang, a silent corruption or an absurd estimate (issue 9),
with the status the service must answer now.

Each case is (id, method, path, body, headers, expected statuses, xfail reason or None).
Recordings that would need unbounded parsing (decompression bombs, complex NPZ arrays, CSV
``1_0``) are refused by the readers before anything is decompressed.
"""
from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np



@dataclass(frozen=True)
class Case:
    id: str
    method: str
    path: str
    body: bytes | Callable[[], bytes] | None   # callables: built only when the case runs
    headers: dict[str, str]
    expect: tuple[int, ...]
    xfail: str | None = None
    detail: tuple[str, ...] = field(default_factory=tuple)  # fragments the detail must hold

    def content(self) -> bytes | None:
        return self.body() if callable(self.body) else self.body


def _spec(**extra: Any) -> dict[str, Any]:
    spec = {"name": "h", "dofs": ["x"], "mass": {"x": 0.05},
            "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                         {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
    spec.update(extra)
    return spec


def _json(x: Any) -> bytes:
    return json.dumps(x).encode()


JSON = {"content-type": "application/json"}
TOML = {"content-type": "application/toml"}
CSV = {"content-type": "text/csv"}
NPZ = {"content-type": "application/x-npz"}
MCAP = {"content-type": "application/x-mcap"}


def _deep_json(depth: int) -> bytes:
    """A spec whose ``parameters.k.scale`` is nested ``depth`` levels deep."""
    return (b'{"name":"h","dofs":["x"],"mass":{"x":0.05},"elements":[{"kind":"spring",'
            b'"between":["x","ground"],"params":{"k":"k"}}],"parameters":{"k":{"scale":'
            + b"[" * depth + b"1" + b"]" * depth + b"}}}")


def _big_int_spec(digits: int) -> bytes:
    return (b'{"name":"h","dofs":["x"],"mass":{"x":' + b"9" * digits +
            b'},"elements":[{"kind":"spring","between":["x","ground"],"params":{"k":"k"}}]}')


def _many_params(n: int) -> bytes:
    return _json(_spec(elements=[{"kind": "spring", "between": ["x", "ground"],
                                  "params": {"k": f"k{i}"}} for i in range(n)]))


def csv_record(fs: float = 1000.0, n: int = 400, cell: str | None = None) -> bytes:
    t = np.arange(n) / fs
    x = 1e-3 * np.exp(-2 * t * fs / 1000) * np.sin(2 * np.pi * 12 * t * fs / 1000)
    rows = [f"{float(ti)!r},{float(xi)!r}" for ti, xi in zip(t, x)]
    if cell is not None:
        rows[5] = f"{float(t[5])!r},{cell}"
    return ("time,disp_x\n" + "\n".join(rows) + "\n").encode()


def npz_bomb(declared: bool, mbytes: int = 256) -> bytes:
    """A small NPZ whose arrays decompress to ``mbytes`` MB of zeros (in a declared column
    or in one the spec never asks for)."""
    n = 400
    t = np.arange(n) / 1000.0
    arrays = {"time": t, "disp_x": 1e-3 * np.sin(2 * np.pi * 12 * t)}
    big = np.zeros(mbytes * (1 << 20) // 8)
    if declared:
        arrays["disp_x"] = big
    else:
        arrays["junk"] = big
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def npz_complex() -> bytes:
    n = 400
    t = np.arange(n) / 1000.0
    buf = io.BytesIO()
    np.savez(buf, time=t, disp_x=(1e-3 * np.sin(2 * np.pi * 12 * t)) * (1 + 1j))
    return buf.getvalue()


def npz_many_arrays(k: int = 20000) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        empty = io.BytesIO()
        np.save(empty, np.zeros(1))
        for i in range(k):
            z.writestr(f"a{i}.npy", empty.getvalue())
    return buf.getvalue()


def mcap_zstd_bomb(mbytes: int = 256) -> bytes:
    """An MCAP recording whose one JSON message (zstd chunk) inflates to ``mbytes`` MB."""
    from mcap.writer import CompressionType, Writer

    buf = io.BytesIO()
    w = Writer(buf, compression=CompressionType.ZSTD, chunk_size=1 << 30)
    w.start()
    sid = w.register_schema("x", "jsonschema", b"{}")
    cid = w.register_channel("/disp_x", "json", sid)
    payload = b'{"value": 0.0, "pad": "' + b" " * (mbytes << 20) + b'"}'
    w.add_message(cid, log_time=1, publish_time=1, data=payload, sequence=0)
    w.finish()
    return buf.getvalue()


def catalogue() -> list[Case]:
    """Requests against a server holding system ``h`` (duffing-like linear oscillator)."""
    S = "/v1/systems"
    R = f"{S}/h/recordings?role=train"
    cases = [
        # --- specs: numbers, nesting, size
        Case("spec-int-309-digits", "PUT", f"{S}/n1", _big_int_spec(309), JSON, (422,),
             detail=("digits",)),
        Case("spec-int-5000-digits", "PUT", f"{S}/n2", _big_int_spec(5000), JSON, (422,)),
        Case("spec-float-1e400", "PUT", f"{S}/n3",
             b'{"name":"h","dofs":["x"],"mass":{"x":1e400},"elements":[]}', JSON, (422,)),
        Case("spec-nan-literal", "PUT", f"{S}/n4",
             b'{"name":"h","dofs":["x"],"mass":{"x":NaN},"elements":[]}', JSON, (422,)),
        Case("spec-toml-int-5000-digits", "PUT", f"{S}/n5",
             b'name = "h"\ndofs = ["x"]\n[mass]\nx = ' + b"9" * 5000 + b"\n", TOML, (422,)),
        Case("spec-toml-int-309-digits", "PUT", f"{S}/n6",
             b'name = "h"\ndofs = ["x"]\n[mass]\nx = ' + b"9" * 309 + b"\n", TOML, (422,)),
        Case("spec-toml-10000-nested", "PUT", f"{S}/n7", b"x = " + b"[" * 10000, TOML,
             (400, 422)),
        Case("spec-json-100000-nested", "PUT", f"{S}/n8", b"[" * 100000, JSON, (400, 413, 422)),
        Case("spec-field-900-deep", "PUT", f"{S}/n9", _deep_json(900), JSON, (422,),
             detail=("nested",)),
        Case("spec-field-900-deep-get-after", "GET", f"{S}/n9", None, {}, (404,)),
        Case("spec-1000-parameters", "PUT", f"{S}/n10", _many_params(1000), JSON, (413, 422)),
        Case("spec-40-parameters", "PUT", f"{S}/n11", _many_params(40), JSON, (422,),
             detail=("SIVA_MAX_PARAMETERS",)),
        Case("spec-100kB", "PUT", f"{S}/n12", _json(_spec(name="h" * 200_000)), JSON, (413,)),
        Case("spec-mass-1e-320", "PUT", f"{S}/n13", _json(_spec(mass={"x": 1e-320})), JSON,
             (422,), detail=("mass.x",)),
        Case("spec-scale-1e308", "PUT", f"{S}/n14",
             _json(_spec(parameters={"k": {"scale": 1e308}})), JSON, (422,)),
        Case("spec-scale-1e-300", "PUT", f"{S}/n15",
             _json(_spec(parameters={"k": {"scale": 1e-300}})), JSON, (422,)),
        Case("spec-nul-body", "PUT", f"{S}/n16", b"\0\0\0", JSON, (400,)),
        Case("spec-not-utf8", "PUT", f"{S}/n17", b"\xff\xfe{", JSON, (400,)),
        Case("spec-empty", "PUT", f"{S}/n18", b"", JSON, (400,)),
        Case("spec-array", "PUT", f"{S}/n19", b"[1,2]", JSON, (422,)),
        Case("spec-wrong-type", "PUT", f"{S}/n20", b"x", {"content-type": "image/png"}, (415,)),
        # --- names
        Case("name-trailing-newline", "PUT", f"{S}/h%0A", _json(_spec()), JSON, (422,)),
        Case("name-dotdot", "PUT", f"{S}/..", _json(_spec()), JSON, (404, 422)),
        Case("name-65-chars", "PUT", f"{S}/{'a' * 65}", _json(_spec()), JSON, (422,)),
        Case("name-unicode", "PUT", f"{S}/%C3%A9t%C3%A9", _json(_spec()), JSON, (422,)),
        # --- recordings: ranges and garbage
        Case("rec-fs-1e-290", "POST", R,
             b"time,disp_x\n0,0\n1e290,1\n2e290,0\n3e290,1\n" * 1, CSV, (422,)),
        Case("rec-fs-10MHz", "POST", R, csv_record(fs=1e7), CSV, (422,),
             detail=("sampling rate",)),
        Case("rec-nul", "POST", R, b"\0" * 1000, CSV, (422,)),
        Case("rec-deep-json", "POST", R, b'{"time":' + b"[" * 50000, JSON, (400, 422)),
        Case("rec-json-huge-int", "POST", R,
             b'{"time":[0,1],"disp_x":[' + b"9" * 5000 + b",1]}", JSON, (422,)),
        Case("rec-bad-multipart", "POST", R, b"--xx\r\nnot a part",
             {"content-type": "multipart/form-data; boundary=xx"}, (400, 422)),
        Case("rec-multipart-no-boundary", "POST", R, b"abc",
             {"content-type": "multipart/form-data"}, (400, 422)),
        Case("rec-truncated-mcap", "POST", R, b"\x89MCAP0\r\n\x01\xff\xff\xff", MCAP, (422,)),
        Case("rec-truncated-zip", "POST", R, b"PK\x03\x04" + b"\0" * 100, NPZ, (422,)),
        Case("rec-unknown-system", "POST", f"{S}/nope/recordings", csv_record(), CSV, (404,)),
        Case("rec-bad-role", "POST", f"{S}/h/recordings?role=evil", csv_record(), CSV, (422,)),
        # --- recordings: bounded parsing (siva_core formats: sizes checked before decompressing)
        Case("rec-csv-underscore-number", "POST", R, csv_record(cell="1_0"), CSV, (422,)),
        Case("rec-npz-complex", "POST", R, npz_complex, NPZ, (422,)),
        Case("rec-npz-20000-arrays", "POST", R, npz_many_arrays, NPZ, (413, 422)),
        Case("rec-npz-bomb-declared-column", "POST", R, lambda: npz_bomb(True), NPZ, (413, 422)),
        Case("rec-npz-bomb-ignored-column", "POST", R, lambda: npz_bomb(False), NPZ, (202, 413, 422)),
        Case("rec-mcap-zstd-bomb", "POST", R, mcap_zstd_bomb, MCAP, (413, 422)),
        # --- reads of things that are not there
        Case("get-unknown-recording", "GET", f"{S}/h/recordings/zzz", None, {}, (404,)),
        Case("get-unknown-raw", "GET", f"{S}/h/recordings/zzz/raw", None, {}, (404,)),
        Case("drift-limit-0", "GET", f"{S}/h/drift?limit=0", None, {}, (422,)),
        Case("drift-limit-huge", "GET", f"{S}/h/drift?limit=" + "9" * 5000, None, {}, (422,)),
        Case("delete-unknown", "DELETE", f"{S}/nope", None, {}, (404,)),
        Case("delete-bad-name", "DELETE", f"{S}/a%0A", None, {}, (422,)),
    ]
    return cases


#: cases whose request body decompresses to far more than it weighs: the server's RSS is
#: measured around them (issue 9: a 1 MB upload must never grow the server by > 200 MB)
BOMBS = ("rec-npz-bomb-declared-column", "rec-npz-bomb-ignored-column", "rec-mcap-zstd-bomb",
         "rec-npz-20000-arrays")


# --------------------------------------------------------------------------- big bodies
# Issue 19: uploads that cost the server many times their size.  Each record is valid up to
# its last row, whose time steps back, so the whole body is parsed before the 4xx (and
# nothing is stored or trained): the server's peak memory is the parse's.
def _rows(n: int, fs: float = 2000.0) -> np.ndarray:
    t = np.arange(n) / fs
    x = 1e-3 * np.exp(-0.5 * t) * np.sin(2 * np.pi * 12.3 * t)
    values = np.column_stack([t, x])
    values[-1, 0] = 0.0  # time steps back on the last row
    return values


def csv_big(mbytes: float) -> bytes:
    """A CSV of about ``mbytes`` MB (2 columns, ~36 characters a row)."""
    n = int(mbytes * 2**20 / 36)
    buf = io.StringIO()
    buf.write("time,disp_x\n")
    np.savetxt(buf, _rows(n), delimiter=",", fmt="%.10e")
    return buf.getvalue().encode()


def csv_one_line(mbytes: float) -> bytes:
    """A header and one data line of ``mbytes`` MB (``0,`` repeated)."""
    return b"time,disp_x\n" + b"0," * int(mbytes * 2**20 / 2) + b"0\n"


def csv_short_rows(mbytes: float) -> bytes:
    """The most rows per byte: ``0,0`` lines (many values, each costing 8 bytes parsed)."""
    return b"time,disp_x\n" + b"0,0\n" * int(mbytes * 2**20 / 4)


def json_big(mbytes: float) -> bytes:
    """A JSON recording of about ``mbytes`` MB."""
    n = int(mbytes * 2**20 / 36)
    v = _rows(n)
    return json.dumps({"time": v[:, 0].tolist(), "disp_x": v[:, 1].tolist()}).encode()


def lvm_big(mbytes: float) -> bytes:
    """A LabVIEW text file of about ``mbytes`` MB."""
    n = int(mbytes * 2**20 / 36)
    head = ("LabVIEW Measurement\t\nSeparator\tTab\nDecimal_Separator\t.\nX_Columns\tOne\n"
            "***End_of_Header***\t\nChannels\t1\n***End_of_Header***\t\nX_Value\tdisp_x\n")
    buf = io.StringIO()
    buf.write(head)
    np.savetxt(buf, _rows(n), delimiter="\t", fmt="%.10e")
    return buf.getvalue().encode()


def mcap_json_bomb(mib: int = 127) -> bytes:
    """A small MCAP whose one zstd chunk holds ``mib`` MiB of JSON numbers on /recording
    (its declared size is under the 128 MiB absolute limit)."""
    from mcap.writer import CompressionType, Writer

    n = (mib << 20) // 4
    data = b'{"time":[' + b"0," * n + b'0],"disp_x":[' + b"0," * n + b"0]}"
    buf = io.BytesIO()
    w = Writer(buf, compression=CompressionType.ZSTD, chunk_size=1 << 30)
    w.start()
    sid = w.register_schema("siva.Recording", "jsonschema", b"{}")
    cid = w.register_channel("/recording", "json", sid)
    w.add_message(cid, log_time=1, publish_time=1, data=data, sequence=0)
    w.finish()
    return buf.getvalue()


def mat_bomb(mib: int = 120) -> bytes:
    """A compressed MATLAB file whose ``disp_x`` decompresses to ``mib`` MiB of zeros."""
    import scipy.io

    n = (mib << 20) // 8
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"time": np.arange(400) / 1e3, "disp_x": np.zeros(n)},
                     do_compression=True, oned_as="column")
    return buf.getvalue()


#: (id, content type, body builder) of the big hostile uploads; sizes in MB of body
BIG_UPLOADS = (
    ("mcap-zstd-127MiB-json", "application/x-mcap", lambda mb: mcap_json_bomb(127)),
    ("npz-bomb-120MiB", "application/x-npz", lambda mb: npz_bomb(True, 120)),
    ("mat-bomb-120MiB", "application/x-matlab-data", lambda mb: mat_bomb(120)),
    ("csv-big", "text/csv", csv_big),
    ("csv-one-line", "text/csv", csv_one_line),
    ("csv-short-rows", "text/csv", csv_short_rows),
    ("json-big", "application/json", json_big),
    ("lvm-big", "application/x-lvm", lvm_big),
)
