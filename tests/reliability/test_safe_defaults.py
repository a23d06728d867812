"""Safe defaults against a real server (issue 19): reads behind the token everywhere when
asked, no cross-site writes, a Host allow-list, security headers on HTML, and a diagnosis
that only a writer may start."""
from __future__ import annotations

import httpx
import pytest

TOKEN = "tok19"
EVIL = "http://evil.example"


@pytest.fixture(scope="module")
def locked(make_server, linear, oscillator):
    """Token for writes and reads; system h with one train and one validation record."""
    s = make_server(env={"SIVA_API_TOKEN": TOKEN, "SIVA_API_TOKEN_READS": "1",
                         "SIVA_REFINE_EVERY_S": "0"})
    with s.client() as c:
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
        for role, v0 in (("train", 1.0), ("validation", 0.6)):
            r = c.post(f"/v1/systems/h/recordings?role={role}", content=oscillator(v0=v0),
                       headers={"content-type": "text/csv"})
            assert r.status_code == 202, r.text
    return s


@pytest.fixture(scope="module")
def open_srv(make_server, linear):
    """The default setup: no token."""
    s = make_server(env={"SIVA_REFINE_EVERY_S": "0"})
    with s.client() as c:
        assert c.put("/v1/systems/h", json={**linear, "name": "h"}).status_code == 201
    return s


READS = ("/metrics", "/v1/systems/h/latest-record", "/v1/systems/h/diagnosis",
         "/v1/systems/h/diagnosis/report", "/v1/systems", "/v1/systems/h",
         "/v1/systems/h/estimate", "/v1/systems/h/drift", "/v1/systems/h/recordings")
OPEN = ("/healthz", "/openapi.json", "/", "/docs", "/static/dashboard.js")


def test_every_read_needs_the_token_when_asked(locked):
    with httpx.Client(base_url=locked.base_url, timeout=30) as anon:
        for path in READS:
            r = anon.get(path)
            assert r.status_code == 401, (path, r.status_code, r.text[:200])
        for path in OPEN:
            assert anon.get(path).status_code == 200, path
    with locked.client() as auth:
        for path in READS:
            if "diagnosis" in path:
                continue  # its own test: a GET that may start a run
            assert auth.get(path).status_code == 200, path


def test_cross_site_writes_are_refused(open_srv, oscillator):
    url = open_srv.base_url
    with httpx.Client(base_url=url, timeout=60) as c:
        body = oscillator()
        cases = [
            ("text/plain upload", "POST", "/v1/systems/h/recordings?role=train",
             {"content-type": "text/plain", "origin": EVIL}, body),
            ("form upload", "POST", "/v1/systems/h/recordings?role=train",
             {"content-type": "application/x-www-form-urlencoded", "origin": EVIL}, body),
            ("drift reset", "POST", "/v1/systems/h/drift/reset", {"origin": EVIL}, None),
            ("delete", "DELETE", "/v1/systems/h", {"origin": EVIL}, None),
            ("opaque origin", "POST", "/v1/systems/h/drift/reset", {"origin": "null"}, None),
            ("fetch metadata", "POST", "/v1/systems/h/drift/reset",
             {"sec-fetch-site": "cross-site"}, None),
            ("same-site is not same-origin", "PUT", "/v1/systems/x", {
                "sec-fetch-site": "same-site", "content-type": "application/json"}, b"{}"),
        ]
        for what, method, path, headers, content in cases:
            r = c.request(method, path, headers=headers, content=content)
            assert r.status_code == 403, (what, r.status_code, r.text[:200])
            assert "cross-site" in r.json()["detail"]
        # the system is untouched, and the dashboard (same origin) and curl-like clients work
        assert c.get("/v1/systems/h").status_code == 200
        assert c.post("/v1/systems/h/drift/reset",
                      headers={"origin": url, "sec-fetch-site": "same-origin"}
                      ).status_code == 200
        assert c.post("/v1/systems/h/recordings?role=train", content=body,
                      headers={"content-type": "text/csv"}).status_code == 202


def test_foreign_host_is_refused_but_probes_pass(open_srv):
    with httpx.Client(base_url=open_srv.base_url, timeout=30) as c:
        for host in ("evil.example", "evil.example:80", "attacker.rebind.network"):
            r = c.get("/v1/systems", headers={"host": host})
            assert r.status_code == 421, (host, r.status_code)
            assert "SIVA_ALLOWED_HOSTS" in r.json()["detail"]
            assert c.post("/v1/systems/h/drift/reset", headers={"host": host}
                          ).status_code == 421
        assert c.get("/healthz", headers={"host": "10.1.2.3:8000"}).status_code == 200
        for host in (f"127.0.0.1:{open_srv.port}", f"localhost:{open_srv.port}", "localhost"):
            assert c.get("/v1/systems", headers={"host": host}).status_code == 200, host


def test_security_headers_on_html_and_api(open_srv):
    with httpx.Client(base_url=open_srv.base_url, timeout=30) as c:
        for path in ("/", "/docs", "/v1/systems", "/static/dashboard.js"):
            r = c.get(path)
            assert r.status_code == 200
            assert r.headers["x-content-type-options"] == "nosniff", path
            assert r.headers["x-frame-options"] == "DENY", path
            csp = r.headers["content-security-policy"]
            assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp, path
            assert "unsafe-eval" not in csp and "'unsafe-inline'" not in \
                csp.split("script-src")[1].split(";")[0], path
        docs = c.get("/docs")
        # Swagger UI's one inline script is allowed by its hash, nothing else inline
        assert "'sha256-" in docs.headers["content-security-policy"]
        assert "/static/vendor/swagger-ui/swagger-ui-bundle.js" in docs.text


def test_host_and_origin_rules():
    """The allow-lists as functions: defaults, configured, wildcard binds, extra origins."""
    import socket

    from service.api.security import allowed_hosts, cross_site

    loop = allowed_hosts(None, "127.0.0.1")
    assert {"localhost", "127.0.0.1", "::1"} <= loop and "evil.example" not in loop
    assert "10.0.0.5" in allowed_hosts([], "10.0.0.5")
    assert socket.gethostname().lower() in allowed_hosts(None, "0.0.0.0")
    assert allowed_hosts(["siva.example.org:8000"], "0.0.0.0") >= {"siva.example.org",
                                                                    "localhost"}
    assert allowed_hosts(["*"], "127.0.0.1") is None
    ops = "https://ops.example.org"
    assert cross_site({"host": "siva:1", "origin": ops, "sec-fetch-site": "cross-site"},
                      [ops]) is None
    assert cross_site({"host": "siva:1", "origin": "https://evil.example"}, [ops])
    assert cross_site({"host": "siva:1", "origin": "http://siva:1"}) is None
    assert cross_site({"host": "siva:1", "origin": "http://siva:2"})
    assert cross_site({"host": "siva:1"}) is None  # curl, httpx, siva-client
