"""The FastAPI application: ``create_app(settings)``, the service registry, error handling.

Error policy (CONTRACT: bad input gets a 4xx with ``{"detail": "<what, where>"}``, never a
5xx): user errors are raised as :class:`ApiError` or come from siva_core as SpecError /
RecordingError and are mapped to 4xx with their message; FastAPI's own validation errors
are flattened to one readable string; anything else is a bug, logged with its traceback
and answered 500.  The upload limit is enforced by a pure ASGI middleware that refuses a
too-large Content-Length before the body is read and counts streamed bytes otherwise.
"""
from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from typing import Any, AsyncIterator

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from siva_core import RecordingError, SpecError, Structure
from siva_core import RecordingTooLarge

from ..errors import ApiError, UploadTooLarge
from .routes.systems import router
from .limits import LimitError, check_sampling_rate, check_structure
from .security import SecurityMiddleware, allowed_hosts
from ..settings import Settings
from ..errors import DuplicateConflict, SpecConflict, UnknownRecording, UnknownSystem
from ..storage.store import Store
from ..storage.uploads import parse_upload
from ..fleet.executor import TrainerHandle, make_executor

log = logging.getLogger("siva.service")


# --------------------------------------------------------------------------- event log hook
class _NoEvents:
    """Stand-in when the event log (service/storage/eventlog) is unavailable: it is optional."""

    def log_spec(self, *a: Any, **k: Any) -> None: ...
    def log_recording(self, *a: Any, **k: Any) -> None: ...
    def rotate(self, *a: Any, **k: Any) -> None: ...
    def log_dataset(self, *a: Any, **k: Any) -> None: ...
    def log_snapshot(self, *a: Any, **k: Any) -> None: ...
    def remove(self, *a: Any, **k: Any) -> "_NothingRemoved":
        return _NothingRemoved()
    def close(self) -> None: ...


class _NothingRemoved:
    """What removing the logs of a service without an event log did: nothing."""

    def to_json(self) -> dict[str, Any]:
        return {"action": "none", "files": 0}


def _make_event_log(settings: Settings) -> Any:
    try:
        from ..storage.eventlog import EventLog
    except ImportError as exc:
        log.warning("event log disabled (service.mcap_log unavailable: %s)", exc)
        return _NoEvents()
    try:
        return EventLog(settings.data_dir, settings={"seed": settings.seed,
                                                     "preset": settings.preset})
    except Exception:  # noqa: BLE001 - an unusable log must not stop the service
        log.exception("event log disabled (cannot open under %s)", settings.data_dir)
        return _NoEvents()


# --------------------------------------------------------------------------- the service
class SivaService:
    """Registry of systems: the durable store, one worker per system, the event log."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.store = Store(settings.data_dir, auto_validation_every=settings.auto_validation_every)
        self.events: Any = _NoEvents()
        self.structures: dict[str, Structure] = {}
        self.workers: dict[str, TrainerHandle] = {}
        self.executor: Any = None
        self.broken: dict[str, str] = {}
        self.repairs: dict[str, Any] = {}  # name -> service.replay.reconcile.Repair (this start)
        self._lock = threading.Lock()
        # supervision: a trainer thread that died is replaced (from its checkpoint) after
        # a back-off; until then /healthz says so
        self._dead: dict[str, tuple[float, int, str]] = {}  # name -> (since, restarts, why)
        self._stopping = threading.Event()
        self._supervisor = threading.Thread(target=self._supervise, name="siva-supervisor",
                                            daemon=True)

    def start(self) -> None:
        if self.settings.torch_threads:
            import torch

            torch.set_num_threads(self.settings.torch_threads)
        self.events = _make_event_log(self.settings)
        self.executor = make_executor(self.settings, self.store, self.events)
        try:  # import torch and the trainer now, not inside the first PUT
            from siva_core import SivaTrainer  # noqa: F401
        except Exception:  # noqa: BLE001 - the workers report it per system
            log.exception("cannot import the trainer")
        for name in self.store.load():
            try:
                structure = Structure.from_dict(self.store.spec(name))
            except SpecError as exc:  # a spec that an older version accepted
                log.error("system %s: stored spec no longer valid (%s); not trained", name, exc)
                self.broken[name] = str(exc)
                continue
            self.structures[name] = structure
            self._safe_event("log_spec", name, self.store.spec(name))
            self._reconcile(name)
            self._start_worker(name, structure)
        log.info("service started: %d system(s) from %s", len(self.structures),
                 self.settings.data_dir)
        self._supervisor.start()

    def stop(self) -> None:
        """Stop every trainer (final checkpoints), waiting at most ``stop_timeout_s`` in all:
        SIGTERM must not hang on an epoch; what is not saved now is redone from the last
        checkpoint and the logged data on the next start."""
        self._stopping.set()
        with self._lock:
            workers = list(self.workers.values())
        late = self.executor.stop_all(workers, self.settings.stop_timeout_s) \
            if self.executor is not None else []
        if late:
            log.warning("stopping without waiting for the trainer(s) of %s", ", ".join(late))
        self.events.close()

    # ------------------------------------------------------------------ supervision
    def _supervise(self) -> None:
        """Replace dead trainer threads, with a back-off (2 s, 4 s, ... at most 60 s)."""
        while not self._stopping.wait(1.0):
            with self._lock:
                items = list(self.workers.items())
            for name, w in items:
                if not w.died:
                    continue
                since, restarts, _ = self._dead.get(name, (time.monotonic(), 0, ""))
                why = f"trainer thread of {name!r} died ({w.error or 'unexpected exit'})"
                self._dead[name] = (since, restarts, why)
                if time.monotonic() - since < min(60.0, 2.0 * 2 ** restarts):
                    continue
                log.error("%s; restarting it from its checkpoint", why)
                self._safe_event("rotate", name)  # a new log segment: replay stitches it
                with self._lock:
                    if self.workers.get(name) is not w or self._stopping.is_set():
                        continue
                    structure = self.structures[name]
                try:
                    self._start_worker(name, structure)
                    w.stop(timeout=0.0)  # the dead one's refiner thread ends too
                except Exception:  # noqa: BLE001 - try again later
                    log.exception("restarting the trainer of %s failed", name)
                self._dead[name] = (time.monotonic(), restarts + 1, why)

    def health_problems(self) -> list[str]:
        """Why the service is not healthy (empty: healthy) - for GET /healthz."""
        problems: list[str] = []
        now = time.monotonic()
        with self._lock:
            items = list(self.workers.items())
        for name, w in items:
            if w.stopping:
                continue
            if w.died:
                problems.append(f"system {name!r}: trainer thread is dead "
                                f"({w.error or 'unexpected exit'}); restarting")
                continue
            other = w.problem()
            if other:
                problems.append(other)
                continue
            beat = getattr(w, "heartbeat", None)
            if beat is not None and now - beat > self.settings.stuck_after_s:
                problems.append(f"system {name!r}: trainer stuck, no progress for "
                                f"{now - beat:.0f} s (SIVA_STUCK_AFTER_S)")
            err = getattr(w, "checkpoint_error", None)
            if err:
                problems.append(f"system {name!r}: cannot write checkpoints ({err})")
        return problems

    def _start_worker(self, name: str, structure: Structure) -> None:
        w = self.executor.trainer(name, structure)
        with self._lock:
            self.workers[name] = w
        w.start()

    def _reconcile(self, name: str) -> None:
        """Bring the event log of ``name`` in line with the store before its trainer
        starts (service/reconcile.py); a failure is logged, never fatal: the log is an
        audit trail, the store keeps serving."""
        from ..replay.reconcile import reconcile

        if not hasattr(self.events, "folder"):  # the event log is disabled
            return
        try:
            self.repairs[name] = reconcile(self.events, self.store, name)
        except Exception:  # noqa: BLE001
            log.exception("event log of %s: start-up reconciliation failed", name)

    def _safe_event(self, method: str, *args: Any, **kw: Any) -> None:
        try:
            getattr(self.events, method)(*args, **kw)
        except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
            log.exception("event log %s failed", method)

    # ------------------------------------------------------------------ operations
    def worker(self, name: str) -> TrainerHandle:
        w = self.workers.get(name)
        if w is None:
            if name in self.broken:
                raise ApiError(409, f"system {name!r}: stored spec is invalid "
                                    f"({self.broken[name]}); DELETE and PUT it again")
            raise ApiError(404, f"system {name!r} does not exist (PUT /v1/systems/{name} first)")
        return w

    def put_system(self, name: str, spec: Any) -> tuple[bool, Structure]:
        try:
            structure = Structure.from_dict(spec)
            check_structure(structure, self.settings)
        except LimitError as exc:
            raise ApiError(exc.status, exc.detail) from None
        except SpecError as exc:
            raise ApiError(422, f"model spec: {exc}") from None
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError,
                RecursionError) as exc:
            # a shape Structure.from_dict did not anticipate (e.g. a list where a name is
            # expected): still the spec's fault; logged so the message can be improved
            log.warning("spec for %s refused by an unanticipated check", name, exc_info=True)
            raise ApiError(422, f"model spec: invalid ({type(exc).__name__}: {exc})") from None
        if not structure.free:
            raise ApiError(422, "model spec: no free parameters to identify (every parameter "
                                "is fixed); SIVA needs at least one")
        spec = structure.spec
        with self._lock:
            try:
                created = self.store.put_spec(name, spec)
            except SpecConflict as exc:
                raise ApiError(409, str(exc)) from None
            except OSError as exc:
                log.error("cannot store the spec of %s: %s", name, exc)
                raise ApiError(507, _storage_detail("the spec", exc)) from None
            if not created:
                return False, self.structures.get(name, structure)
            self.structures[name] = structure
        self._safe_event("log_spec", name, spec)
        self._start_worker(name, structure)
        return True, structure

    def delete_system(self, name: str, *, archive_logs: bool = False) -> dict[str, Any]:
        """Stop the trainer (at most ``stop_timeout_s``), then delete atomically.  A delete
        the disk refuses (507) changes nothing: the trainer is started again.  Then the
        system's MCAP event logs are deleted too, or archived (``archive_logs``); returns
        what happened to them (``EventLog.remove``)."""
        try:
            n_recordings = sum(self.store.counts(name).values())
        except UnknownSystem:
            n_recordings = None
        with self._lock:
            w = self.workers.get(name)
        if w is not None:
            w.stop(timeout=self.settings.stop_timeout_s)
        try:
            self.store.delete_system(name)
        except UnknownSystem as exc:
            raise ApiError(404, str(exc)) from None
        except OSError as exc:
            log.error("cannot delete %s: %s", name, exc)
            with self._lock:
                structure = self.structures.get(name)
                restart = structure is not None and self.workers.get(name) is w
            if restart:
                self._start_worker(name, structure)
            raise ApiError(507, _storage_detail("the deletion", exc)) from None
        with self._lock:
            if self.workers.get(name) is w:
                self.workers.pop(name, None)
            self.structures.pop(name, None)
            self.broken.pop(name, None)
        self.executor.removed(name)
        self._dead.pop(name, None)
        try:
            logs = self.events.remove(name, archive=archive_logs).to_json()
        except OSError as exc:  # the system is gone; its logs stay, and the answer says so
            log.error("%s: cannot remove the event logs: %s", name, exc)
            logs = {"action": "kept", "files": None,
                    "error": f"the event logs could not be {'archived' if archive_logs else 'deleted'} "
                             f"({exc.strerror or exc}); they are under logs/{name}/"}
        return {"recordings": n_recordings, "logs": logs}

    def add_recording(self, name: str, raw: bytes, *, role: str | None, fmt: str,
                      filename: str, channel_map: dict[str, str] | None = None,
                      units: dict[str, str] | None = None) -> dict[str, Any]:
        """Validate, store durably, log, notify the worker; runs in a worker thread."""
        w = self.worker(name)
        try:
            try:
                rates = {m.filename or m.id: m.fs for m in self.store.recordings(name)}
            except UnknownSystem as exc:
                raise ApiError(404, str(exc)) from None
            info = parse_upload(w.structure, raw, fmt, filename, channel_map=channel_map,
                                units=units, existing_rates=rates, theta=_estimate_theta(w))
            check_sampling_rate(float(info.get("fs", 0.0)), filename, self.settings)
        except RecordingTooLarge as exc:
            raise ApiError(413, str(exc)) from None
        except RecordingError as exc:
            raise ApiError(422, str(exc)) from None
        except LimitError as exc:
            raise ApiError(exc.status, exc.detail) from None

        def write_ahead(meta: Any) -> None:
            # the log entry is durable before the store commits and before the 202: every
            # acknowledged recording is in the log (a failure here aborts the upload)
            self.events.log_recording(name, meta.id, meta.role, raw, fmt, w.epoch,
                                      name=filename, channel_map=channel_map, units=units)

        try:
            meta, duplicate = self.store.add_recording(name, raw, role=role, fmt=fmt,
                                                       filename=filename, info=info,
                                                       before_commit=write_ahead)
        except DuplicateConflict as exc:
            raise ApiError(409, str(exc)) from None
        except UnknownSystem as exc:  # deleted while we parsed
            raise ApiError(404, str(exc)) from None
        except OSError as exc:
            log.error("cannot store a recording of %s: %s", name, exc)
            raise ApiError(507, _storage_detail("the recording", exc)) from None
        if not duplicate:
            w.notify()
        return {**meta.to_dict(), "duplicate": duplicate, "warnings": info["warnings"]}

    def counts(self, name: str) -> dict[str, int]:
        try:
            return self.store.counts(name)
        except UnknownSystem as exc:
            raise ApiError(404, str(exc)) from None


def _storage_detail(what: str, exc: OSError) -> str:
    import errno

    why = {errno.ENOSPC: "the disk is full", errno.EDQUOT: "the disk quota is exceeded",
           errno.EROFS: "the data directory is read-only"}.get(exc.errno or 0,
                                                              exc.strerror or str(exc))
    return f"cannot store {what}: {why}; nothing was changed, retry later"


# --------------------------------------------------------------------------- middleware
class BodyLimitMiddleware:
    """413 for request bodies above ``limit`` bytes, without reading them whole.

    A declared Content-Length above the limit is refused before the app runs; otherwise
    the bytes are counted as the app reads them and the read fails with UploadTooLarge
    (answered 413) as soon as the count passes the limit.
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for key, value in scope.get("headers", []):
            if key == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await _send_json(send, 400, "Content-Length header is not a number")
                    return
                if declared > self.limit:
                    await _send_json(send, 413, _too_large(self.limit, f"{declared} bytes declared"))
                    return
        seen = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    raise UploadTooLarge(_too_large(self.limit, f"more than {self.limit} bytes sent"))
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except UploadTooLarge as exc:  # raised where the app did not handle it itself
            if not started:
                await _send_json(send, 413, str(exc))


def _csv(text: str) -> list[str]:
    return [x.strip() for x in (text or "").split(",") if x.strip()]


def _too_large(limit: int, what: str) -> str:
    return f"request body too large: {what}, the limit is {limit} bytes (SIVA_MAX_UPLOAD_BYTES)"


async def _send_json(send: Send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


# --------------------------------------------------------------------------- the app
def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; systems are loaded and workers started in the lifespan."""
    settings = settings or Settings.from_env()
    service = SivaService(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        service.start()
        try:
            yield
        finally:
            service.stop()

    app = FastAPI(title="siva", version="0.1.0", lifespan=lifespan, docs_url=None,
                  description="Streaming structural system identification (SIVA). "
                              "See docs/service.md.")
    app.state.service = service
    app.state.settings = settings

    app.include_router(router)
    from . import dashboard, metrics

    dashboard.install(app)  # GET /, /docs (offline Swagger UI), /static, latest-record
    from .routes.diagnosis import router as diagnosis_router

    app.include_router(diagnosis_router)
    from .routes.export import router as export_router

    app.include_router(export_router)

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

    app.add_middleware(BodyLimitMiddleware, limit=settings.max_upload_bytes)
    app.add_middleware(SecurityMiddleware,  # Host allow-list, cross-site writes, headers
                       hosts=allowed_hosts(_csv(settings.allowed_hosts), settings.bind_host),
                       origins=_csv(settings.allowed_origins))
    metrics.install(app, service)  # GET /metrics; its middleware outermost (counts 413s too)
    return app


__all__ = ["create_app", "SivaService", "ApiError", "UploadTooLarge", "BodyLimitMiddleware",
           "UnknownRecording"]


def _estimate_theta(w: Any) -> Any:
    """The system's converged estimate as a parameter vector (its modes bound the sampling
    rate of new records), or None before convergence or when a value is missing."""
    import numpy as np

    try:
        snap = w.snapshot() or {}
    except Exception:  # noqa: BLE001 - a trainer without a snapshot yet
        return None
    if not snap.get("converged"):
        return None
    params = snap.get("parameters") or {}
    vals = [(params.get(p) or {}).get("mean") for p in w.structure.free]
    if not vals or any(v is None for v in vals):
        return None
    theta = np.array(vals, dtype=float)
    return theta if np.all(np.isfinite(theta)) else None
