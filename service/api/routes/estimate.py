"""Routes of results: the estimate (never waits for training) and the drift report."""
from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Query
from starlette.concurrency import run_in_threadpool

from ..auth import require_read_token, require_token
from ..deps import ServiceDep, SystemDep
from ..http_errors import READ_ERRORS, errors
from ..schemas import DriftReport, Estimate

router = APIRouter()


@router.get("/v1/systems/{name}/estimate", tags=["estimate"], response_model=Estimate,
            responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_estimate(name: str, w: SystemDep, svc: ServiceDep) -> dict[str, Any]:
    """The latest published estimate (never waits for training)."""
    return w.snapshot().to_json(svc.counts(name))


@router.get("/v1/systems/{name}/drift", tags=["estimate"], response_model=DriftReport,
            responses=READ_ERRORS,
            dependencies=[Depends(require_read_token)])
async def get_drift(name: str, w: SystemDep,
                    limit: int | None = Query(None, ge=1, description="last N snapshots only")
                    ) -> dict[str, Any]:
    """History of snapshots (recent means, intervals, modal quantities) and alarms."""
    report = await run_in_threadpool(w.drift_report)  # with Ray: fetched from the actor
    return {"system": name, **report.to_json(history_limit=limit)}


@router.post("/v1/systems/{name}/drift/reset", tags=["estimate"], response_model=DriftReport,
             responses=errors(401, 403, 404, 409), dependencies=[Depends(require_token)])
async def reset_drift(name: str, w: SystemDep) -> dict[str, Any]:
    """Forget the drift reference and alarms (e.g. after a repair); history is kept."""
    report = await run_in_threadpool(w.reset_drift)
    return {"system": name, **report.to_json()}
