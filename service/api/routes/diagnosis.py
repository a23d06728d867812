"""`GET /v1/systems/{name}/diagnosis`: `siva diagnose` on a system's current records.

A diagnosis takes tens of seconds, so the route never runs it: the first request starts it
in a background thread and answers 202 with its progress (state, fraction, ETA); later
requests get the progress, then the result (200).  The result is cached per system under
a *data key* (the spec and the ids of the train and val records): any new or deleted
recording or a new spec changes the key, and the next request starts a fresh run.  A run
whose key went stale while it ran is not served.

CPU is bounded (issue 19): one diagnosis runs per system at a time, in one thread per system
(:func:`_run_system`).  A run superseded by a new key (new data, or ``quick`` toggled) is
cancelled at its next progress report and the new one starts when it has stopped; requests
in between see the new run as ``queued``.  *Starting* a run is a write: it needs the token
when one is set and is refused to a cross-site browser request; reading a run's progress or
finished result is a read.
"""
from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse

from siva_core import DiagnoseSettings, Recording, diagnose, html_report

from ...errors import Conflict, NotFound
from ..auth import require_read_token, require_write_rights
from ...systems import SivaService
from ..deps import ServiceDep, get_system
from ..http_errors import ApiError, errors
from ..schemas import ErrorDetail

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
    #: a failed run was answered once: the next request retries it (before, every request
    #: retried, so a polling client never saw the failure, only a run restarting forever)
    failure_served: bool = False
    cancel: threading.Event = field(default_factory=threading.Event, repr=False)

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


class DiagnosisCancelled(Exception):
    """Raised inside a run at a progress report once a newer run superseded it."""


class _Jobs:
    """Per-system jobs of one app (kept on app.state) and the one runner thread of each."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.by_system: dict[str, DiagnosisJob] = {}
        self.runners: dict[str, threading.Thread] = {}


def _jobs(request: Request) -> _Jobs:
    jobs = getattr(request.app.state, "diagnosis_jobs", None)
    if jobs is None:
        jobs = request.app.state.diagnosis_jobs = _Jobs()
    return jobs


def _data_key(spec: dict[str, Any], train: list[str], val: list[str], quick: bool) -> str:
    blob = json.dumps({"spec": spec, "train": train, "val": val, "quick": quick},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _run_system(jobs: _Jobs, svc: Any, name: str, first: DiagnosisJob) -> None:
    """The one runner thread of a system: runs ``first``, then any job queued while it ran
    (a superseded run is cancelled first, so runs never overlap)."""
    _run(first, svc, name)
    while True:
        with jobs.lock:
            job = jobs.by_system.get(name)
            if job is None or job.state != "queued":
                jobs.runners.pop(name, None)
                return
            job.state = "running"
            job.started = time.time()
        _run(job, svc, name)


def _run(job: DiagnosisJob, svc: Any, name: str) -> None:
    """Read the records, diagnose, keep JSON and HTML (stops early once cancelled)."""
    def check() -> None:
        if job.cancel.is_set():
            raise DiagnosisCancelled

    try:
        structure = svc.worker(name).structure
        metas = {m.id: m for m in svc.store.recordings(name)}

        def read(rid: str) -> Recording:
            m = metas[rid]
            return Recording.read(svc.store.read_raw(name, m), structure.dofs,
                                  name=m.filename or rid, fmt=m.fmt,
                                  **m.read_options(structure))

        check()
        train = [read(r) for r in job.train]
        val = [read(r) for r in job.val]
        check()
        settings = DiagnoseSettings(**QUICK) if job.quick else DiagnoseSettings()

        def progress(msg: str) -> None:
            check()
            job.message = msg[:300]

        def fraction(x: float) -> None:
            check()
            job.fraction = max(job.fraction, min(float(x), 0.99))

        diag = diagnose(structure, train, val, "auto", settings=settings, progress=progress,
                        fraction=fraction)
        job.result = diag.to_json()
        job.html = html_report(diag)
        check()
        job.fraction, job.state = 1.0, "done"
    except DiagnosisCancelled:
        job.state, job.message = "cancelled", "superseded by a newer diagnosis request"
    except Exception as exc:  # noqa: BLE001 - reported in the job, the service goes on
        log.exception("diagnosis of %s failed", name)
        job.state, job.error = "failed", f"{type(exc).__name__}: {exc}"
    finally:
        job.finished = time.time()


def _current(request: Request, svc: SivaService, name: str, quick: bool,
             start: bool) -> DiagnosisJob:
    """The job of the current records; with ``start``, a new one when there is none (which
    needs write rights, and cancels a superseded run)."""
    metas = svc.store.recordings(name)
    train = [m.id for m in metas if m.role == "train"]
    val = [m.id for m in metas if m.role == "validation"]
    if not train or not val:
        raise Conflict(f"system {name!r}: a diagnosis needs at least one train and one "
                       f"val recording (has {len(train)} train, {len(val)} val)")
    key = _data_key(svc.store.spec(name), train, val, quick)
    jobs = _jobs(request)
    with jobs.lock:
        job = jobs.by_system.get(name)
        if job is not None and job.key == key and job.state not in ("failed", "cancelled"):
            return job
        if job is not None and job.key == key and job.state == "failed" \
                and not job.failure_served:
            job.failure_served = True
            return job
    if not start:
        raise NotFound(f"system {name!r}: no diagnosis of the current records yet "
                       f"(GET /v1/systems/{name}/diagnosis starts one)")
    try:
        require_write_rights(request, "starting a diagnosis")
    except ApiError:
        if job is not None and job.key == key:
            return job  # a reader sees the failed or cancelled run; a writer restarts it
        raise
    with jobs.lock:
        old = jobs.by_system.get(name)
        if old is not None and old.key == key and old.state not in ("failed", "cancelled"):
            return old  # another request started it meanwhile
        if old is not None and old.state in ("queued", "running"):
            old.cancel.set()
            if old.state == "queued":
                old.state = "cancelled"
        runner = jobs.runners.get(name)
        idle = runner is None or not runner.is_alive()
        job = DiagnosisJob(key, train, val, quick, state="running" if idle else "queued")
        jobs.by_system[name] = job
        if idle:
            runner = threading.Thread(target=_run_system, args=(jobs, svc, name, job),
                                      daemon=True, name=f"diagnosis-{name}")
            jobs.runners[name] = runner
            runner.start()
    return job


_PROGRESS = {"description": "the run of the current records is queued or running: "
                            "state, fraction, ETA", "content": {"application/json": {}}}


@router.get("/v1/systems/{name}/diagnosis", tags=["diagnosis"],
            responses={202: _PROGRESS, **errors(401, 403, 404, 409, 422)},
            dependencies=[Depends(require_read_token), Depends(get_system)])  # 404/409 first
async def get_diagnosis(name: str, request: Request, svc: ServiceDep,
                        quick: bool = Query(False, description="reduced settings: one "
                                            "effect, fewer candidates and evaluations")
                        ) -> JSONResponse:
    """The diagnosis of the system's current train/val records: 202 with progress while it
    runs (started by this request if the data changed: that needs write rights), 200 with
    the result when done (or failed)."""
    job = _current(request, svc, name, quick, start=True)
    running = job.state in ("queued", "running")
    return JSONResponse(job.status(name), status_code=202 if running else 200)


@router.get("/v1/systems/{name}/diagnosis/report", tags=["diagnosis"],
            response_class=HTMLResponse,
            responses={code: {"description": v["description"], "content": {"application/json": {
                "schema": ErrorDetail.model_json_schema()}}}
                for code, v in errors(401, 404, 409, 422).items()},
            dependencies=[Depends(require_read_token), Depends(get_system)])
async def get_diagnosis_report(name: str, request: Request, svc: ServiceDep,
                               quick: bool = Query(False)) -> HTMLResponse:
    """The HTML report of the finished diagnosis of the current records (404 before)."""
    job = _current(request, svc, name, quick, start=False)
    if job.state != "done" or job.html is None:
        raise NotFound(f"system {name!r}: the diagnosis is {job.state} "
                       f"({100 * job.fraction:.0f} %); the report follows when done")
    return HTMLResponse(job.html)
