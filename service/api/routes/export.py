"""`GET /v1/systems/{name}/export/{what}.csv`: the estimate, per-record fits, drift history
and alarms as CSV files (``csv_export.py`` says what each holds)."""
from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from ...errors import NotFound
from ..auth import require_read_token
from ..csv_export import EXPORTS, export_csv
from ..deps import ServiceDep, SystemDep
from ..http_errors import WRITE_ERRORS

router = APIRouter()


@router.get("/v1/systems/{name}/export/{what}.csv", tags=["estimate"],
            response_class=Response,
            responses={200: {"description": "text/csv; header row with units, e.g. "
                                            "`k1 [N/m]`; times as `time_utc`",
                             "content": {"text/csv": {"schema": {"type": "string"}}}},
                       **WRITE_ERRORS},
            dependencies=[Depends(require_read_token)])
async def export(name: str, what: str, w: SystemDep, svc: ServiceDep) -> Response:
    """estimates | records | drift | alarms as CSV (a download: Content-Disposition)."""
    if what not in EXPORTS:
        raise NotFound(f"export {what!r}: one of {', '.join(f'{e}.csv' for e in EXPORTS)}")
    units = w.structure.parameter_units()
    est = w.snapshot().to_json(svc.counts(name))
    report = ((await run_in_threadpool(w.drift_report)).to_json()
              if what != "estimates" else {})
    text = export_csv(what, est, report, units)
    return Response(text, media_type="text/csv; charset=utf-8", headers={
        "Content-Disposition": f'attachment; filename="{name}-{what}.csv"'})
