"""Routes of recordings: upload (bounded: ``upload_slots.py``), list, read, raw bytes."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from siva_core import media_types, parse_pairs, resolve_format

from ...errors import Invalid, ServiceError, Unreadable
from ...storage.recordings import FORMATS
from ...systems import SivaService
from ..auth import require_read_token, require_token
from ..deps import ServiceDep, SystemDep, media_type
from ..http_errors import READ_ERRORS, ApiError, UploadTooLarge, errors
from ..schemas import RecordingAck, RecordingInfo, RecordingList
from ..upload_slots import upload_slot

router = APIRouter()

CONTENT_FORMATS = media_types()


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
    name: str, request: Request, svc: ServiceDep, w: SystemDep,  # 404 before reading a body
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
    role = _role(role)
    fmt = _format(format) if format else None
    try:
        cmap, units = parse_pairs(map_, "map"), parse_pairs(unit, "unit")
    except ValueError as exc:
        raise Invalid(f"query parameter {exc}") from None
    async with upload_slot(request):  # the body stays in the socket until there is room
        return await _receive_recording(svc, name, request, role, fmt, filename,
                                        cmap or None, units or None)


async def _receive_recording(svc: SivaService, name: str, request: Request, role: str | None,
                             fmt: str | None, filename: str | None,
                             cmap: dict[str, str] | None = None,
                             units: dict[str, str] | None = None) -> Response:
    media = media_type(request)
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
        raise Invalid(f"{filename}: empty body, expected a recording")
    ack = await run_in_threadpool(svc.add_recording, name, raw, role=role, fmt=fmt,
                                  filename=filename, channel_map=cmap, units=units)
    return JSONResponse(ack.to_json(), status_code=202)


def _role(role: Any) -> str | None:
    if role is None or role == "":
        return None
    r = str(role).strip().lower()
    r = {"val": "validation", "valid": "validation", "training": "train"}.get(r, r)
    if r not in ("train", "validation"):
        raise Invalid(f"query parameter role={role!r}: must be 'train' or 'validation' "
                      "(or omitted for the automatic split)")
    return r


def _format(fmt: str) -> str:
    f = fmt.strip().lower().lstrip(".")
    if f not in FORMATS:
        raise Invalid(f"query parameter format={fmt!r}: must be one of {', '.join(FORMATS)}")
    return f


def _format_of(media: str | None, filename: str | None, raw: bytes) -> str:
    """Format from the Content-Type, else the file suffix, else sniffing the bytes."""
    return resolve_format(media, filename, raw)


async def _multipart(request: Request) -> tuple[bytes, str | None, str | None, Any]:
    try:
        form = await request.form()
    except (ApiError, ServiceError, UploadTooLarge):
        raise
    except Exception as exc:  # noqa: BLE001 - a malformed multipart body is a user error
        raise Unreadable(f"multipart body: cannot parse ({exc})") from None
    try:
        files = [v for v in form.values() if isinstance(v, UploadFile)]
        if len(files) != 1:
            raise Invalid(f"multipart body: expected exactly one file part (field "
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
async def list_recordings(name: str, w: SystemDep, svc: ServiceDep) -> dict[str, Any]:
    data = w.snapshot().data
    in_mem = set() if data is None else {*data.train, *data.validation}
    metas = svc.store.recordings(name)  # UnknownSystem: 404
    return {"system": name, "n_recordings": svc.counts(name),
            "recordings": [{**m.to_dict(), "in_memory": m.id in in_mem} for m in metas]}


@router.get("/v1/systems/{name}/recordings/{rid}", tags=["recordings"],
            response_model=RecordingInfo, responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_recording(name: str, rid: str, w: SystemDep, svc: ServiceDep) -> dict[str, Any]:
    meta = svc.store.recording(name, rid)  # UnknownSystem, UnknownRecording: 404
    data = w.snapshot().data
    return {**meta.to_dict(),
            "in_memory": data is not None and meta.id in {*data.train, *data.validation}}


@router.get("/v1/systems/{name}/recordings/{rid}/raw", tags=["recordings"],
            response_class=Response,
            responses={200: {"description": "the uploaded bytes (Content-Type from the format)",
                             "content": {t: {"schema": {"type": "string", "format": "binary"}}
                                         for t in ("text/csv", "application/json",
                                                   "application/x-npz", "application/x-mcap")}},
                       **READ_ERRORS},
            dependencies=[Depends(require_read_token)])
async def get_recording_raw(name: str, rid: str, w: SystemDep, svc: ServiceDep) -> Response:
    """The stored bytes, exactly as uploaded."""
    meta = svc.store.recording(name, rid)  # UnknownSystem, UnknownRecording: 404
    raw = await run_in_threadpool(svc.store.read_raw, name, meta)
    media = {v: k for k, v in reversed(list(CONTENT_FORMATS.items()))}.get(meta.fmt,
                                                                         "application/octet-stream")
    return Response(raw, media_type=media, headers={"X-Sha256": meta.sha256})
