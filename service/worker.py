"""One trainer thread per system: streaming SIVA that never blocks a read.

Why a thread per system and immutable snapshots: training is CPU-bound torch work that
must never run inside an async route, and a GET must answer in milliseconds whatever the
trainer is doing.  The worker owns the trainer exclusively; every few epochs it builds a
new, never-mutated snapshot dict (and drift report) and swaps a reference to it, which the
routes read without a lock (a reference assignment is atomic in CPython).

Loop: when notified of new recordings it updates the replay buffer (store.ReplayBuffer),
re-reads and processes only what is selected, and calls ``trainer.set_data`` (networks and
optimisers are kept: a warm start).  It then trains epoch after epoch forever, publishing
a snapshot every ``snapshot_every`` epochs and checkpointing (atomically, torch.save) every
``checkpoint_every_s`` seconds and on shutdown.  Without both a train and a validation
record it sleeps.  A trainer exception is logged, shown in the snapshot, and retried after
a back-off; it never kills the thread.

``best`` (the recommended value of ``Siva.fit``: Approach III over the ensemble, then the
output-error refinement, ``siva_core._impl.siva.recommend_best``) is computed by a second
thread per system, the refiner, so that neither training nor reads ever wait for it.  Once
converged, the trainer thread hands it a job (a copy of the ensemble's last samples, the
ids of the most recent training records and the processing chain) whenever the data set
changed since the last job, and otherwise at most every ``refine_every_s`` seconds; the
refiner re-parses those records from the store and publishes the result into the snapshot.
A result computed on a data set that has since been replaced is dropped.  The refiner only
reads copies: the trainer's state and random generators are untouched, so ``siva replay``
still reproduces the trainer exactly (``best`` itself is not replayed).
"""
from __future__ import annotations

import csv
import logging
import math
import threading
import time
from dataclasses import asdict, is_dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from siva_core._impl.processing import Processing, States
from siva_core._impl.recording import Recording, RecordingError
from siva_core._impl.structure import Structure

from .drift import DriftMonitor, DriftRule, modal_quantities
from .settings import Settings
from .store import RecordingMeta, ReplayBuffer, Store, UnknownSystem

log = logging.getLogger("siva.service.worker")

#: one refinement at a time in the process (they are CPU-heavy and use numba's threads)
_REFINE_LOCK = threading.Lock()
#: ensemble epochs on the current data set needed before a refinement starts from them
REFINE_MIN_SAMPLES = 10

CHECKPOINT_VERSION = 1


# --------------------------------------------------------------------------- helpers
def processing_for(recordings: Sequence[Recording], dofs: Sequence[str]) -> Processing:
    """The processing chain for these records: ``Processing.auto`` when available."""
    auto = getattr(Processing, "auto", None)
    if auto is None or not recordings:
        return Processing()
    return auto(list(recordings), list(dofs))


def parse_upload(structure: Structure, raw: bytes, fmt: str, name: str) -> dict[str, Any]:
    """Validate an upload exactly as the worker will use it; returns facts for the meta.

    Raises RecordingError (a 4xx) for anything unusable, including a record the processing
    chain cannot handle (e.g. too short for its filters), so nothing unusable is stored.
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rec = Recording.read(raw, structure.dofs, name=name, fmt=fmt)
        except RecordingError:
            raise
        except ImportError as exc:
            raise RecordingError(f"{name}: format {fmt!r} is not supported here ({exc})") from None
        except (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError,
                csv.Error) as exc:
            # garbage the reader did not anticipate is still the upload's fault, not a 5xx
            raise RecordingError(f"{name}: unreadable {fmt} ({type(exc).__name__}: "
                                 f"{str(exc)[:200]})") from None
    try:
        proc = processing_for([rec], structure.dofs)
        st = proc.apply(rec, structure.dofs)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        raise RecordingError(f"{name}: cannot be processed ({exc})") from None
    if len(st) < 2 or not all(np.isfinite(x).all() for x in (st.q, st.v, st.a, st.f)):
        raise RecordingError(f"{name}: processing leaves no usable (finite) samples")
    return {"n_samples": len(rec), "fs": rec.fs, "duration_s": float(rec.time[-1] - rec.time[0]),
            "columns": ["time", *rec.channels], "warnings": [str(w.message) for w in caught]}


def jsonable(x: Any) -> Any:
    """Plain JSON types; NaN/inf become None (JSON has no NaN, and a 500 is not an option)."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if is_dataclass(x) and not isinstance(x, type):
        return jsonable(asdict(x))
    return x


def _same(a: Any, b: Any) -> bool:
    """Equality of two processing chains, even when a field holds numpy arrays."""
    try:
        return bool(a == b)
    except (ValueError, TypeError):
        return repr(a) == repr(b)


# --------------------------------------------------------------------------- the worker
class SystemWorker:
    """Owns one system's trainer, replay buffer and drift monitor (in its own thread)."""

    def __init__(self, name: str, structure: Structure, store: Store, settings: Settings,
                 events: Any | None = None, *,
                 trainer_factory: Callable[[Structure, Settings], Any] | None = None) -> None:
        self.name = name
        self.structure = structure
        self.store = store
        self.settings = settings
        self.events = events
        self._factory = trainer_factory or default_trainer
        self.buffer = ReplayBuffer(settings.replay_window, settings.replay_reservoir,
                                   settings.validation_window, f"{settings.seed}:{name}")
        self.drift = DriftMonitor(structure.free, DriftRule(settings.drift_consecutive,
                                                            settings.drift_rel_tol,
                                                            settings.drift_reference_after),
                                  settings.history_limit)
        self._drift_lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._dirty = threading.Event()
        self._dirty.set()
        self._thread = threading.Thread(target=self._run, name=f"siva-trainer-{name}", daemon=True)
        # refinement (``best``): a job slot filled by the trainer thread, emptied by the refiner
        self._snap_lock = threading.Lock()
        self._refine_cv = threading.Condition()
        self._refine_job: dict[str, Any] | None = None
        self._refine_offered: tuple[int, float] | None = None  # (data version, monotonic)
        self._data_version = 0
        self._data_epoch = 0
        self._best: dict[str, Any] | None = None
        self._best_error: str | None = None
        self._refiner = (threading.Thread(target=self._refine_loop, name=f"siva-refine-{name}",
                                          daemon=True) if settings.refine_every_s > 0 else None)
        self.trainer: Any = None
        self.epoch = 0
        self.checkpoint_epoch: int | None = None
        self.checkpoint_error: str | None = None  # the last checkpoint write failed (why)
        self.heartbeat = time.monotonic()          # loop progress, for /healthz "stuck"
        self._recs: dict[str, Recording] = {}
        self._states: dict[str, States] = {}
        self._proc: Processing | None = None
        self._train_ids: list[str] = []
        self._val_ids: list[str] = []
        self.rejected: dict[str, str] = {}       # unreadable bytes: permanent
        self.unprocessable: dict[str, str] = {}  # processing failed in the current set
        self._thetas: list[np.ndarray] = []
        self._last_log: Any = None
        self._state = "starting"
        self._error: str | None = None
        self._epoch_times: list[float] = []
        self._snapshot: dict[str, Any] = self._base_snapshot()
        self._drift_report: dict[str, Any] = self._report()

    # ------------------------------------------------------------------ control (any thread)
    def start(self) -> None:
        """Restore the trainer (checkpoint) here, so the first read after a restart already
        shows the resumed epoch; records are re-read and processed in the thread."""
        try:
            self._setup_trainer()
        except Exception as exc:  # noqa: BLE001 - the thread retries; the service stays up
            log.exception("%s: trainer setup failed", self.name)
            self.trainer = None
            self._fail(f"trainer setup failed: {type(exc).__name__}: {exc}")
        self._thread.start()
        if self._refiner is not None:
            self._refiner.start()

    def notify(self) -> None:
        """New recordings are in the store: pick them up before the next epoch."""
        self._dirty.set()
        self._wake.set()

    def stop(self, timeout: float = 60.0) -> None:
        """Stop after the current epoch; the thread writes a final checkpoint."""
        self._stop.set()
        self._wake.set()
        with self._refine_cv:
            self._refine_cv.notify_all()
        t0 = time.monotonic()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if self._refiner is not None and self._refiner.is_alive():
            # a refinement cannot be interrupted; its result is simply dropped (daemon thread)
            self._refiner.join(max(0.0, min(5.0, timeout - (time.monotonic() - t0))))

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def snapshot(self) -> dict[str, Any]:
        """The latest published snapshot (immutable by convention: never mutated)."""
        return self._snapshot

    def drift_report(self) -> dict[str, Any]:
        return self._drift_report

    def reset_drift(self) -> dict[str, Any]:
        with self._drift_lock:
            self.drift.reset()
            self._drift_report = self._report()
        return self._drift_report

    def _report(self) -> dict[str, Any]:
        """The drift report, JSON-safe.  History entries are built from already JSON-safe
        snapshots and never mutated, so only the rest needs converting (cheap per snapshot)."""
        report = self.drift.report()
        history = report.pop("history")
        return {**jsonable(report), "history": history}

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        # the OpenMP thread count is per thread: set it where the training runs, so the
        # live run matches a replay bit for bit
        import torch

        torch.set_num_threads(max(1, self.settings.torch_threads or 1))
        while self.trainer is None and not self._stop.is_set():
            self._stop.wait(10.0)
            try:
                self._setup_trainer()
            except Exception as exc:  # noqa: BLE001 - keep the service up, show the error
                log.exception("%s: trainer setup failed", self.name)
                self.trainer = None
                self._fail(f"trainer setup failed: {type(exc).__name__}: {exc}")
        failures = 0
        last_ckpt = time.monotonic()
        while not self._stop.is_set():
            self.heartbeat = time.monotonic()
            if self._dirty.is_set():
                self._dirty.clear()
                try:
                    self._refresh_data()
                except Exception as exc:  # noqa: BLE001
                    log.exception("%s: data refresh failed", self.name)
                    self._fail(f"data refresh failed: {type(exc).__name__}: {exc}")
                    self._stop.wait(5.0)
                    self._dirty.set()
                    continue
            if not (self._train_ids and self._val_ids):
                self._state = "waiting_for_data" if not self._train_ids else "waiting_for_validation"
                if self._snapshot.get("state") != self._state:
                    self._publish()
                self._wake.wait(self.settings.idle_sleep_s)
                self._wake.clear()
                continue
            try:
                t0 = time.perf_counter()
                elog = self.trainer.run_epoch()
                self._epoch_times.append(time.perf_counter() - t0)
                del self._epoch_times[:-20]
                failures = 0
                self._error = None
            except Exception as exc:  # noqa: BLE001
                failures += 1
                log.exception("%s: epoch failed (%d in a row)", self.name, failures)
                self._fail(f"epoch failed: {type(exc).__name__}: {exc}")
                self._stop.wait(min(60.0, 2.0 * failures))
                continue
            self.epoch = int(self.trainer.epoch)
            self._trim_history()
            self._last_log = elog
            self._thetas.append(np.asarray(elog.theta, dtype=float))
            self._state = "converged" if self.trainer.converged else "training"
            if len(self._thetas) >= self.settings.snapshot_every:
                self._publish(observe=True)
                self._offer_refinement()
            if time.monotonic() - last_ckpt >= self.settings.checkpoint_every_s:
                self._checkpoint()
                last_ckpt = time.monotonic()
            if self.trainer.converged and self.settings.epoch_pause_s > 0:
                self._stop.wait(self.settings.epoch_pause_s)
        if self.trainer is not None and self.trainer.epoch > 0:
            try:
                if self._thetas:
                    self._publish(observe=True)
                self._checkpoint()
            except Exception:  # noqa: BLE001
                log.exception("%s: final checkpoint failed", self.name)

    def _setup_trainer(self) -> None:
        self.trainer = self._factory(self.structure, self.settings)
        ckpt = self.store.load_checkpoint(self.name)
        if ckpt is not None:
            if ckpt.get("version") != CHECKPOINT_VERSION or ckpt.get("spec") != self.structure.spec:
                log.warning("%s: checkpoint does not match this spec/version; starting fresh",
                            self.name)
            else:
                try:
                    self.trainer.load_state_dict(ckpt["trainer"])
                    with self._drift_lock:
                        self.drift.load_state_dict(ckpt.get("drift", {}))
                except Exception:  # noqa: BLE001 - e.g. a trainer of another version
                    log.exception("%s: checkpoint unusable; training starts over", self.name)
                    self.trainer = self._factory(self.structure, self.settings)
                    with self._drift_lock:
                        self.drift.load_state_dict({})
                else:
                    self.epoch = int(self.trainer.epoch)
                    self.checkpoint_epoch = self.epoch
                    log.info("%s: resumed from checkpoint at epoch %d", self.name, self.epoch)
        self._error = None
        self._state = "starting"
        self._publish()

    def _trim_history(self) -> None:
        """The trainer logs every epoch in ``history``; a service trains forever, so keep
        only the last ``history_limit`` entries (memory and checkpoint size stay bounded)."""
        hist = getattr(self.trainer, "history", None)
        limit = self.settings.history_limit
        if isinstance(hist, dict):
            for values in hist.values():
                if isinstance(values, list) and len(values) > 2 * limit:
                    del values[:-limit]

    def _fail(self, message: str) -> None:
        self._error = message
        self._state = "error"
        self._publish()

    # ------------------------------------------------------------------ data
    def _refresh_data(self) -> None:
        try:
            metas = self.store.recordings(self.name)
        except UnknownSystem:
            self._stop.set()  # deleted under us
            return
        by_id: dict[str, RecordingMeta] = {m.id: m for m in metas}
        self.buffer.extend(m for m in metas if m.index > self.buffer.last_index)
        wanted = [i for i in self.buffer.train_ids + self.buffer.val_ids if i not in self.rejected]
        for rid in wanted:
            if rid in self._recs:
                continue
            meta = by_id[rid]
            try:
                raw = self.store.read_raw(self.name, meta)
                self._recs[rid] = Recording.read(raw, self.structure.dofs, name=rid, fmt=meta.fmt)
            except (OSError, RecordingError) as exc:
                log.error("%s: recording %s unusable: %s", self.name, rid, exc)
                self.rejected[rid] = str(exc)
        for rid in list(self._recs):
            if rid not in wanted:
                del self._recs[rid]
        recs = [self._recs[i] for i in wanted if i in self._recs]
        try:
            proc = processing_for(recs, self.structure.dofs)
        except Exception as exc:  # noqa: BLE001 - fall back to the plain chain, say so
            log.error("%s: Processing.auto failed (%s); using Processing()", self.name, exc)
            proc = Processing()
        if not _same(proc, self._proc):
            self._states.clear()
            self._proc = proc
        for rid in list(self._states):
            if rid not in self._recs:
                del self._states[rid]
        self.unprocessable = {}
        for rid, rec in self._recs.items():
            if rid in self._states:
                continue
            try:
                self._states[rid] = proc.apply(rec, self.structure.dofs)
            except Exception as exc:  # noqa: BLE001
                # the chain chosen for the whole set does not suit this record (it passed
                # its own chain at upload): use the record's own chain rather than lose it
                try:
                    own = processing_for([rec], self.structure.dofs)
                    self._states[rid] = own.apply(rec, self.structure.dofs)
                    log.warning("%s: %s processed with its own chain (the common one "
                                "failed: %s)", self.name, rid, exc)
                except Exception as exc2:  # noqa: BLE001
                    log.error("%s: processing %s failed: %s", self.name, rid, exc2)
                    self.unprocessable[rid] = f"processing failed: {exc2}"
        train = [i for i in self.buffer.train_ids if i in self._states]
        val = [i for i in self.buffer.val_ids if i in self._states]
        changed = (train, val) != (self._train_ids, self._val_ids)
        self._train_ids, self._val_ids = train, val
        if train and val and (changed or getattr(self.trainer, "train", None) is None):
            self.trainer.set_data([self._states[i] for i in train], [self._states[i] for i in val])
            self._data_version += 1
            self._data_epoch = int(self.trainer.epoch)
            if self.events is not None:
                self.events.log_dataset(self.name, int(self.trainer.epoch), train, val,
                                        processing=self._proc)

    # ------------------------------------------------------------------ snapshots
    def _base_snapshot(self) -> dict[str, Any]:
        return {"system": self.name, "state": self._state, "epoch": self.epoch,
                "converged": False, "converged_at": None, "parameters": {},
                "estimate_source": None, "discriminator": {}, "error": self._error,
                "time": time.time()}

    def _estimate(self) -> tuple[dict[str, Any], str | None]:
        return estimate_parameters(self.structure, self.trainer)

    def _publish(self, observe: bool = False) -> None:
        snap = self._base_snapshot()
        tr = self.trainer
        recent: dict[str, float] = {}
        if self._thetas:
            mean_theta = np.mean(self._thetas, axis=0)
            recent = self.structure.as_dict(mean_theta)
        self._thetas = []
        if tr is not None:
            try:
                params, source = self._estimate()
                disc = tr.discriminator_scores() if (self._train_ids and tr.epoch > 0) else {}
            except Exception as exc:  # noqa: BLE001 - a read-out must not kill training
                log.exception("%s: building the snapshot failed", self.name)
                params, source, disc = {}, None, {}
                snap["error"] = f"snapshot failed: {exc}"
            means = [params[p]["mean"] for p in self.structure.free] if params else None
            modal = modal_quantities(self.structure, means) if means else None
            # the modal quantities of the last epochs: they follow a change at once, while
            # the running ensemble's means lag by up to its length
            modal_recent = (modal_quantities(self.structure, [recent[p] for p in self.structure.free])
                            if recent else None)
            snap.update({
                "epoch": int(tr.epoch),
                "converged": bool(tr.converged),
                "converged_at": getattr(getattr(tr, "monitor", None), "converged_at", None),
                "parameters": params,
                "estimate_source": source,
                "recent": recent,
                "fixed": {p: i.fixed for p, i in self.structure.parameters.items()
                          if i.fixed is not None and not p.startswith("_fixed_")},
                "discriminator": disc,
                "modal": modal,
                "modal_recent": modal_recent,
            })
            if self._last_log is not None:
                snap["losses"] = {"loss_d": self._last_log.loss_d,
                                  "loss_adv": self._last_log.loss_adv,
                                  "loss_mse": self._last_log.loss_mse}
        snap["data"] = {
            "train": list(self._train_ids), "validation": list(self._val_ids),
            "train_samples": int(sum(len(self._states[i]) for i in self._train_ids)),
            "validation_samples": int(sum(len(self._states[i]) for i in self._val_ids)),
            "processing": jsonable(self._proc) if self._proc is not None else None,
            "rejected": {**self.rejected, **self.unprocessable},
        }
        snap["checkpoint_epoch"] = self.checkpoint_epoch
        if self._epoch_times:
            snap["seconds_per_epoch"] = float(np.mean(self._epoch_times))
        snap = jsonable(snap)
        snap["best"] = self._best
        if self._best_error:
            snap["best_error"] = self._best_error
        with self._drift_lock:
            if observe and tr is not None and recent:
                raised = self.drift.observe({
                    "epoch": snap["epoch"], "time": snap["time"], "converged": snap["converged"],
                    "recent": snap["recent"],
                    "parameters": {p: {k: s.get(k) for k in ("mean", "std", "ci95")}
                                   for p, s in snap["parameters"].items()},
                    "modal": snap.get("modal_recent"), "modal_estimate": snap.get("modal"),
                    "n_train": len(self._train_ids),
                    "n_validation": len(self._val_ids)})
                for a in raised:
                    log.warning("%s: drift alarm: %s", self.name, a["message"])
            report = self._report()
        snap["alarms"] = [a for a in report["alarms"] if a["active"]]
        self._drift_report = report
        with self._snap_lock:
            # the refiner may have published a newer ``best`` while this one was built
            snap["best"] = self._best
            self._snapshot = snap
        if self.events is not None and observe:
            try:
                self.events.log_snapshot(self.name, estimate_view(snap, self._counts()))
            except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
                log.exception("%s: event log failed", self.name)

    # ------------------------------------------------------------------ refinement (best)
    def _offer_refinement(self) -> None:
        """Trainer thread: hand the refiner a job when one is due (cheap: copies only)."""
        tr = self.trainer
        if self._refiner is None or tr is None or not tr.converged or not self._train_ids:
            return
        now = time.monotonic()
        last = self._refine_offered
        if (last is not None and last[0] == self._data_version
                and now - last[1] < self.settings.refine_every_s):
            return
        ens = getattr(tr, "ensemble", None)
        if ens is None or len(ens) == 0:
            return
        samples = np.array(ens.samples, dtype=float, copy=True)
        epochs = np.asarray(getattr(ens, "epochs", np.full(len(samples), tr.epoch)))
        samples = samples[epochs >= self._data_epoch]  # harvested on the current data set
        if len(samples) < min(REFINE_MIN_SAMPLES, getattr(ens, "maxlen", None) or REFINE_MIN_SAMPLES):
            return  # just after a data change: wait for samples of the new data set
        job = {"version": self._data_version, "epoch": int(tr.epoch),
               "candidates": samples[-self.settings.refine_candidates:],
               "train": list(self._train_ids[-self.settings.refine_max_records:]),
               "processing": self._proc}
        self._refine_offered = (self._data_version, now)
        with self._refine_cv:
            self._refine_job = job  # a job not yet started is superseded by this one
            self._refine_cv.notify_all()

    def _refine_loop(self) -> None:
        while not self._stop.is_set():
            with self._refine_cv:
                while self._refine_job is None and not self._stop.is_set():
                    self._refine_cv.wait(1.0)
                job, self._refine_job = self._refine_job, None
            if job is None or self._stop.is_set():
                continue
            try:
                best = self._refine(job)
            except Exception as exc:  # noqa: BLE001 - never kills the thread or the service
                log.exception("%s: refinement failed", self.name)
                self._best_error = f"refinement failed: {type(exc).__name__}: {exc}"
                continue
            if best is None:
                continue
            with self._snap_lock:
                if job["version"] != self._data_version:  # a newer data set supersedes it
                    log.info("%s: refinement of data set %d superseded; result dropped",
                             self.name, job["version"])
                    continue
                self._best = best
                self._best_error = None
                snap = {k: v for k, v in self._snapshot.items() if k != "best_error"}
                snap["best"] = best
                self._snapshot = snap

    def _refine(self, job: dict[str, Any]) -> dict[str, Any] | None:
        """Refiner thread: ``recommend_best`` on the job's records, re-parsed from the store.
        None when the data set changed meanwhile (a newer job follows) or the service stops."""
        from siva_core._impl.siva import recommend_best

        t0 = time.perf_counter()
        by_id = {m.id: m for m in self.store.recordings(self.name)}
        recs = []
        for rid in job["train"]:
            meta = by_id.get(rid)
            if meta is None:
                return None  # deleted meanwhile
            raw = self.store.read_raw(self.name, meta)
            recs.append(Recording.read(raw, self.structure.dofs, name=rid, fmt=meta.fmt))
        proc = job["processing"] if job["processing"] is not None else Processing()
        with _REFINE_LOCK:
            if self._stop.is_set() or job["version"] != self._data_version:
                return None
            rec = recommend_best(self.structure, job["candidates"], recs, proc)
        params: dict[str, Any] = {}
        for k, p in enumerate(self.structure.free):
            v = float(rec.theta[k])
            s = None if rec.std is None else float(rec.std[k])
            params[p] = {"value": v, "std": s,
                         "ci95": None if s is None else [v - 1.96 * s, v + 1.96 * s]}
        seconds = time.perf_counter() - t0
        log.info("%s: best from %d candidates on %d record(s) in %.1f s (refined=%s, "
                 "output error %.3g)", self.name, len(job["candidates"]), len(recs), seconds,
                 rec.refined, rec.output_error if rec.output_error is not None else float("nan"))
        return jsonable({
            "parameters": params, "epoch": job["epoch"], "n_records": len(recs),
            "time": time.time(), "output_error": rec.output_error,
            "refined": rec.refined, "records": job["train"], "n_candidates": len(job["candidates"]),
            "approach_III": self.structure.as_dict(rec.theta_III), "note": rec.note,
            "seconds": seconds})

    def _counts(self) -> dict[str, int]:
        try:
            return self.store.counts(self.name)
        except UnknownSystem:
            return {"train": 0, "validation": 0}

    def _checkpoint(self) -> None:
        if self.trainer is None:
            return
        state = {"version": CHECKPOINT_VERSION, "spec": self.structure.spec,
                 "trainer": self.trainer.state_dict(),
                 "drift": self.drift.state_dict(),
                 "data": {"train": list(self._train_ids), "validation": list(self._val_ids)},
                 "time": time.time()}
        try:
            self.store.save_checkpoint(self.name, state)
        except UnknownSystem:
            return
        except Exception as exc:  # noqa: BLE001 - disk full/read-only: train on, retry later
            log.error("%s: checkpoint failed: %s", self.name, exc)
            self.checkpoint_error = f"{type(exc).__name__}: {exc}"
            return
        self.checkpoint_error = None
        self.checkpoint_epoch = int(self.trainer.epoch)


def estimate_view(snapshot: Mapping[str, Any], counts: Mapping[str, int]) -> dict[str, Any]:
    """The GET .../estimate body: the contract's keys first, then everything else."""
    out = {"parameters": {p: {"mean": s.get("mean"), "std": s.get("std"), "ci95": s.get("ci95"),
                              **{k: v for k, v in s.items() if k not in ("mean", "std", "ci95")}}
                          for p, s in snapshot.get("parameters", {}).items()},
           "discriminator": snapshot.get("discriminator", {}),
           "epoch": snapshot.get("epoch", 0),
           "converged": snapshot.get("converged", False),
           "n_recordings": {"train": int(counts.get("train", 0)),
                            "validation": int(counts.get("validation", 0))}}
    for k, v in snapshot.items():
        if k not in out:
            out[k] = v
    return out


def default_trainer(structure: Structure, settings: Settings) -> Any:
    """The lead's SivaTrainer with the preset and seed of the settings."""
    from siva_core._impl.training import SivaSettings, SivaTrainer

    preset = getattr(SivaSettings, settings.preset, None)
    if preset is None:
        raise ValueError(f"unknown SIVA preset {settings.preset!r} (fast, paper)")
    return SivaTrainer(structure, preset(seed=settings.seed))


def estimate_parameters(structure: Structure, tr: Any) -> tuple[dict[str, Any], str | None]:
    """Parameters {mean, std, ci95, ess, n}: the Approach II ensemble once converged,
    before that the spread of the generator's output (Approach I sampling).  Shared by the
    live worker and ``siva replay`` so both read out the same way."""
    free = structure.free
    summary = tr.ensemble.summary(free) if len(tr.ensemble) >= 2 else {}
    if summary:
        return summary, "approach_II"
    if tr.epoch == 0 or not getattr(tr, "initialised", True):
        return {}, None
    from siva_core._impl.ensemble import normal_summary

    return normal_summary(tr.sample(256), free, ess=False), "generator"
