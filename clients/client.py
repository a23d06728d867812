"""`SivaClient`: a thin, typed-enough wrapper over the service's HTTP API (CONTRACT.md).

Why a client at all: uploads need the right content type per format, writes need the bearer
token, and errors should surface as the server's own ``detail`` message (which names what is
wrong and where) instead of an HTTP status.  Everything returns the server's JSON as dicts.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence
from urllib.parse import quote

import httpx

API = "/v1"
DEFAULT_URL = "http://127.0.0.1:8000"

# upload content type per file suffix (CONTRACT.md: CSV; the same content as JSON / MCAP)
# (the server's registry: siva_core.RECORDING_FORMATS; a test keeps the two in step)
CONTENT_TYPES: dict[str, str] = {
    "csv": "text/csv",
    "txt": "text/csv",
    "json": "application/json",
    "npz": "application/x-npz",
    "mcap": "application/x-mcap",
    "lvm": "application/x-lvm",
    "uff": "application/x-uff",
    "unv": "application/x-uff",
    "uff58": "application/x-uff",
    "tdms": "application/x-tdms",
    "mat": "application/x-matlab-data",
}
RECORDING_SUFFIXES = tuple(f".{s}" for s in CONTENT_TYPES if s != "txt")  # .txt: too vague
ROLES = ("train", "validation")


class SivaClientError(RuntimeError):
    """A request the server refused (``status`` and its ``detail``) or could not be sent."""

    def __init__(self, message: str, status: int | None = None, detail: Any = None) -> None:
        super().__init__(message)
        self.status = status
        self.detail = detail


class SivaClient:
    """Client of one siva service.  ``token``: the service's ``SIVA_API_TOKEN``, if it has one."""

    def __init__(self, base_url: str = DEFAULT_URL, token: str | None = None, *,
                 timeout: float = 60.0, transport: httpx.BaseTransport | None = None) -> None:
        self.base_url = base_url.rstrip("/")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout,
                                  transport=transport)

    # ------------------------------------------------------------------ plumbing
    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "SivaClient":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        try:
            r = self._http.request(method, path, **kw)
        except httpx.TransportError as exc:
            raise SivaClientError(f"cannot reach the siva service at {self.base_url} "
                                  f"({type(exc).__name__}: {exc})") from None
        if r.status_code >= 400:
            detail: Any
            try:
                detail = r.json().get("detail", r.text)
            except (ValueError, AttributeError):
                detail = r.text.strip() or r.reason_phrase
            raise SivaClientError(f"{method} {path}: {r.status_code} {_detail_text(detail)}",
                                  r.status_code, detail)
        return r

    def _json(self, method: str, path: str, **kw: Any) -> Any:
        r = self._request(method, path, **kw)
        return r.json() if r.content else {}

    # ------------------------------------------------------------------ API
    def health(self) -> bool:
        """True when GET /healthz answers 200."""
        try:
            return self._http.get("/healthz").status_code == 200
        except httpx.TransportError:
            return False

    def register(self, name: str, spec: Mapping[str, Any] | str | Path) -> dict[str, Any]:
        """PUT the model spec (a dict, or a TOML/JSON file path).  Adds ``created``:
        True on 201 (new), False on 200 (the same spec was already there)."""
        body = load_spec(spec) if isinstance(spec, (str, Path)) else dict(spec)
        r = self._request("PUT", _sys(name), json=body)
        out = r.json() if r.content else {}
        if isinstance(out, dict):
            out.setdefault("created", r.status_code == 201)
        return out

    def upload(self, name: str, path_or_bytes: str | Path | bytes, role: str | None = None,
               *, fmt: str | None = None, channel_map: Sequence[str] = (),
               units: Sequence[str] = ()) -> dict[str, Any]:
        """POST one recording; returns the server's acknowledgement (``{"id": ...}``).

        ``role`` None lets the server choose (its documented default policy).  Bytes are
        sent as CSV unless ``fmt`` says otherwise; files by their suffix.  ``channel_map``
        (``"Accel LO=acc_LO"``) and ``units`` (``"acc_LO=g"``) are the upload's ``map`` and
        ``unit`` query parameters: how the server reads this file's channels.
        """
        if isinstance(path_or_bytes, (bytes, bytearray)):
            data, fmt = bytes(path_or_bytes), (fmt or "csv")
            filename = None
        else:
            p = Path(path_or_bytes)
            try:
                data = p.read_bytes()
            except OSError as exc:
                raise SivaClientError(f"{p}: cannot read ({exc.strerror})") from None
            fmt = fmt or p.suffix.lower().lstrip(".") or "csv"
            filename = p.name
        if fmt not in CONTENT_TYPES:
            raise SivaClientError(f"unknown recording format {fmt!r} "
                                  f"(one of {', '.join(sorted(CONTENT_TYPES))})")
        params: dict[str, str | list[str]] = {}
        if channel_map:
            params["map"] = list(channel_map)
        if units:
            params["unit"] = list(units)
        if role is not None:
            params["role"] = _check_role(role)
        if filename:
            params["name"] = filename  # the server's name for the record, used in messages
        headers = {"Content-Type": CONTENT_TYPES[fmt]}
        return self._json("POST", f"{_sys(name)}/recordings", params=params,
                          content=data, headers=headers)

    def upload_folder(self, name: str, folder: str | Path, role: str | None = None,
                      warn: Callable[[str], None] | None = None, *,
                      channel_map: Sequence[str] = (),
                      units: Sequence[str] = ()) -> list[dict[str, Any]]:
        """Upload every recording file of a folder, in name order.

        Roles: ``role`` for all when given; otherwise files under ``train/`` and
        ``val/`` or ``validation/`` subfolders get those roles, and files elsewhere whose
        name starts with ``val`` are validation; the rest are left to the server's default.
        What is not a recording is skipped with a warning (``warn``): files of another
        suffix, and files the server refuses as recordings (413/415/422); any other error
        (token, unknown system, unreachable server) stops the upload.
        """
        warn = warn or (lambda msg: None)
        items, others = folder_plan(folder, role, with_skipped=True)
        for p in others:
            warn(f"skipping {p}: not a recording format ({', '.join(RECORDING_SUFFIXES)})")
        if not items:
            raise SivaClientError(f"{folder}: no recording files ({', '.join(RECORDING_SUFFIXES)})")
        out = []
        for path, r in items:
            try:
                ack = self.upload(name, path, role=r, channel_map=channel_map, units=units)
            except SivaClientError as exc:
                if exc.status not in (413, 415, 422):
                    raise
                warn(f"skipping {path}: {exc}")
                continue
            out.append({"path": str(path), "role": r, **ack})
        return out

    def delete(self, name: str, *, archive_logs: bool = False) -> dict[str, Any]:
        """DELETE a system with its recordings, estimate and history, and its MCAP event
        logs: deleted, or moved to the server's ``<data>/archive/logs/`` with
        ``archive_logs``.  The answer's ``logs`` says which (``action``, ``files``)."""
        return self._json("DELETE", _sys(name),
                          params={"logs": "archive" if archive_logs else "delete"})

    def export(self, name: str, what: str) -> bytes:
        """A CSV export: ``estimates`` | ``records`` | ``drift`` | ``alarms`` (the bytes)."""
        return self._request("GET", f"{_sys(name)}/export/{quote(what, safe='')}.csv").content

    def drift_reset(self, name: str) -> dict[str, Any]:
        """Forget the drift reference and alarms (e.g. after a repair); history is kept."""
        return self._json("POST", f"{_sys(name)}/drift/reset")

    def system(self, name: str) -> dict[str, Any]:
        """The registered system (its spec)."""
        return self._json("GET", _sys(name))

    def recordings(self, name: str) -> Any:
        return self._json("GET", f"{_sys(name)}/recordings")

    def estimate(self, name: str) -> dict[str, Any]:
        return self._json("GET", f"{_sys(name)}/estimate")

    def drift(self, name: str) -> dict[str, Any]:
        return self._json("GET", f"{_sys(name)}/drift")

    def wait_converged(self, name: str, timeout: float = 600.0, poll: float = 1.0,
                       min_recordings: int = 0) -> dict[str, Any]:
        """Poll the estimate until ``converged`` (and, optionally, until it counts at least
        ``min_recordings`` recordings); the estimate, or TimeoutError after ``timeout`` s."""
        return self.wait(name, "converged", timeout, poll, min_recordings)

    def wait(self, name: str, until: str = "best", timeout: float = 600.0, poll: float = 1.0,
             min_recordings: int = 0) -> dict[str, Any]:
        """Poll the estimate until ``until`` holds: "best" (the headline ``parameters`` are
        the output-error estimate, ``estimate_source == "best"``) or "converged" (the
        trainer's ensemble has converged; ``best`` may still be null).  Returns the
        estimate, or raises TimeoutError after ``timeout`` s saying what it waited for."""
        if until not in ("best", "converged"):
            raise ValueError(f"wait until {until!r}: use 'best' or 'converged'")
        deadline = time.monotonic() + timeout
        last: dict[str, Any] = {}
        while True:
            try:
                last = self.estimate(name)
                counted = sum((last.get("n_recordings") or {}).values())
                done = (last.get("estimate_source") == "best" and last.get("best") is not None
                        if until == "best" else bool(last.get("converged")))
                if done and counted >= min_recordings:
                    return last
            except SivaClientError as exc:
                if exc.status not in (404, 409, 425, 503):  # not "no estimate yet"
                    raise
            if time.monotonic() >= deadline:
                what = ("no best estimate yet" if until == "best" else "not converged")
                raise TimeoutError(f"{name}: {what} after {timeout:g} s (epoch "
                                   f"{last.get('epoch')}, converged {last.get('converged')}, "
                                   f"source {last.get('estimate_source')})")
            time.sleep(poll)


def load_spec(path: str | Path) -> dict[str, Any]:
    """A model spec file (TOML, or JSON by suffix) as the JSON body of PUT."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise SivaClientError(f"{p}: cannot read model spec ({exc.strerror})") from None
    try:
        if p.suffix.lower() == ".json":
            return json.loads(text)
        import tomllib

        return tomllib.loads(text)
    except (ValueError, json.JSONDecodeError) as exc:
        raise SivaClientError(f"{p}: not a valid model spec file ({exc})") from None


def folder_plan(folder: str | Path, role: str | None = None, *, with_skipped: bool = False
                ) -> Any:
    """(file, role) pairs that :meth:`SivaClient.upload_folder` sends, in order; with
    ``with_skipped`` also the files it leaves out (another suffix; hidden files are ignored)."""
    root = Path(folder)
    if not root.is_dir():
        raise SivaClientError(f"{root}: not a folder")
    visible = sorted(p for p in root.rglob("*") if p.is_file()
                     and not any(s.startswith(".") for s in p.relative_to(root).parts))
    files = [p for p in visible if p.suffix.lower() in RECORDING_SUFFIXES]
    skipped = [p for p in visible if p.suffix.lower() not in RECORDING_SUFFIXES]
    if role is not None:
        plan = [(p, _check_role(role)) for p in files]
        return (plan, skipped) if with_skipped else plan
    out: list[tuple[Path, str | None]] = []
    for p in files:
        parts = [s.lower() for s in p.relative_to(root).parts[:-1]]
        if any(s in ("val", "validation") for s in parts):
            r: str | None = "validation"
        elif "train" in parts:
            r = "train"
        elif p.name.lower().startswith("val"):
            r = "validation"
        else:
            r = None
        out.append((p, r))
    return (out, skipped) if with_skipped else out


def _sys(name: str) -> str:
    return f"{API}/systems/{quote(name, safe='')}"


def _check_role(role: str) -> str:
    r = role.lower()
    r = {"val": "validation"}.get(r, r)
    if r not in ROLES:
        raise SivaClientError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    return r


def _detail_text(detail: Any) -> str:
    """FastAPI details are strings, or lists of validation errors: make them one line."""
    if isinstance(detail, list):
        parts = []
        for d in detail:
            if isinstance(d, Mapping):
                loc = ".".join(str(x) for x in d.get("loc", []))
                parts.append(f"{loc}: {d.get('msg', d)}" if loc else str(d.get("msg", d)))
            else:
                parts.append(str(d))
        return "; ".join(parts)
    return str(detail)
