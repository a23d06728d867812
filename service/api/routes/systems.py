"""HTTP routes (prefix /v1, CONTRACT.md).  Handlers only parse, check and delegate.

Anything that touches the disk (fsync) or parses a recording runs in the thread pool, and
reads return the worker's latest published snapshot, so no route ever waits for training.
"""
from __future__ import annotations

import asyncio
import contextlib
import hmac
from typing import Any, AsyncIterator

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from siva_core import media_types, parse_pairs, resolve_format

from ...errors import ApiError, UploadTooLarge
from ..limits import LimitError, parse_spec_body
from ..security import cross_site
from ..schemas import (DriftReport, ErrorDetail, Estimate, Health, RecordingAck, RecordingInfo,
                       RecordingList, SystemAck, SystemList, SystemSpec)
from ...errors import UnknownRecording, UnknownSystem
from ...storage.recordings import FORMATS
from ...storage.store import NAME_RE
from ...trainer.estimate import estimate_view


router = APIRouter()

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorDetail, "description": text} for code, text in {
        400: "unreadable body: malformed JSON, TOML or multipart, a bad Content-Length",
        401: "no or a wrong bearer token (when SIVA_API_TOKEN is set; reads too with "
             "SIVA_API_TOKEN_READS=1)",
        403: "a cross-site write from a browser (Origin / Sec-Fetch-Site of another site)",
        404: "unknown system or recording",
        409: "conflicting spec or role",
        413: "body above SIVA_MAX_UPLOAD_BYTES, or a recording above the read limits",
        415: "unsupported content type",
        421: "a Host header this service does not answer to (SIVA_ALLOWED_HOSTS)",
        422: "invalid spec, recording or parameter; the detail names what and where",
        503: "too many uploads being parsed at once: retry after Retry-After seconds",
        507: "the data directory is full or read-only: nothing was changed",
    }.items()}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The error responses of a route (every route may answer 421 for a foreign Host)."""
    return {c: ERROR_RESPONSES[c] for c in sorted({*codes, 421})}


#: what a read of one system answers beyond 200
READ_ERRORS = errors(401, 404, 409, 422)
#: what a write answers beyond its 2xx
WRITE_ERRORS = errors(400, 401, 403, 404, 409, 413, 415, 422, 507)
_ERRORS = WRITE_ERRORS

CONTENT_FORMATS = media_types()


def service_of(request: Request) -> Any:
    """The ``SivaService`` the app holds (not imported here: app.py imports this module)."""
    return request.app.state.service


def require_token(request: Request) -> None:
    """Writes need ``Authorization: Bearer <SIVA_API_TOKEN>`` when the token is set."""
    _check_token(request, "writes")


def require_write_rights(request: Request, what: str) -> None:
    """A write hidden in a GET (starting a diagnosis): the token when one is set, and no
    cross-site browser request (the middleware checks only unsafe methods)."""
    _check_token(request, "writes")
    origins = [o for o in request.app.state.settings.allowed_origins.split(",") if o.strip()]
    why = cross_site({k.lower(): v for k, v in request.headers.items()}, origins)
    if why:
        raise ApiError(403, f"{what} is a write: cross-site request refused ({why})")


def require_read_token(request: Request) -> None:
    """Reads need the token too when ``SIVA_API_TOKEN_READS=1`` (the data is not public)."""
    if request.app.state.settings.token_for_reads:
        _check_token(request, "reads")


def _check_token(request: Request, what_needs: str) -> None:
    token = request.app.state.settings.api_token
    if not token:
        return
    auth = request.headers.get("authorization", "")
    scheme, _, given = auth.partition(" ")
    if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), token.encode()):
        what = "missing" if not auth else "wrong or malformed"
        raise ApiError(401, f"Authorization header {what}: {what_needs} need "
                            "'Authorization: Bearer <SIVA_API_TOKEN>'",
                       headers={"WWW-Authenticate": "Bearer"})


def check_name(name: str) -> str:
    if not NAME_RE.fullmatch(name):
        raise ApiError(422, f"system name {name!r}: use 1-64 letters, digits, '_', '.' or '-', "
                            "starting with a letter or digit")
    return name


def _media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


# --------------------------------------------------------------------------- health, systems
@router.get("/healthz", response_model=Health, tags=["service"],
            responses={503: {"model": Health, "description": "a trainer is dead or stuck, or "
                             "checkpoints cannot be written; `problems` says which and why"}})
async def healthz(request: Request) -> Response:
    """200 when every trainer runs and persists; 503 with the reasons otherwise."""
    svc = service_of(request)
    problems = svc.health_problems()
    body = {"status": "ok" if not problems else "unhealthy", "systems": len(svc.workers),
            "workers_alive": sum(w.alive for w in list(svc.workers.values())),
            "problems": problems,
            "executor": svc.executor.describe() if svc.executor is not None else None}
    return JSONResponse(body, status_code=503 if problems else 200)


@router.get("/v1/systems", response_model=SystemList, tags=["systems"],
            responses=errors(401), dependencies=[Depends(require_read_token)])
async def list_systems(request: Request) -> dict[str, Any]:
    svc = service_of(request)
    out = []
    for name, w in sorted(list(svc.workers.items())):
        snap = w.snapshot()
        try:
            counts = svc.store.counts(name)
        except UnknownSystem:
            continue
        out.append({"name": name, "state": snap.get("state"), "epoch": snap.get("epoch", 0),
                    "converged": snap.get("converged", False), "n_recordings": counts,
                    "active_alarms": [a["parameter"] for a in snap.get("alarms", [])]})
    for name, why in sorted(svc.broken.items()):
        out.append({"name": name, "state": "invalid_spec", "epoch": 0, "converged": False,
                    "n_recordings": svc.store.counts(name), "active_alarms": [], "error": why})
    return {"systems": out}


@router.put("/v1/systems/{name}", tags=["systems"], status_code=201,
            response_model=SystemAck,
            responses={200: {"model": SystemAck, "description": "the same spec was already there"},
                       **errors(400, 401, 403, 413, 415, 422, 507)},
            openapi_extra={"requestBody": {"required": True, "content": {
                "application/json": {"schema": SystemSpec.model_json_schema()},
                "application/toml": {"schema": {"type": "string"}}}}},
            dependencies=[Depends(require_token)])
async def put_system(name: str, request: Request) -> Response:
    """Register a system with its model spec (JSON; TOML accepted as application/toml).

    Limits (413/422, docs/reliability.md): SIVA_MAX_SPEC_BYTES, SIVA_MAX_SPEC_DEPTH,
    SIVA_MAX_DOFS, SIVA_MAX_ELEMENTS, SIVA_MAX_PARAMETERS, plausible masses and scales."""
    check_name(name)
    media = _media_type(request)
    if media in ("application/toml", "text/toml", "application/x-toml"):
        kind = "toml"
    elif media in ("", "application/json", "text/json"):
        kind = "json"
    else:
        raise ApiError(415, f"Content-Type {media!r}: send the spec as application/json "
                            "(or application/toml)")
    raw = await request.body()
    try:
        spec = parse_spec_body(raw, kind, request.app.state.settings)
    except LimitError as exc:
        raise ApiError(exc.status, exc.detail) from None
    svc = service_of(request)
    created, structure = await run_in_threadpool(svc.put_system, name, spec)
    body = {"name": name, "created": created, "dofs": structure.dofs,
            "free_parameters": structure.free, "spec": svc.store.spec(name)}
    return JSONResponse(body, status_code=201 if created else 200)


@router.get("/v1/systems/{name}", tags=["systems"], responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_system(name: str, request: Request) -> dict[str, Any]:
    svc = service_of(request)
    w = svc.worker(name)
    snap = w.snapshot()
    return {"name": name, "spec": svc.store.spec(name), "dofs": w.structure.dofs,
            "free_parameters": w.structure.free,
            "parameter_units": w.structure.parameter_units(), "state": snap.get("state"),
            "epoch": snap.get("epoch", 0), "converged": snap.get("converged", False),
            "n_recordings": svc.counts(name)}


@router.delete("/v1/systems/{name}", tags=["systems"],
               responses=errors(401, 403, 404, 422, 507),
               dependencies=[Depends(require_token)])
async def delete_system(
    name: str, request: Request,
    logs: str = Query("delete", description="the system's MCAP event logs: delete (default) "
                                            "or archive (moved to <data>/archive/logs/)"),
) -> dict[str, Any]:
    """Stop the worker and remove the system with all its recordings (irreversible), and
    its MCAP event logs: deleted, or archived with ``?logs=archive``; ``logs`` in the answer
    says which (``action``: deleted | archived | none | kept, ``files``, ``archive``)."""
    check_name(name)
    mode = logs.strip().lower()
    if mode not in ("delete", "archive"):
        raise ApiError(422, f"query parameter logs={logs!r}: must be 'delete' or 'archive'")
    done = await run_in_threadpool(service_of(request).delete_system, name,
                                   archive_logs=mode == "archive")
    return {"deleted": name, **done}


# --------------------------------------------------------------------------- recordings
@router.post("/v1/systems/{name}/recordings", tags=["recordings"], status_code=202,
             response_model=RecordingAck,
             responses=errors(400, 401, 403, 404, 409, 413, 415, 422, 503, 507),
             openapi_extra={"requestBody": {"required": True, "content": {
                 "text/csv": {"schema": {"type": "string"}},
                 "application/json": {"schema": {"type": "object", "description":
                                                 '{"time": [...], "acc_x": [...], ...}'}},
                 "multipart/form-data": {"schema": {"type": "object", "properties": {
                     "file": {"type": "string", "format": "binary"}}}},
                 "application/x-mcap": {"schema": {"type": "string", "format": "binary"}},
                 "application/x-npz": {"schema": {"type": "string", "format": "binary"}}}}},
             dependencies=[Depends(require_token)])
async def post_recording(
    name: str, request: Request,
    role: str | None = Query(None, description="train | validation; omitted: the automatic "
                                               "split (docs/service.md)"),
    format: str | None = Query(None, description="csv | json | npz | mcap; default from the "
                                                 "Content-Type or file name"),
    filename: str | None = Query(None, alias="name",
                                 description="a name for the record, used in messages"),
    map_: list[str] | None = Query(None, alias="map",
                                   description="SRC=DST, repeatable: read the file's channel "
                                               "SRC as column DST (e.g. 'Accel LO=acc_LO'); "
                                               "over the spec's [channels] map"),
    unit: list[str] | None = Query(None, description="COL=UNIT, repeatable: the unit a column "
                                                     "was recorded in (e.g. acc_LO=g), "
                                                     "converted to SI"),
) -> Response:
    """Upload one recording; 202 only once it is durably stored (temp, fsync, rename)."""
    svc = service_of(request)
    svc.worker(name)  # 404 before reading a body for nothing
    role = _role(role)
    fmt = _format(format) if format else None
    try:
        cmap, units = parse_pairs(map_, "map"), parse_pairs(unit, "unit")
    except ValueError as exc:
        raise ApiError(422, f"query parameter {exc}") from None
    async with upload_slot(request):  # the body stays in the socket until there is room
        return await _receive_recording(svc, name, request, role, fmt, filename,
                                        cmap or None, units or None)


class UploadSlots:
    """Uploads in flight, bounded in number *and* in declared body bytes: many small
    uploads run side by side, large ones take turns (memory follows the bytes)."""

    def __init__(self, count: int, budget: int) -> None:
        self.count, self.budget = count, budget
        self.used, self.used_bytes = 0, 0
        self.cond = asyncio.Condition()

    def _fits(self, nbytes: int) -> bool:
        return self.used < self.count and (self.used == 0 or
                                           self.used_bytes + nbytes <= self.budget)

    async def acquire(self, nbytes: int, timeout: float) -> None:
        async with self.cond:
            if not self._fits(nbytes):
                if timeout <= 0:
                    raise asyncio.TimeoutError
                await asyncio.wait_for(self.cond.wait_for(lambda: self._fits(nbytes)),
                                       timeout)
            self.used += 1
            self.used_bytes += nbytes

    async def release(self, nbytes: int) -> None:
        async with self.cond:
            self.used -= 1
            self.used_bytes -= nbytes
            self.cond.notify_all()


@contextlib.asynccontextmanager
async def upload_slot(request: Request) -> AsyncIterator[None]:
    """At most SIVA_MAX_CONCURRENT_UPLOADS recordings, declaring at most
    SIVA_UPLOAD_BYTES_IN_FLIGHT body bytes together (a body without Content-Length counts
    as SIVA_MAX_UPLOAD_BYTES), are read and parsed at once, so memory and CPU stay bounded
    whatever the number of clients; a request waits up to SIVA_UPLOAD_QUEUE_S for room,
    then gets 503 with Retry-After.  The body stays in the socket while it waits."""
    settings = request.app.state.settings
    slots = getattr(request.app.state, "upload_slots", None)
    if slots is None:
        slots = request.app.state.upload_slots = UploadSlots(
            settings.max_concurrent_uploads, settings.upload_bytes_in_flight)
    try:
        declared = int(request.headers.get("content-length", ""))
    except ValueError:
        declared = settings.max_upload_bytes
    nbytes = max(0, min(declared, settings.max_upload_bytes))
    try:
        await slots.acquire(nbytes, settings.upload_queue_s)
    except asyncio.TimeoutError:
        raise ApiError(503, f"too many uploads in flight ({slots.used}, "
                            f"{slots.used_bytes / 2**20:.0f} MiB declared) and no room within "
                            f"{settings.upload_queue_s:g} s; retry later "
                            "(SIVA_MAX_CONCURRENT_UPLOADS, SIVA_UPLOAD_BYTES_IN_FLIGHT, "
                            "SIVA_UPLOAD_QUEUE_S)", headers={"Retry-After": "5"}) from None
    try:
        yield
    finally:
        await slots.release(nbytes)


async def _receive_recording(svc: Any, name: str, request: Request, role: str | None,
                             fmt: str | None, filename: str | None,
                             cmap: dict[str, str] | None = None,
                             units: dict[str, str] | None = None) -> Response:
    media = _media_type(request)
    if media == "multipart/form-data":
        raw, part_name, part_type, form_role = await _multipart(request)
        filename = filename or part_name
        role = role or _role(form_role)
        fmt = fmt or _format_of(part_type, part_name, raw)
    else:
        if media and media not in CONTENT_FORMATS and media != "application/octet-stream":
            raise ApiError(415, f"Content-Type {media!r} is not a recording format "
                                f"({', '.join(CONTENT_FORMATS)}, multipart/form-data)")
        raw = await request.body()
        fmt = fmt or _format_of(media, filename, raw)
    filename = filename or f"upload.{fmt}"
    if not raw:
        raise ApiError(422, f"{filename}: empty body, expected a recording")
    ack = await run_in_threadpool(svc.add_recording, name, raw, role=role, fmt=fmt,
                                  filename=filename, channel_map=cmap, units=units)
    return JSONResponse(ack, status_code=202)


def _role(role: Any) -> str | None:
    if role is None or role == "":
        return None
    r = str(role).strip().lower()
    r = {"val": "validation", "valid": "validation", "training": "train"}.get(r, r)
    if r not in ("train", "validation"):
        raise ApiError(422, f"query parameter role={role!r}: must be 'train' or 'validation' "
                            "(or omitted for the automatic split)")
    return r


def _format(fmt: str) -> str:
    f = fmt.strip().lower().lstrip(".")
    if f not in FORMATS:
        raise ApiError(422, f"query parameter format={fmt!r}: must be one of {', '.join(FORMATS)}")
    return f


def _format_of(media: str | None, filename: str | None, raw: bytes) -> str:
    """Format from the Content-Type, else the file suffix, else sniffing the bytes."""
    return resolve_format(media, filename, raw)


async def _multipart(request: Request) -> tuple[bytes, str | None, str | None, Any]:
    try:
        form = await request.form()
    except (ApiError, UploadTooLarge):
        raise
    except Exception as exc:  # noqa: BLE001 - a malformed multipart body is a user error
        raise ApiError(400, f"multipart body: cannot parse ({exc})") from None
    try:
        files = [v for v in form.values() if isinstance(v, UploadFile)]
        if len(files) != 1:
            raise ApiError(422, f"multipart body: expected exactly one file part (field "
                                f"'file'), got {len(files)}")
        part = files[0]
        raw = await part.read()
        ctype = (part.content_type or "").split(";")[0].strip().lower() or None
        if ctype == "application/octet-stream":
            ctype = None
        return raw, part.filename, ctype, form.get("role")
    finally:
        await form.close()


@router.get("/v1/systems/{name}/recordings", tags=["recordings"], response_model=RecordingList,
            responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def list_recordings(name: str, request: Request) -> dict[str, Any]:
    svc = service_of(request)
    w = svc.worker(name)
    data = w.snapshot().get("data", {})
    in_mem = set(data.get("train", [])) | set(data.get("validation", []))
    try:
        metas = svc.store.recordings(name)
    except UnknownSystem as exc:
        raise ApiError(404, str(exc)) from None
    return {"system": name, "n_recordings": svc.counts(name),
            "recordings": [{**m.to_dict(), "in_memory": m.id in in_mem} for m in metas]}


@router.get("/v1/systems/{name}/recordings/{rid}", tags=["recordings"],
            response_model=RecordingInfo, responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_recording(name: str, rid: str, request: Request) -> dict[str, Any]:
    svc = service_of(request)
    w = svc.worker(name)
    try:
        meta = svc.store.recording(name, rid)
    except (UnknownSystem, UnknownRecording) as exc:
        raise ApiError(404, str(exc)) from None
    data = w.snapshot().get("data", {})
    return {**meta.to_dict(),
            "in_memory": meta.id in set(data.get("train", [])) | set(data.get("validation", []))}


@router.get("/v1/systems/{name}/recordings/{rid}/raw", tags=["recordings"],
            response_class=Response,
            responses={200: {"description": "the uploaded bytes (Content-Type from the format)",
                             "content": {t: {"schema": {"type": "string", "format": "binary"}}
                                         for t in ("text/csv", "application/json",
                                                   "application/x-npz", "application/x-mcap")}},
                       **READ_ERRORS},
            dependencies=[Depends(require_read_token)])
async def get_recording_raw(name: str, rid: str, request: Request) -> Response:
    """The stored bytes, exactly as uploaded."""
    svc = service_of(request)
    svc.worker(name)
    try:
        meta = svc.store.recording(name, rid)
        raw = await run_in_threadpool(svc.store.read_raw, name, meta)
    except (UnknownSystem, UnknownRecording) as exc:
        raise ApiError(404, str(exc)) from None
    media = {v: k for k, v in reversed(list(CONTENT_FORMATS.items()))}.get(meta.fmt,
                                                                         "application/octet-stream")
    return Response(raw, media_type=media, headers={"X-Sha256": meta.sha256})


# --------------------------------------------------------------------------- estimate, drift
@router.get("/v1/systems/{name}/estimate", tags=["estimate"], response_model=Estimate,
            responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_estimate(name: str, request: Request) -> dict[str, Any]:
    """The latest published estimate (never waits for training)."""
    svc = service_of(request)
    w = svc.worker(name)
    return estimate_view(w.snapshot(), svc.counts(name))


@router.get("/v1/systems/{name}/drift", tags=["estimate"], response_model=DriftReport,
            responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_drift(name: str, request: Request,
                    limit: int | None = Query(None, ge=1, description="last N snapshots only")
                    ) -> dict[str, Any]:
    """History of snapshots (recent means, intervals, modal quantities) and alarms."""
    w = service_of(request).worker(name)
    report = await run_in_threadpool(w.drift_report)  # with Ray: fetched from the actor
    hist = report["history"] if limit is None else report["history"][-limit:]
    return {"system": name, **report, "history": hist}


@router.post("/v1/systems/{name}/drift/reset", tags=["estimate"], response_model=DriftReport,
             responses=errors(401, 403, 404, 409), dependencies=[Depends(require_token)])
async def reset_drift(name: str, request: Request) -> dict[str, Any]:
    """Forget the drift reference and alarms (e.g. after a repair); history is kept."""
    w = service_of(request).worker(name)
    report = await run_in_threadpool(w.reset_drift)
    return {"system": name, **report}
