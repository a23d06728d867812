"""Routes of the service and its systems: health, list, register (PUT), read, delete.

Handlers only parse, check and delegate (to ``service/systems.py``); the service and the
system come in through dependencies (``deps.py``), refusals are domain errors or
:class:`ApiError` (``http_errors.py``).
"""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from ...errors import Invalid, UnknownSystem
from ...limits import parse_spec_body
from ..auth import require_read_token, require_token
from ..deps import Name, ServiceDep, SettingsDep, SystemDep, media_type
from ..http_errors import READ_ERRORS, ApiError, errors
from ..schemas import Health, SystemAck, SystemList, SystemSpec

router = APIRouter()


@router.get("/healthz", response_model=Health, tags=["service"],
            responses={503: {"model": Health, "description": "a trainer is dead or stuck, or "
                             "checkpoints cannot be written; `problems` says which and why"}})
async def healthz(svc: ServiceDep) -> Response:
    """200 when every trainer runs and persists; 503 with the reasons otherwise."""
    problems = svc.health_problems()
    body = {"status": "ok" if not problems else "unhealthy", "systems": len(svc.workers),
            "workers_alive": sum(w.alive for w in list(svc.workers.values())),
            "problems": problems,
            "executor": svc.executor.describe() if svc.executor is not None else None}
    return JSONResponse(body, status_code=503 if problems else 200)


@router.get("/v1/systems", response_model=SystemList, tags=["systems"],
            responses=errors(401), dependencies=[Depends(require_read_token)])
async def list_systems(svc: ServiceDep) -> dict[str, Any]:
    out = []
    for name, w in sorted(list(svc.workers.items())):
        snap = w.snapshot()
        try:
            counts = svc.store.counts(name)
        except UnknownSystem:
            continue
        out.append({"name": name, "state": snap.state, "epoch": snap.epoch,
                    "converged": snap.converged, "n_recordings": counts,
                    "active_alarms": [a["parameter"] for a in snap.alarms]})
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
async def put_system(name: Name, request: Request, svc: ServiceDep,
                     settings: SettingsDep) -> Response:
    """Register a system with its model spec (JSON; TOML accepted as application/toml).

    Limits (413/422, docs/reliability.md): SIVA_MAX_SPEC_BYTES, SIVA_MAX_SPEC_DEPTH,
    SIVA_MAX_DOFS, SIVA_MAX_ELEMENTS, SIVA_MAX_PARAMETERS, plausible masses and scales."""
    media = media_type(request)
    if media in ("application/toml", "text/toml", "application/x-toml"):
        kind = "toml"
    elif media in ("", "application/json", "text/json"):
        kind = "json"
    else:
        raise ApiError(415, f"Content-Type {media!r}: send the spec as application/json "
                            "(or application/toml)")
    raw = await request.body()
    spec = parse_spec_body(raw, kind, settings)
    created, structure = await run_in_threadpool(svc.put_system, name, spec)
    body = {"name": name, "created": created, "dofs": structure.dofs,
            "free_parameters": structure.free, "spec": svc.store.spec(name)}
    return JSONResponse(body, status_code=201 if created else 200)


@router.get("/v1/systems/{name}", tags=["systems"], responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_system(name: str, w: SystemDep, svc: ServiceDep) -> dict[str, Any]:
    snap = w.snapshot()
    return {"name": name, "spec": svc.store.spec(name), "dofs": w.structure.dofs,
            "free_parameters": w.structure.free,
            "parameter_units": w.structure.parameter_units(), "state": snap.state,
            "epoch": snap.epoch, "converged": snap.converged,
            "n_recordings": svc.counts(name)}


@router.delete("/v1/systems/{name}", tags=["systems"],
               responses=errors(401, 403, 404, 422, 507),
               dependencies=[Depends(require_token)])
async def delete_system(
    name: Name, svc: ServiceDep,
    logs: str = Query("delete", description="the system's MCAP event logs: delete (default) "
                                            "or archive (moved to <data>/archive/logs/)"),
) -> dict[str, Any]:
    """Stop the worker and remove the system with all its recordings (irreversible), and
    its MCAP event logs: deleted, or archived with ``?logs=archive``; ``logs`` in the answer
    says which (``action``: deleted | archived | none | kept, ``files``, ``archive``)."""
    mode = logs.strip().lower()
    if mode not in ("delete", "archive"):
        raise Invalid(f"query parameter logs={logs!r}: must be 'delete' or 'archive'")
    done = await run_in_threadpool(svc.delete_system, name,
                                   archive_logs=mode == "archive")
    return {"deleted": name, **done.to_json()}
