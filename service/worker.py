"""One trainer thread per system: streaming SIVA that never blocks a read.

Why a thread per system and immutable snapshots: training is CPU-bound torch work that
must never run inside an async route, and a GET must answer in milliseconds whatever the
trainer is doing.  The worker owns the trainer exclusively; every few epochs it builds a
new, never-mutated snapshot dict (and drift report) and swaps a reference to it, which the
routes read without a lock (a reference assignment is atomic in CPython).

Loop: when notified of new recordings it updates the replay buffer (store.ReplayBuffer),
re-reads and processes only what is selected, and calls ``trainer.set_data`` (networks and
optimisers are kept: a warm start).  It then trains epoch after epoch forever, publishing
a snapshot every ``snapshot_every`` epochs (or ``snapshot_max_interval_s``) and checkpointing (atomically, torch.save) every
``checkpoint_every_s`` seconds and on shutdown.  Without both a train and a validation
record it sleeps.  A trainer exception is logged, shown in the snapshot, and retried after
a back-off; it never kills the thread.

``best`` and monitoring run in a second thread per system (service/refiner.py), so that
neither training nor reads ever wait for them.  Once converged, the trainer thread hands it
one job: the first ``best`` (``recommend_best`` on the ensemble).  From then on the refiner
fits every stored record once, in arrival order (service/monitor.py: one output-error fit
per record, warm-started from the headline); those fits give the headline estimate
(``parameters``, ``estimate_source = "best"``) and the drift test (service/detector.py).
Nothing is refitted on unchanged data.

Idle: once converged, ``idle_after_epochs`` epochs after the last data change the trainer
pauses (state ``idle``) until a new record arrives; with the refiner also waiting, an idle
system uses no CPU.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

import numpy as np

from siva_core import Processing, Recording, RecordingError, States, Structure

from .checkpoints import CHECKPOINT_VERSION, checkpoint_state, matches
from .detector import DetectorSettings
from .drift import EstimateHistory, modal_quantities
from .estimate import estimate_parameters, estimate_view, headline, jsonable
from .monitor import RecordMonitor
from .refiner import REFINE_LOCK, Refiner
from .settings import Settings
from .store import RecordingMeta, ReplayBuffer, Store, UnknownSystem
from .uploads import parse_upload, processing_for

log = logging.getLogger("siva.service.worker")

#: ensemble epochs on the current data set needed before a refinement starts from them
REFINE_MIN_SAMPLES = 10

__all__ = ["SystemWorker", "default_trainer", "base_snapshot", "stop_workers", "CHECKPOINT_VERSION", "REFINE_MIN_SAMPLES",
           # moved to their own modules; re-exported for existing imports
           "parse_upload", "processing_for", "estimate_view", "estimate_parameters", "jsonable"]


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
        self.history = EstimateHistory(settings.history_limit)
        self.monitor = RecordMonitor(structure, DetectorSettings(
            baseline_records=settings.drift_baseline_records,
            arl0_records=settings.drift_arl0_records,
            min_rel_scatter=settings.drift_min_rel_scatter),
            window=settings.headline_window, max_nfev=settings.record_max_nfev,
            max_records=settings.history_limit)
        self._monitor_view: dict[str, Any] = {"report": self.monitor.report(limit=0),
                                              "best": None}
        self._drift_lock = threading.Lock()
        self._monitor_lock = threading.Lock()  # the monitor changes under it (refiner, reset)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._dirty = threading.Event()
        self._dirty.set()
        self._thread = threading.Thread(target=self._run, name=f"siva-trainer-{name}", daemon=True)
        # refinement (``best``): the refiner thread fills it through ``_set_best``
        self._snap_lock = threading.Lock()
        self._refine_offered: tuple[int, float] | None = None  # (data version, monotonic)
        self._data_version = 0
        self._data_epoch = 0
        self._best: dict[str, Any] | None = None
        self._best_error: str | None = None
        self._refiner = (Refiner(name, structure, store,
                                 on_result=self._set_best, on_error=self._set_best_error,
                                 step=self._monitor_step)
                         if settings.refine_every_s > 0 else None)
        self._idle_since_epoch: int | None = None
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
        self._published_at = time.monotonic()
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
        if self._refiner is not None:
            self._refiner.poke()

    def request_stop(self) -> None:
        """Ask the threads to stop without waiting (``stop`` waits)."""
        self._stop.set()
        self._wake.set()

    def stop(self, timeout: float = 60.0) -> None:
        """Stop after the current epoch; the thread writes a final checkpoint."""
        self.request_stop()
        t0 = time.monotonic()
        if self._refiner is not None:
            self._refiner.request_stop()
        if self._thread.is_alive():
            self._thread.join(timeout)
        if self._refiner is not None:
            self._refiner.stop(min(5.0, timeout - (time.monotonic() - t0)))

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    @property
    def died(self) -> bool:
        """The trainer thread was started and ended without being asked to stop (a worker
        still restoring its checkpoint in ``start`` has not started its thread yet)."""
        t = self._thread
        return t.ident is not None and not t.is_alive() and not self._stop.is_set()

    @property
    def error(self) -> str | None:
        return self._error

    def problem(self) -> str | None:
        """Why this trainer is unhealthy beyond death, stalls and checkpoints (None)."""
        return None

    def snapshot(self) -> dict[str, Any]:
        """The latest published snapshot (immutable by convention: never mutated)."""
        return self._snapshot

    def drift_report(self) -> dict[str, Any]:
        return self._drift_report

    def reset_drift(self) -> dict[str, Any]:
        """Forget baseline and alarms (after a repair): the next records form a new baseline.
        Waits for a per-record fit in progress, so the reset is never half-applied."""
        with self._monitor_lock:
            self.monitor.reset()
            with self._snap_lock:
                self._update_monitor_view()
                self._refresh_snapshot()
        return self._drift_report

    def _report(self) -> dict[str, Any]:
        """The drift report, JSON-safe: the detector's rule, reference, alarm history and
        per-record estimates (``records``), the headline, and the published estimates
        (``history``, already JSON-safe and never mutated)."""
        view = self._monitor_view
        snap = getattr(self, "_snapshot", {}) or {}
        return {**view["report"], "headline": {
                    "parameters": snap.get("parameters", {}),
                    "estimate_source": snap.get("estimate_source"),
                    "estimate": snap.get("estimate"), "modal": snap.get("modal")},
                "history": self.history.last()}

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
            if self._snapshot_due():
                self._publish(observe=True)
                self._offer_refinement()
            if time.monotonic() - last_ckpt >= self.settings.checkpoint_every_s:
                self._checkpoint()
                last_ckpt = time.monotonic()
            if self.trainer.converged and self.settings.epoch_pause_s > 0:
                self._stop.wait(self.settings.epoch_pause_s)
            if self._should_idle():
                self._idle()
                last_ckpt = time.monotonic()
        if self.trainer is not None and self.trainer.epoch > 0:
            try:
                if self._thetas:
                    self._publish(observe=True)
                self._checkpoint()
            except Exception:  # noqa: BLE001
                log.exception("%s: final checkpoint failed", self.name)

    def _snapshot_due(self) -> bool:
        """``snapshot_every`` epochs since the last snapshot, or ``snapshot_max_interval_s``
        seconds and at least one epoch: with many systems sharing few cores an epoch can
        take seconds, and an estimate should still move every few seconds."""
        s = self.settings
        if len(self._thetas) >= s.snapshot_every:
            return True
        return bool(self._thetas) and s.snapshot_max_interval_s > 0 and (
            time.monotonic() - self._published_at >= s.snapshot_max_interval_s)

    def _should_idle(self) -> bool:
        """Converged, ``idle_after_epochs`` epochs on unchanged data, the first ``best``
        asked for: more epochs would only re-sample the same posterior."""
        n = self.settings.idle_after_epochs
        tr = self.trainer
        if n <= 0 or tr is None or not tr.converged or self._dirty.is_set():
            return False
        if self._idle_since_epoch is None:
            self._idle_since_epoch = int(tr.epoch)
        due = int(tr.epoch) - max(self._idle_since_epoch, self._data_epoch) >= n
        return due and (self._refiner is None or self._refine_offered is not None
                        or self._best is not None)

    def _idle(self) -> None:
        """Trainer thread: publish, checkpoint, then sleep until new data (or stop)."""
        self._state = "idle"
        if self._thetas:
            self._publish(observe=True)
        else:
            self._publish()
        self._checkpoint()
        log.info("%s: idle at epoch %d (converged, data unchanged); resumes on new data",
                 self.name, self.epoch)
        while not self._stop.is_set() and not self._dirty.is_set():
            self.heartbeat = time.monotonic()  # idle is not stuck (for a liveness check)
            self._wake.wait(10.0)
            self._wake.clear()
        self._idle_since_epoch = None
        self._state = "converged"

    def _setup_trainer(self) -> None:
        self.trainer = self._factory(self.structure, self.settings)
        ckpt = self.store.load_checkpoint(self.name)
        if ckpt is not None:
            if not matches(ckpt, self.structure.spec):
                log.warning("%s: checkpoint does not match this spec/version; starting fresh",
                            self.name)
            else:
                try:
                    self.trainer.load_state_dict(ckpt["trainer"])
                    with self._drift_lock:
                        self.history.load_state_dict(ckpt.get("drift", {}))
                        self.monitor.load_state_dict(ckpt.get("monitor", {}))
                        self._best = ckpt.get("best")
                        self._update_monitor_view()
                except Exception:  # noqa: BLE001 - e.g. a trainer of another version
                    log.exception("%s: checkpoint unusable; training starts over", self.name)
                    self.trainer = self._factory(self.structure, self.settings)
                    with self._drift_lock:
                        self.history.load_state_dict({})
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
                self._recs[rid] = Recording.read(raw, self.structure.dofs, name=rid, fmt=meta.fmt,
                                                 **meta.read_options(self.structure))
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
        return base_snapshot(self.name, self._state, self.epoch, self._error)

    def _estimate(self) -> tuple[dict[str, Any], str | None]:
        return estimate_parameters(self.structure, self.trainer)

    def _current_best(self) -> dict[str, Any] | None:
        """The monitor's headline once it has one, else the first ``best``."""
        return self._monitor_view.get("best") or self._best

    def _publish(self, observe: bool = False) -> None:
        self._published_at = time.monotonic()
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
            modal_recent = (modal_quantities(self.structure, [recent[p] for p in self.structure.free])
                            if recent else None)
            snap.update({
                "epoch": int(tr.epoch),
                "converged": bool(tr.converged),
                "converged_at": getattr(getattr(tr, "monitor", None), "converged_at", None),
                "recent": recent,
                "fixed": {p: i.fixed for p, i in self.structure.parameters.items()
                          if i.fixed is not None and not p.startswith("_fixed_")},
                "discriminator": disc,
                "modal_recent": modal_recent,
            })
            snap.update({"ensemble": params, "ensemble_source": source})
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
        with self._snap_lock:
            # the refiner may have published a newer ``best`` while this one was built
            if tr is not None:
                snap.update(jsonable(self._headline_keys(snap.get("ensemble", {}),
                                                         snap.get("ensemble_source"))))
            if self._best_error:
                snap["best_error"] = self._best_error
            snap["alarms"] = [a for a in self._monitor_view["report"]["alarms"] if a["active"]]
            self._snapshot = snap
            with self._drift_lock:
                if observe and tr is not None:
                    self.history.add({
                        "epoch": snap["epoch"], "time": snap["time"],
                        "converged": snap["converged"], "recent": snap.get("recent") or {},
                        "parameters": {p: {k: v.get(k) for k in ("mean", "std", "ci95")}
                                       for p, v in snap.get("parameters", {}).items()},
                        "estimate_source": snap.get("estimate_source"),
                        "ensemble": {p: v.get("mean") for p, v in
                                     snap.get("ensemble", {}).items()},
                        "modal": snap.get("modal"), "modal_recent": snap.get("modal_recent")})
                self._drift_report = self._report()
        if self.events is not None and observe:
            try:
                self.events.log_snapshot(self.name, estimate_view(snap, self._counts()))
            except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
                log.exception("%s: event log failed", self.name)

    def _headline_keys(self, ensemble: dict[str, Any], source: str | None) -> dict[str, Any]:
        keys = headline(self.structure, ensemble, source, self._current_best())
        means = [keys["parameters"].get(p, {}).get("mean") for p in self.structure.free]
        keys["modal"] = (modal_quantities(self.structure, means)
                         if means and all(m is not None for m in means) else None)
        keys["best"] = self._current_best()
        keys["monitoring"] = self._monitor_view.get("summary")
        keys["alarm_history"] = self._monitor_view["report"]["alarm_history"]
        return keys

    # ------------------------------------------------------------------ refinement (best)
    def _offer_refinement(self) -> None:
        """Trainer thread: hand the refiner a job when one is due (cheap: copies only)."""
        tr = self.trainer
        if self._refiner is None or tr is None or not tr.converged or not self._train_ids:
            return
        now = time.monotonic()
        last = self._refine_offered
        if self._best is not None or self.monitor.ready:
            return  # from now on the per-record fits carry the headline
        if last is not None and (last[0] == self._data_version
                                 or now - last[1] < self.settings.refine_every_s):
            return  # one job per data set, at most every refine_every_s
        ens = getattr(tr, "ensemble", None)
        if ens is None or len(ens) == 0:
            return
        samples = np.array(ens.samples, dtype=float, copy=True)
        epochs = np.asarray(getattr(ens, "epochs", np.full(len(samples), tr.epoch)))
        need = min(REFINE_MIN_SAMPLES, getattr(ens, "maxlen", None) or REFINE_MIN_SAMPLES)
        current = samples[epochs >= self._data_epoch]  # harvested on the current data set
        # prefer candidates of the current data set; while records stream (a new data set
        # every few epochs) the older ones will do: Approach III picks among them on the
        # current records, and the refinement and per-record fits take it from there
        samples = current if len(current) >= need else samples
        if len(samples) < need:
            return
        job = {"version": self._data_version, "epoch": int(tr.epoch),
               "candidates": samples[-self.settings.refine_candidates:],
               "train": list(self._train_ids[-self.settings.refine_max_records:]),
               "processing": self._proc}
        self._refine_offered = (self._data_version, now)
        self._refiner.submit(job)

    def _set_best(self, best: dict[str, Any], job: dict[str, Any]) -> None:
        """Refiner thread: publish the first ``best`` and seed the monitor with it.  Kept
        even when records arrived meanwhile (while records stream they always do): it only
        starts the per-record fits, which then follow every record."""
        with self._snap_lock:
            self._best = {**best, "source": "recommend_best",
                          "method": "Approach III over the ensemble, then output-error "
                                    "refinement on the most recent training records"}
            self._best_error = None
            if not self.monitor.ready:
                theta = [best["parameters"][p]["value"] for p in self.structure.free]
                proc = job["processing"] if job["processing"] is not None else Processing()
                with self._monitor_lock:
                    self.monitor.seed(theta, proc)
            self._refresh_snapshot()

    def _refresh_snapshot(self) -> None:
        """Refiner thread (under ``_snap_lock``): the headline keys of the current snapshot
        follow a new ``best`` at once, even while the trainer is idle."""
        snap = {k: v for k, v in self._snapshot.items() if k != "best_error"}
        if snap.get("epoch"):
            snap.update(jsonable(self._headline_keys(snap.get("ensemble", {}),
                                                     snap.get("ensemble_source"))))
        snap["alarms"] = [a for a in self._monitor_view["report"]["alarms"] if a["active"]]
        self._snapshot = snap
        with self._drift_lock:
            self._drift_report = self._report()

    # ------------------------------------------------------------------ monitoring
    def _monitor_step(self) -> bool:
        """Refiner thread: fit the oldest stored record not yet monitored; False when
        there is none (or no ``best`` to start from yet)."""
        if not self.monitor.ready or self._stop.is_set():
            return False
        try:
            metas = self.store.recordings(self.name)
        except UnknownSystem:
            return False
        pending = [m for m in metas if m.index > self.monitor.processed_index]
        if not pending:
            return False
        meta = min(pending, key=lambda m: m.index)
        try:
            raw = self.store.read_raw(self.name, meta)
            rec = Recording.read(raw, self.structure.dofs, name=meta.id, fmt=meta.fmt,
                                 **meta.read_options(self.structure))
        except (OSError, RecordingError) as exc:
            self.monitor.processed_index = meta.index
            self.monitor.failures[meta.id] = str(exc)
            return True
        with REFINE_LOCK, self._monitor_lock:
            if self._stop.is_set():
                return False
            changes = self.monitor.process(meta.id, meta.index, rec,
                                           getattr(meta, "received_at", None))
        for a in changes:
            a.setdefault(f"epoch_{a['state']}", self.epoch)
            a.setdefault("epoch", self.epoch)
            log.warning("%s: drift alarm %s: %s", self.name, a["state"], a["message"])
        with self._snap_lock:
            self._update_monitor_view()
            self._refresh_snapshot()
        if changes and self.events is not None:
            try:
                self.events.log_snapshot(self.name, estimate_view(self._snapshot, self._counts()))
            except Exception:  # noqa: BLE001
                log.exception("%s: event log failed", self.name)
        return True

    def _update_monitor_view(self) -> None:
        """Immutable, JSON-safe copies of what the monitor holds, for readers."""
        self._monitor_view = jsonable(self.monitor.view(self.epoch, self.settings.history_limit))

    def _set_best_error(self, message: str) -> None:
        self._best_error = message

    def _counts(self) -> dict[str, int]:
        try:
            return self.store.counts(self.name)
        except UnknownSystem:
            return {"train": 0, "validation": 0}

    def _checkpoint(self) -> None:
        if self.trainer is None:
            return
        with self._monitor_lock:  # a consistent monitor (no fit half-applied)
            extra = {"monitor": self.monitor.state_dict(), "best": self._best}
        position = getattr(self.events, "position", None)
        if position is not None:  # which log explains this state (service/reconcile.py)
            try:
                extra["log"] = position(self.name)
            except Exception:  # noqa: BLE001 - an audit aid, never a reason not to checkpoint
                pass
        state = checkpoint_state(self.structure.spec, self.trainer, self.history,
                                 self._train_ids, self._val_ids, extra)
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


def stop_workers(workers: list[Any], timeout: float) -> list[str]:
    """Ask every worker to stop, then wait at most ``timeout`` in all (one slow epoch must
    not delay the others' final checkpoints); returns the names still running."""
    for w in workers:
        w.request_stop()
    deadline = time.monotonic() + timeout
    for w in workers:
        w.stop(timeout=max(0.0, deadline - time.monotonic()))
    return [w.name for w in workers if w.alive]


def base_snapshot(name: str, state: str, epoch: int = 0,
                  error: str | None = None) -> dict[str, Any]:
    """The keys every snapshot has, before any estimate exists."""
    return {"system": name, "state": state, "epoch": epoch, "converged": False,
            "converged_at": None, "parameters": {}, "estimate_source": None,
            "discriminator": {}, "error": error, "time": time.time()}


def default_trainer(structure: Structure, settings: Settings) -> Any:
    """The lead's SivaTrainer with the preset and seed of the settings."""
    from siva_core import SivaSettings, SivaTrainer

    preset = getattr(SivaSettings, settings.preset, None)
    if preset is None:
        raise ValueError(f"unknown SIVA preset {settings.preset!r} (fast, paper)")
    return SivaTrainer(structure, preset(seed=settings.seed))
