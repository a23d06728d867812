"""`GET /v1/systems/{name}/diagnosis`: `siva diagnose` on a system's current records.

A diagnosis takes tens of seconds, so the route never runs it: the first request starts it
in a background thread and answers 202 with its progress (state, fraction, ETA); later
requests get the progress, then the result (200).  The result is cached per system under
a *data key* (the spec and the ids of the train and val records): any new or deleted
recording or a new spec changes the key, and the next request starts a fresh run.  A run
whose key went stale while it ran is not served.
"""
from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse

from siva_core import DiagnoseSettings, Recording, diagnose, html_report

from .errors import ApiError
from .routes import service_of

log = logging.getLogger("siva.service.diagnosis")
router = APIRouter()

#: reduced settings for ?quick=true (smoke checks, small machines): one effect, no sensors
QUICK = dict(top_k=2, nominal_nfev=15, fit_nfev=15, max_effects=1, sensors=False)


@dataclass
class DiagnosisJob:
    """One background diagnosis of one system's records under one data key."""

    key: str
    train: list[str]
    val: list[str]
    quick: bool
    state: str = "running"
    fraction: float = 0.0
    message: str = ""
    started: float = field(default_factory=time.time)
    finished: float | None = None
    result: dict[str, Any] | None = None
    html: str | None = None
    error: str | None = None

    def status(self, name: str) -> dict[str, Any]:
        elapsed = (self.finished or time.time()) - self.started
        eta = None
        if self.state == "running" and self.fraction > 0.02:
            eta = round(elapsed * (1 - self.fraction) / self.fraction, 1)
        return {"system": name, "state": self.state, "fraction": round(self.fraction, 3),
                "eta_s": eta, "elapsed_s": round(elapsed, 1), "message": self.message,
                "data_key": self.key, "quick": self.quick,
                "records": {"train": self.train, "val": self.val},
                "error": self.error, "result": self.result}


class _Jobs:
    """Per-system jobs of one app (kept on app.state)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.by_system: dict[str, DiagnosisJob] = {}


def _jobs(request: Request) -> _Jobs:
    jobs = getattr(request.app.state, "diagnosis_jobs", None)
    if jobs is None:
        jobs = request.app.state.diagnosis_jobs = _Jobs()
    return jobs


def _data_key(spec: dict[str, Any], train: list[str], val: list[str], quick: bool) -> str:
    blob = json.dumps({"spec": spec, "train": train, "val": val, "quick": quick},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _run(job: DiagnosisJob, svc: Any, name: str) -> None:
    """The thread body: read the records, diagnose, keep JSON and HTML."""
    try:
        structure = svc.worker(name).structure
        metas = {m.id: m for m in svc.store.recordings(name)}

        def read(rid: str) -> Recording:
            m = metas[rid]
            return Recording.read(svc.store.read_raw(name, m), structure.dofs,
                                  name=m.filename or rid, fmt=m.fmt,
                                  **m.read_options(structure))

        train = [read(r) for r in job.train]
        val = [read(r) for r in job.val]
        settings = DiagnoseSettings(**QUICK) if job.quick else DiagnoseSettings()

        def progress(msg: str) -> None:
            job.message = msg[:300]

        def fraction(x: float) -> None:
            job.fraction = max(job.fraction, min(float(x), 0.99))

        diag = diagnose(structure, train, val, "auto", settings=settings, progress=progress,
                        fraction=fraction)
        job.result = diag.to_json()
        job.html = html_report(diag)
        job.fraction, job.state = 1.0, "done"
    except Exception as exc:  # noqa: BLE001 - reported in the job, the service goes on
        log.exception("diagnosis of %s failed", name)
        job.state, job.error = "failed", f"{type(exc).__name__}: {exc}"
    finally:
        job.finished = time.time()


def _current(request: Request, name: str, quick: bool, start: bool) -> DiagnosisJob:
    svc = service_of(request)
    w = svc.worker(name)  # 404 / 409 for unknown or broken systems
    metas = svc.store.recordings(name)
    train = [m.id for m in metas if m.role == "train"]
    val = [m.id for m in metas if m.role == "validation"]
    if not train or not val:
        raise ApiError(409, f"system {name!r}: a diagnosis needs at least one train and one "
                            f"val recording (has {len(train)} train, {len(val)} val)")
    key = _data_key(svc.store.spec(name), train, val, quick)
    jobs = _jobs(request)
    with jobs.lock:
        job = jobs.by_system.get(name)
        if job is not None and job.key == key and job.state != "failed":
            return job
        if not start:
            raise ApiError(404, f"system {name!r}: no diagnosis of the current records yet "
                                f"(GET /v1/systems/{name}/diagnosis starts one)")
        job = DiagnosisJob(key, train, val, quick)
        jobs.by_system[name] = job
    del w
    threading.Thread(target=_run, args=(job, svc, name), daemon=True,
                     name=f"diagnosis-{name}").start()
    return job


@router.get("/v1/systems/{name}/diagnosis", tags=["diagnosis"])
async def get_diagnosis(name: str, request: Request,
                        quick: bool = Query(False, description="reduced settings: one "
                                            "effect, fewer candidates and evaluations")
                        ) -> JSONResponse:
    """The diagnosis of the system's current train/val records: 202 with progress while it
    runs (started by this request if the data changed), 200 with the result when done."""
    job = _current(request, name, quick, start=True)
    return JSONResponse(job.status(name), status_code=200 if job.state != "running" else 202)


@router.get("/v1/systems/{name}/diagnosis/report", tags=["diagnosis"],
            response_class=HTMLResponse)
async def get_diagnosis_report(name: str, request: Request,
                               quick: bool = Query(False)) -> HTMLResponse:
    """The HTML report of the finished diagnosis of the current records (404 before)."""
    job = _current(request, name, quick, start=False)
    if job.state != "done" or job.html is None:
        raise ApiError(404, f"system {name!r}: the diagnosis is {job.state} "
                            f"({100 * job.fraction:.0f} %); the report follows when done")
    return HTMLResponse(job.html)
