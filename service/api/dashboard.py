"""The live dashboard (``GET /``), the offline Swagger UI (``GET /docs``) and the JSON the
dashboard needs beyond the public API (``GET /v1/systems/{name}/latest-record``).

Why here and not in routes.py: the dashboard is a reader of what the service already
publishes (systems, estimate, drift, recordings); the only new data is the latest record
simulated with the current estimate.  Everything it draws is vendored under
``service/static`` (uPlot and Swagger UI from npm, pinned, with their licences), so it works
on a machine without internet.  ``install(app)`` is the one hook app.py calls.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from siva_core import Recording, RecordingError

from ..monitoring.latest_record import (LatestRecord, LatestRecordCache, compute_latest,
                                        parameters_for_simulation)
from ..timefmt import iso_utc
from .auth import require_read_token
from .deps import ServiceDep, SystemDep
from .http_errors import ERROR_RESPONSES
from .security import csp_with_scripts

log = logging.getLogger("siva.service.dashboard")

STATIC = Path(__file__).resolve().parents[1] / "static"

router = APIRouter()


@router.get("/", include_in_schema=False)
async def dashboard_page() -> FileResponse:
    return FileResponse(STATIC / "index.html", media_type="text/html")


@router.get("/docs", include_in_schema=False)
async def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI from the vendored assets (FastAPI's default loads them from a CDN), with a
    CSP that allows its one inline script by hash."""
    page = get_swagger_ui_html(openapi_url=request.app.openapi_url or "/openapi.json",
                               title="siva - API",
                               swagger_js_url="/static/vendor/swagger-ui/swagger-ui-bundle.js",
                               swagger_css_url="/static/vendor/swagger-ui/swagger-ui.css",
                               swagger_favicon_url="/static/vendor/swagger-ui/favicon-32x32.png")
    html = bytes(page.body).decode()
    inline = re.findall(r"<script>(.*?)</script>", html, flags=re.S)
    return HTMLResponse(html, headers={"Content-Security-Policy": csp_with_scripts(*inline)})


@router.get("/v1/systems/{name}/latest-record", tags=["dashboard"],
            responses={k: v for k, v in ERROR_RESPONSES.items() if k in (401, 404, 409, 421)},
            dependencies=[Depends(require_read_token)])
async def latest_record(name: str, request: Request, w: SystemDep,
                        svc: ServiceDep) -> dict[str, Any]:
    """The most recent recording simulated with the current estimate (``best`` when there
    is one, else the headline means): measured vs simulated displacement [mm] and residual,
    Fourier spectra, CWT.  ``available: false`` with a ``reason`` while there is nothing to
    show yet.  Computed in a thread and cached per data version (record id + parameters)."""
    metas = svc.store.recordings(name)  # UnknownSystem: 404
    if not metas:
        return {"system": name, "available": False, "reason": "no recording yet"}
    meta = max(metas, key=lambda m: m.index)
    snap = w.snapshot()
    chosen = parameters_for_simulation(snap.best, snap.parameters, snap.estimate_source,
                                       w.structure.free)
    record = {"id": meta.id, "role": meta.role, "filename": meta.filename,
              "received_at": meta.received_at, "received_at_iso": iso_utc(meta.received_at)}
    if chosen is None:
        return {"system": name, "available": False, "record": record,
                "reason": "no estimate yet (the trainer has not published parameters)"}
    theta, source = chosen
    key = (meta.id, source, tuple(round(theta[p], 12) for p in w.structure.free))
    cache: LatestRecordCache = request.app.state.latest_records

    def compute() -> LatestRecord:
        raw = svc.store.read_raw(name, meta)
        rec = Recording.read(raw, w.structure.dofs, name=meta.filename or meta.id, fmt=meta.fmt,
                             **meta.read_options(w.structure))
        proc = getattr(w, "_proc", None)  # the chain the trainer uses, when it has one
        try:
            series = compute_latest(w.structure, rec, proc, theta)
        except (ValueError, FloatingPointError) as exc:
            if proc is None:
                raise
            log.warning("%s: latest record with the trainer's chain failed (%s); own chain",
                        name, exc)
            from ..storage.uploads import processing_for
            series = compute_latest(w.structure, rec, processing_for([rec], w.structure.dofs),
                                    theta)
        return LatestRecord(record=record, parameters=theta, parameters_source=source,
                            epoch=snap.epoch, series=series)

    try:
        view, cached = await run_in_threadpool(cache.get, name, key, meta.id, compute)
    except (RecordingError, ValueError, FloatingPointError) as exc:
        return {"system": name, "available": False, "record": record,
                "reason": f"cannot simulate {meta.id}: {exc}"}
    return {"system": name, "available": True, "record": view.record,
            "parameters": view.parameters, "parameters_source": view.parameters_source,
            "parameter_units": w.structure.parameter_units(), "epoch": view.epoch,
            **view.series.to_json(), "computed_at": view.computed_at,
            "computed_at_iso": None if view.computed_at is None else iso_utc(view.computed_at),
            "cached": cached}


def install(app: FastAPI) -> None:
    """Mount the static files, the dashboard, /docs and the latest-record endpoint."""
    app.state.latest_records = LatestRecordCache()
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    app.include_router(router)


__all__ = ["install", "router", "STATIC"]
