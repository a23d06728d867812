"""The systems of one service process: the durable store, one trainer per system (threads
or Ray actors), the event log, supervision of dead trainers.  What the routes call.

Why not in the API: registering, deleting and uploading are the same operations whatever
the front (HTTP routes, the demo, a test); they raise domain errors (``errors.py``) that
the API maps to status codes, and bad input from siva_core (SpecError, RecordingError)
becomes an :class:`~service.errors.Invalid` (or :class:`~service.errors.TooLarge`) naming
what and where.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from siva_core import RecordingError, RecordingTooLarge, SpecError, Structure

from .errors import (Conflict, DuplicateConflict, Invalid, NotFound, SpecConflict, StorageRefused,
                      TooLarge, UnknownSystem)
from .fleet.executor import TrainerHandle, make_executor
from .limits import check_sampling_rate, check_structure
from .settings import Settings
from .storage.recordings import RecordingMeta
from .storage.store import Store
from .storage.uploads import parse_upload

log = logging.getLogger("siva.service")


@dataclass(frozen=True)
class Upload:
    """An accepted recording: its stored meta, whether it was already there, and what
    parsing it warned about (the API's 202 body is built from it)."""

    meta: RecordingMeta
    duplicate: bool
    warnings: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {**self.meta.to_dict(), "duplicate": self.duplicate,
                "warnings": list(self.warnings)}


@dataclass(frozen=True)
class Deletion:
    """What deleting a system removed: its recordings (None: unknown), and what happened
    to its event logs (``EventLog.remove``, or ``kept`` with the error)."""

    recordings: int | None
    logs: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"recordings": self.recordings, "logs": self.logs}


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
        from .storage.eventlog import EventLog
    except ImportError as exc:
        log.warning("event log disabled (service/storage/eventlog unavailable: %s)", exc)
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
        with self._lock:
            started = list(self.workers.values())
        self.executor.await_starts(started)  # Ray: the first reads show the resumed epochs
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
        from .replay.reconcile import reconcile

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
                raise Conflict(f"system {name!r}: stored spec is invalid "
                               f"({self.broken[name]}); DELETE and PUT it again")
            raise NotFound(f"system {name!r} does not exist (PUT /v1/systems/{name} first)")
        return w

    def put_system(self, name: str, spec: Any) -> tuple[bool, Structure]:
        try:
            structure = Structure.from_dict(spec)
            check_structure(structure, self.settings)
        except SpecError as exc:
            raise Invalid(f"model spec: {exc}") from None
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError,
                RecursionError) as exc:
            # a shape Structure.from_dict did not anticipate (e.g. a list where a name is
            # expected): still the spec's fault; logged so the message can be improved
            log.warning("spec for %s refused by an unanticipated check", name, exc_info=True)
            raise Invalid(f"model spec: invalid ({type(exc).__name__}: {exc})") from None
        if not structure.free:
            raise Invalid("model spec: no free parameters to identify (every parameter "
                          "is fixed); SIVA needs at least one")
        spec = structure.spec
        with self._lock:
            try:
                created = self.store.put_spec(name, spec)
            except SpecConflict as exc:
                raise Conflict(str(exc)) from None
            except OSError as exc:
                log.error("cannot store the spec of %s: %s", name, exc)
                raise StorageRefused(_storage_detail("the spec", exc)) from None
            if not created:
                return False, self.structures.get(name, structure)
            self.structures[name] = structure
        self._safe_event("log_spec", name, spec)
        self._start_worker(name, structure)
        return True, structure

    def delete_system(self, name: str, *, archive_logs: bool = False) -> Deletion:
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
            raise NotFound(str(exc)) from None
        except OSError as exc:
            log.error("cannot delete %s: %s", name, exc)
            with self._lock:
                structure = self.structures.get(name)
                restart = structure is not None and self.workers.get(name) is w
            if restart:
                self._start_worker(name, structure)
            raise StorageRefused(_storage_detail("the deletion", exc)) from None
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
        return Deletion(n_recordings, logs)

    def add_recording(self, name: str, raw: bytes, *, role: str | None, fmt: str,
                      filename: str, channel_map: dict[str, str] | None = None,
                      units: dict[str, str] | None = None) -> Upload:
        """Validate, store durably, log, notify the worker; runs in a worker thread."""
        w = self.worker(name)
        try:
            try:
                rates = {m.filename or m.id: m.fs for m in self.store.recordings(name)}
            except UnknownSystem as exc:
                raise NotFound(str(exc)) from None
            info = parse_upload(w.structure, raw, fmt, filename, channel_map=channel_map,
                                units=units, existing_rates=rates, theta=_estimate_theta(w))
            check_sampling_rate(info.fs, filename, self.settings)
        except RecordingTooLarge as exc:
            raise TooLarge(str(exc)) from None
        except RecordingError as exc:
            raise Invalid(str(exc)) from None

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
            raise Conflict(str(exc)) from None
        except UnknownSystem as exc:  # deleted while we parsed
            raise NotFound(str(exc)) from None
        except OSError as exc:
            log.error("cannot store a recording of %s: %s", name, exc)
            raise StorageRefused(_storage_detail("the recording", exc)) from None
        if not duplicate:
            w.notify()
        return Upload(meta, duplicate, info.warnings)

    def counts(self, name: str) -> dict[str, int]:
        try:
            return self.store.counts(name)
        except UnknownSystem as exc:
            raise NotFound(str(exc)) from None


def _storage_detail(what: str, exc: OSError) -> str:
    import errno

    why = {errno.ENOSPC: "the disk is full", errno.EDQUOT: "the disk quota is exceeded",
           errno.EROFS: "the data directory is read-only"}.get(exc.errno or 0,
                                                              exc.strerror or str(exc))
    return f"cannot store {what}: {why}; nothing was changed, retry later"


def _estimate_theta(w: Any) -> Any:
    """The system's converged estimate as a parameter vector (its modes bound the sampling
    rate of new records), or None before convergence or when a value is missing."""
    import numpy as np

    try:
        snap = w.snapshot()
    except Exception:  # noqa: BLE001 - a trainer without a snapshot yet
        return None
    if snap is None or not snap.converged:
        return None
    params = snap.parameters or {}
    vals = [(params.get(p) or {}).get("mean") for p in w.structure.free]
    if not vals or any(v is None for v in vals):
        return None
    theta = np.array(vals, dtype=float)
    return theta if np.all(np.isfinite(theta)) else None
