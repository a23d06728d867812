"""Browser-facing safety of the service: Host allow-list, cross-site write refusal, headers.

Why a middleware of its own: the API is meant for scripts (curl, httpx, siva-client), which
send no ``Origin`` and no ``Sec-Fetch-Site``; a browser always sends them on a cross-site
write.  Without a token any web page a user visits could otherwise POST a ``text/plain``
or form body (no CORS preflight) to ``http://127.0.0.1:8000`` - e.g. reset the drift alarms -
and a DNS-rebinding page could even read the answers.  So, before any route runs:

- ``Host`` must be one of the allowed names (:func:`allowed_hosts`: the loopback names, the
  bound host and, when bound to every interface, this machine's names and addresses, or
  ``SIVA_ALLOWED_HOSTS``); anything else is answered 421.  ``/healthz`` stays open to
  probes whatever their Host.
- an unsafe method (POST, PUT, PATCH, DELETE) carrying ``Sec-Fetch-Site`` other than
  ``same-origin``/``none``, or an ``Origin`` whose host is not the request's own ``Host``
  (nor in ``SIVA_ALLOWED_ORIGINS``), is refused 403.  No Origin and no Sec-Fetch-Site
  (a non-browser client) passes: the token, when set, is what protects against those.
- every response carries ``X-Content-Type-Options: nosniff``, ``X-Frame-Options: DENY``,
  ``Referrer-Policy: same-origin`` and a Content-Security-Policy (:data:`CSP`) unless the
  route set its own (``/docs`` adds the hash of Swagger UI's one inline script).
"""
from __future__ import annotations

import base64
import hashlib
import json
import socket
from typing import Iterable
from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1", "testserver")
WILDCARD_BINDS = ("0.0.0.0", "::", "")
UNSAFE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: paths a probe reaches whatever Host it sends
HOST_EXEMPT = ("/healthz",)

#: the policy of every page: only this origin's scripts; inline styles (the dashboard and
#: the diagnosis report set some); images from here or data: URLs (the report's figures)
CSP = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
       "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
       "frame-ancestors 'none'; form-action 'self'")


def csp_with_scripts(*inline_scripts: str) -> str:
    """:data:`CSP` that also allows exactly these inline scripts (by their sha256)."""
    hashes = " ".join("'sha256-" + base64.b64encode(hashlib.sha256(s.encode()).digest())
                      .decode() + "'" for s in inline_scripts)
    return CSP.replace("script-src 'self'", f"script-src 'self' {hashes}")


def _split_host(host: str) -> str:
    """``'[::1]:8000'`` -> ``'::1'``, ``'Example.org:80'`` -> ``'example.org'``."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:].split("]", 1)[0]
    if host.count(":") == 1:
        return host.split(":", 1)[0]
    return host


def _machine_names() -> set[str]:
    """This machine's host name, FQDN and addresses (for a server bound to all interfaces)."""
    names: set[str] = set()
    try:
        for n in (socket.gethostname(), socket.getfqdn()):
            if n:
                names.add(n.lower())
                for info in socket.getaddrinfo(n, None):
                    names.add(str(info[4][0]).lower())
    except OSError:
        pass
    return names


def allowed_hosts(configured: Iterable[str] | None, bind_host: str | None) -> set[str] | None:
    """The Host names answered (None: any).  ``configured`` (SIVA_ALLOWED_HOSTS) replaces
    the defaults; ``*`` in it turns the check off."""
    if configured:
        names = {_split_host(h) for h in configured if h.strip()}
        return None if "*" in names else names | set(LOOPBACK_HOSTS)
    names = set(LOOPBACK_HOSTS)
    bind = (bind_host or "").strip().lower()
    if bind in WILDCARD_BINDS:
        names |= _machine_names()
    else:
        names.add(_split_host(bind))
    return names


class SecurityMiddleware:
    """Host allow-list, cross-site write refusal and security headers (module docstring)."""

    def __init__(self, app: ASGIApp, hosts: set[str] | None,
                 origins: Iterable[str] = ()) -> None:
        self.app = app
        self.hosts = hosts
        self.origins = {o.strip().lower().rstrip("/") for o in origins if o.strip()}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1")
                   for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        path = scope.get("path", "")
        if self.hosts is not None and path not in HOST_EXEMPT \
                and _split_host(host) not in self.hosts:
            await _refuse(send, 421, f"Host {host[:100]!r} is not served here (DNS rebinding "
                                     "guard); add it to SIVA_ALLOWED_HOSTS")
            return
        if scope.get("method", "GET").upper() in UNSAFE_METHODS:
            why = cross_site(headers, self.origins)
            if why:
                await _refuse(send, 403, f"cross-site write refused ({why}); browsers may "
                                         "only write from this service's own pages "
                                         "(SIVA_ALLOWED_ORIGINS)")
                return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {k.lower() for k, _ in message.get("headers", [])}
                extra = [(b"x-content-type-options", b"nosniff"),
                         (b"x-frame-options", b"DENY"),
                         (b"referrer-policy", b"same-origin"),
                         (b"content-security-policy", CSP.encode())]
                message = {**message, "headers": [*message.get("headers", []),
                                                  *[(k, v) for k, v in extra
                                                    if k not in present]]}
            await send(message)

        await self.app(scope, receive, with_headers)


def cross_site(headers: dict[str, str], origins: Iterable[str] = ()) -> str | None:
    """Why a request is cross-site (None: same-origin, or not from a browser).

    ``headers`` has lower-case names; ``origins`` are extra origins allowed to write."""
    host = headers.get("host", "")
    origin = headers.get("origin")
    o = (origin or "").strip().lower().rstrip("/")
    if origin is not None and o in {x.strip().lower().rstrip("/") for x in origins}:
        return None  # an origin the operator allowed (SIVA_ALLOWED_ORIGINS)
    site = headers.get("sec-fetch-site", "").strip().lower()
    if site and site not in ("same-origin", "none"):
        return f"Sec-Fetch-Site: {site}"
    if origin is None:
        return None
    parts = urlsplit(o)
    if o == "null" or not parts.netloc:
        return f"Origin: {origin[:100]}"
    if parts.netloc != host.strip().lower():
        return f"Origin {origin[:100]} is not this host {host[:100]!r}"
    return None


async def _refuse(send: Send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"x-content-type-options", b"nosniff"),
                            (b"x-frame-options", b"DENY"),
                            (b"content-security-policy", CSP.encode())]})
    await send({"type": "http.response.body", "body": body})


__all__ = ["SecurityMiddleware", "cross_site", "allowed_hosts", "CSP", "csp_with_scripts", "LOOPBACK_HOSTS"]
