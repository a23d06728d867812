"""The one place where refusals become HTTP answers: domain error class -> status code,
the API's own refusals (:class:`ApiError`: auth, content type - things only HTTP has),
the documented error responses of the OpenAPI schema, and the app's exception handlers.

Every answer is ``{"detail": "..."}`` naming what is wrong and where; nothing below the
API knows a status code (``service/errors.py``).
"""
from __future__ import annotations

import json
import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from ..errors import (Conflict, Invalid, NotFound, ServiceError, StorageRefused, TooLarge,
                       Unavailable, Unreadable)
from .schemas import ErrorDetail

log = logging.getLogger("siva.service")

#: domain error -> HTTP status (the most specific class listed first wins)
STATUS: tuple[tuple[type[ServiceError], int], ...] = (
    (Unreadable, 400),
    (NotFound, 404),
    (Conflict, 409),
    (TooLarge, 413),
    (Invalid, 422),
    (Unavailable, 503),
    (StorageRefused, 507),
)


def status_of(exc: ServiceError) -> int:
    """The HTTP status of a domain error (500 for a class nobody mapped: a bug)."""
    for cls, status in STATUS:
        if isinstance(exc, cls):
            return status
    return 500


class ApiError(Exception):
    """A refusal only HTTP has (a token, a content type, a cross-site write): raised in
    the API layer alone, with its status."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


class UploadTooLarge(Exception):
    """The body grew past SIVA_MAX_UPLOAD_BYTES while being read (413, connection closed)."""


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


def install(app: FastAPI) -> None:
    """Answer every refusal as ``{"detail"}`` with its status; a bug as a logged 500."""

    @app.exception_handler(ServiceError)
    async def _domain(request: Request, exc: ServiceError) -> JSONResponse:
        headers = None
        if isinstance(exc, Unavailable) and exc.retry_after_s is not None:
            headers = {"Retry-After": str(max(1, round(exc.retry_after_s)))}
        return JSONResponse({"detail": exc.detail}, status_code=status_of(exc), headers=headers)

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status, headers=exc.headers)

    @app.exception_handler(UploadTooLarge)
    async def _too_large_handler(request: Request, exc: UploadTooLarge) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=413, headers={"connection": "close"})

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts = []
        for err in exc.errors():
            where = ".".join(str(x) for x in err.get("loc", ()))
            parts.append(f"{where}: {err.get('msg', 'invalid')}")
        return JSONResponse({"detail": "; ".join(parts) or "invalid request"}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no such endpoint: {request.method} {request.url.path}"
        elif exc.status_code == 405:
            detail = f"method {request.method} not allowed on {request.url.path}"
        return JSONResponse({"detail": detail}, status_code=exc.status_code,
                            headers=getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        log.error("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
        return JSONResponse({"detail": f"internal error ({type(exc).__name__}); "
                                       "this is a bug, it has been logged"}, status_code=500)
