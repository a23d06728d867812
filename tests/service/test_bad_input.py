"""Bad input never breaks the service: 4xx with a detail naming what and where, never a
5xx (the client fixture fails on any), and nothing is stored on failure."""
from __future__ import annotations

import os

import httpx
import pytest

TOKEN = "s3cret-token"
LIMIT = 1_000_000  # bytes; the Duffing CSVs (~695 kB) fit, 1.5 MB does not


@pytest.fixture(scope="module")
def srv(make_server, linear):
    s = make_server(env={"SIVA_API_TOKEN": TOKEN, "SIVA_MAX_UPLOAD_BYTES": str(LIMIT)})
    with s.client() as c:
        assert c.put("/v1/systems/bad", json=linear).status_code == 201
    return s


@pytest.fixture
def c(srv):
    with srv.client() as cl:
        yield cl


def _stored(srv, system: str = "bad") -> list[str]:
    """Every file under the system's recordings dir (temporary ones included)."""
    d = srv.data_dir / "systems" / system / "recordings"
    return sorted(p.name for p in d.iterdir()) if d.exists() else []


def _csv(rows: list[str], header: str = "time,disp_x,vel_x,acc_x") -> bytes:
    return ("\n".join([header, *rows]) + "\n").encode()


def _good_rows(n: int = 40) -> list[str]:
    return [f"{i * 1e-3:.6f},{0.001 * i:.6f},{0.1:.6f},{-1.0:.6f}" for i in range(n)]


def _post(c, body: bytes, ctype: str = "text/csv", **params) -> httpx.Response:
    return c.post("/v1/systems/bad/recordings", params={"role": "train", **params},
                  content=body, headers={"content-type": ctype})


def _replace(rows: list[str], i: int, row: str) -> list[str]:
    rows = list(rows)
    rows[i] = row
    return rows


BAD_CSV = {
    # name: (body, fragments the detail must contain)
    "nan": (_csv(_replace(_good_rows(), 9, "0.009000,nan,0.1,-1.0")),
            ["'disp_x'", "row 11", "not finite"]),
    "inf": (_csv(_replace(_good_rows(), 4, "0.004000,0.004,inf,-1.0")),
            ["'vel_x'", "row 6", "not finite"]),
    "ragged": (_csv(_replace(_good_rows(), 7, "0.007000,0.007")), ["row 9", "2 values"]),
    "text_cell": (_csv(_replace(_good_rows(), 2, "0.002000,abc,0.1,-1.0")),
                  ["'disp_x'", "row 4", "'abc'"]),
    "non_uniform": (_csv(_replace(_good_rows(), 20, "0.020500,0.02,0.1,-1.0")),
                    ["'time'", "row", "non-uniform"]),
    "decreasing": (_csv(_replace(_good_rows(), 20, "0.018000,0.02,0.1,-1.0")),
                   ["'time'", "row", "does not increase"]),
    "missing_dof": (_csv([f"{i * 1e-3:.6f},1.0" for i in range(40)], header="time,force_x"),
                    ["DOF 'x'", "acc_x"]),
    # ("t" is a name of the time column since issue 17; "tick" is not)
    "no_time": (_csv([f"{i},{i}" for i in range(40)], header="tick,acc_x"), ["'time'", "tick"]),
    "too_few": (_csv(_good_rows(5)), ["5 samples"]),
    "wrong_unit": (_csv(_good_rows(), header="time,disp_x,vel_x,acc_x [g]"),
                   ["'acc_x [g]'", "unit"]),
    "binary": (bytes(range(256)) * 8, ["binary"]),
    "not_utf8": (b"time,acc_x\n0,\xff\xfe\n", ["UTF-8"]),
    "header_only": (b"time,disp_x,vel_x,acc_x\n", ["0 samples"]),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_malformed_csv_refused_with_where(c, srv, case):
    body, fragments = BAD_CSV[case]
    r = _post(c, body, name=f"{case}.csv")
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail.startswith(f"{case}.csv:"), detail
    for frag in fragments:
        assert frag in detail, (frag, detail)
    assert _stored(srv) == []


def test_bad_json_recordings(c, srv):
    r = _post(c, b'{"time": [0, 1e-3, ', "application/json", name="cut.json")
    assert r.status_code == 422 and "cut.json" in r.json()["detail"]
    assert "invalid JSON" in r.json()["detail"]
    r = _post(c, b'{"time": 5, "acc_x": [1]}', "application/json", name="scalar.json")
    assert r.status_code == 422 and "'time'" in r.json()["detail"]
    cols = {"time": [i * 1e-3 for i in range(40)], "acc_x": [0.0] * 39 + ["x"]}
    r = c.post("/v1/systems/bad/recordings?role=train&name=str.json", json=cols)
    assert r.status_code == 422 and "'acc_x'" in r.json()["detail"], r.text
    r = _post(c, b"[1, 2, 3]", "application/json")
    assert r.status_code == 422
    assert _stored(srv) == []


def test_bad_upload_envelopes(c, srv):
    r = _post(c, b"", name="empty.csv")
    assert r.status_code == 422 and "empty" in r.json()["detail"]
    r = _post(c, _csv(_good_rows()), "image/png")
    assert r.status_code == 415 and "image/png" in r.json()["detail"]
    r = _post(c, _csv(_good_rows()), role="testing")
    assert r.status_code == 422 and "role" in r.json()["detail"]
    r = _post(c, _csv(_good_rows()), format="xlsx")
    assert r.status_code == 422 and "format" in r.json()["detail"]
    no_file = b'--xx\r\nContent-Disposition: form-data; name="role"\r\n\r\ntrain\r\n--xx--\r\n'
    r = c.post("/v1/systems/bad/recordings", content=no_file,
               headers={"content-type": "multipart/form-data; boundary=xx"})
    assert r.status_code == 422 and "got 0" in r.json()["detail"], r.text
    r = c.post("/v1/systems/bad/recordings?role=train", content=b"--xx\r\ngarbage",
               headers={"content-type": "multipart/form-data; boundary=xx"})
    assert r.status_code in (400, 422), r.text
    r = c.post("/v1/systems/bad/recordings?role=train", data={"role": "train"})
    assert r.status_code == 415, r.text  # urlencoded form: not a recording format
    r = c.post("/v1/systems/bad/recordings?role=train",
               files={"a": ("a.csv", _csv(_good_rows()), "text/csv"),
                      "b": ("b.csv", _csv(_good_rows(41)), "text/csv")})
    assert r.status_code == 422 and "exactly one file" in r.json()["detail"]
    assert _stored(srv) == []


def test_unknown_system_is_404(c, srv):
    for method, path in (("GET", "/v1/systems/nope"), ("GET", "/v1/systems/nope/estimate"),
                         ("GET", "/v1/systems/nope/drift"),
                         ("GET", "/v1/systems/nope/recordings"),
                         ("GET", "/v1/systems/bad/recordings/r999999-x"),
                         ("POST", "/v1/systems/nope/recordings"),
                         ("DELETE", "/v1/systems/nope")):
        r = c.request(method, path, content=_csv(_good_rows()) if method == "POST" else None,
                      headers={"content-type": "text/csv"})
        assert r.status_code == 404, (method, path, r.text)
        assert "'nope'" in r.json()["detail"] or "r999999-x" in r.json()["detail"]
    assert not (srv.data_dir / "systems" / "nope").exists()


BAD_SPECS = {
    "negative_mass": ({"dofs": ["x"], "mass": {"x": -1.0},
                       "elements": [{"kind": "spring", "between": ["x", "ground"],
                                     "params": {"k": "k"}}]}, ["mass.x", "positive"]),
    "unknown_kind": ({"dofs": ["x"], "mass": {"x": 1.0},
                      "elements": [{"kind": "magic_spring", "between": ["x", "ground"],
                                    "params": {"k": "k"}}]},
                     ["elements[0].kind", "magic_spring"]),
    "dangling_dof": ({"dofs": ["x"], "mass": {"x": 1.0},
                      "elements": [{"kind": "spring", "between": ["x", "y"],
                                    "params": {"k": "k"}}]}, ["elements[0].between", "'y'"]),
    "missing_coefficient": ({"dofs": ["x"], "mass": {"x": 1.0},
                             "elements": [{"kind": "spring", "between": ["x", "ground"],
                                           "params": {}}]}, ["elements[0].params", "'k'"]),
    "kind_not_a_string": ({"dofs": ["x"], "mass": {"x": 1.0},
                           "elements": [{"kind": ["spring"], "between": ["x", "ground"],
                                         "params": {"k": "k"}}]}, ["model spec"]),
    "no_elements": ({"dofs": ["x"], "mass": {"x": 1.0}, "elements": []}, ["'elements'"]),
    "not_an_object": ([1, 2], ["object"]),
    "nan_mass": ({"dofs": ["x"], "mass": {"x": "NaN"}, "elements": []}, ["mass.x"]),
}


@pytest.mark.parametrize("case", sorted(BAD_SPECS))
def test_invalid_spec_refused(c, srv, case):
    spec, fragments = BAD_SPECS[case]
    r = c.put(f"/v1/systems/spec-{case.replace('_', '-')}", json=spec)
    assert r.status_code == 422, r.text
    for frag in fragments:
        assert frag in r.json()["detail"], (frag, r.json()["detail"])
    assert not (srv.data_dir / "systems" / f"spec-{case.replace('_', '-')}").exists()
    names = [s["name"] for s in c.get("/v1/systems").json()["systems"]]
    assert names == ["bad"]


def test_malformed_spec_bodies(c, srv):
    r = c.put("/v1/systems/spec-json", content=b'{"dofs": ["x"],',
              headers={"content-type": "application/json"})
    assert r.status_code == 400 and "line 1" in r.json()["detail"]
    r = c.put("/v1/systems/spec-json", content=b"", headers={"content-type": "application/json"})
    assert r.status_code == 400 and "empty" in r.json()["detail"]
    r = c.put("/v1/systems/spec-json", content=b"dofs: [x]",
              headers={"content-type": "application/yaml"})
    assert r.status_code == 415
    r = c.put("/v1/systems/spec-json", content=b"dofs = [x",
              headers={"content-type": "application/toml"})
    assert r.status_code == 400 and "TOML" in r.json()["detail"]
    r = c.put("/v1/systems/bad%20name!", json={})
    assert r.status_code == 422 and "system name" in r.json()["detail"]
    assert not (srv.data_dir / "systems" / "spec-json").exists()


def test_upload_limit_declared_length(c, srv):
    big = b"time,acc_x\n" + b"0.000000,0.0\n" * (LIMIT // 13 + 1000)
    assert len(big) > LIMIT
    r = _post(c, big, name="big.csv")
    assert r.status_code == 413 and str(LIMIT) in r.json()["detail"]
    assert _stored(srv) == []


def test_upload_limit_streamed_without_length(c, srv):
    sent = 0

    def chunks():
        nonlocal sent
        yield b"time,acc_x\n"
        for _ in range(400):  # up to 4 MB; the server must stop us well before the end
            sent += 10_000
            yield b"0.000000,0.0\n" * 769 + b"0.00\n"

    r = c.post("/v1/systems/bad/recordings?role=train", content=chunks(),
               headers={"content-type": "text/csv"})
    assert r.status_code == 413, r.text
    assert "limit" in r.json()["detail"]
    assert _stored(srv) == []


def test_upload_limit_multipart(c, srv):
    big = b"time,acc_x\n" + b"0.000000,0.0\n" * (LIMIT // 13 + 1000)
    r = c.post("/v1/systems/bad/recordings?role=train", files={"file": ("big.csv", big)})
    assert r.status_code == 413
    assert _stored(srv) == []


def test_writes_need_the_token(srv, linear):
    good = _csv(_good_rows())
    for token in (None, "wrong-token"):
        with srv.client(token=token) as anon:
            r = anon.put("/v1/systems/no-auth", json=linear)
            assert r.status_code == 401 and "Bearer" in r.json()["detail"]
            assert r.headers["www-authenticate"] == "Bearer"
            r = anon.post("/v1/systems/bad/recordings?role=train", content=good,
                          headers={"content-type": "text/csv"})
            assert r.status_code == 401
            assert anon.delete("/v1/systems/bad").status_code == 401
            assert anon.post("/v1/systems/bad/drift/reset").status_code == 401
            # reads stay open
            assert anon.get("/v1/systems/bad/estimate").status_code == 200
            assert anon.get("/healthz").status_code == 200
    with httpx.Client(base_url=srv.base_url) as raw:
        r = raw.put("/v1/systems/no-auth", json=linear, headers={"Authorization": TOKEN})
        assert r.status_code == 401  # no "Bearer" scheme
    assert not (srv.data_dir / "systems" / "no-auth").exists()
    assert _stored(srv) == []
    # and with the token the same upload is accepted
    with srv.client() as ok:
        r = ok.post("/v1/systems/bad/recordings?role=train", content=good,
                    headers={"content-type": "text/csv"})
        assert r.status_code == 202, r.text
        ok.delete("/v1/systems/bad")
        assert ok.put("/v1/systems/bad", json=linear).status_code == 201


def test_unknown_columns_only_warn(c, srv):
    rows = [r + ",7" for r in _good_rows()]
    r = _post(c, _csv(rows, header="time,disp_x,vel_x,acc_x,temperature"), name="warm.csv")
    assert r.status_code == 202, r.text
    assert any("temperature" in w for w in r.json()["warnings"])
    assert len([n for n in _stored(srv) if n.endswith(".data.csv")]) == 1
    assert not [n for n in _stored(srv) if n.startswith(".")]


def test_no_unhandled_errors_so_far(srv):
    assert "unhandled error" not in srv.log_text()
    assert os.path.isdir(srv.data_dir)
