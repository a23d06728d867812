"""One trainer thread per system: ``siva identify``'s two-phase SIVA, streaming.

Why a thread per system and immutable snapshots: training is CPU-bound torch work that
must never run inside an async route, and a GET must answer in milliseconds whatever the
trainer is doing.  The worker owns the trainer exclusively; every few epochs it builds a
new, never-mutated snapshot dict and swaps a reference to it, which the routes read
without a lock (a reference assignment is atomic in CPython).

The method (docs/method.md, docs/service.md "The running ensemble"):

1. **Equation error** (the paper's loss) until converged: cheap, finds the basin.  Its
   ensemble is biased by the processing chain on measured data, so it is published as
   ``provisional`` (no ``ci95``).
2. **The first ``best``** (refiner thread): Approach III over that ensemble and the
   output-error refinement; then the output error is linearised at it (the *anchor*).
3. **Output error**: between two epochs the trainer switches to the linearised output
   error with one parametric-bootstrap replicate per epoch, exactly as ``Siva.fit``;
   once converged it harvests Approach II samples, the running ensemble (final after
   ``ENSEMBLE_MIN_SAMPLES``: then it has a ``ci95``).
4. **New records** (``notify``): the data set changes (``set_data``: a warm start) and the
   refiner re-anchors at the current headline (which the per-record fits have already
   updated); the networks stay warm, the ensemble restarts on the new anchor.

Every data set and every anchor is logged (``/siva/dataset``, ``/siva/anchor``) with the
epoch it took effect, so ``siva replay`` rebuilds the same trainer bit for bit.

Monitoring (per-record fits, headline, drift) and the validation test run in the refiner
thread (``refiner.py``); neither training nor reads wait for them.  Idle: once the
ensemble is final and ``idle_after_epochs`` epochs have passed on unchanged data, the
trainer sleeps until a record arrives; an idle system uses no CPU.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

import numpy as np

from siva_core import Processing, Structure

from ..checkpoints import checkpoint_state, matches
from ..drift import EstimateHistory
from ..estimate import estimate_view
from ..settings import Settings
from ..store import Store, UnknownSystem
from .anchoring import anchor_record, apply_anchor, build_anchor, processing_from
from .data import DataFeed, SystemDeleted
from .factory import base_snapshot, default_trainer
from .readout import (ENSEMBLE_MIN_SAMPLES, EnsembleReadout, candidates, output_error_wanted,
                      read_ensemble)
from .monitoring import Monitoring
from .refiner import REFINE_LOCK, Refiner
from .snapshot import SnapshotParts, build_snapshot, history_entry
from .types import Anchor, Best, DataSet, RefineJob, ValidationJob, Verdict, best_from

log = logging.getLogger("siva.service.worker")


class SystemWorker:
    """Owns one system's trainer, data feed and monitor (in its own threads)."""

    def __init__(self, name: str, structure: Structure, store: Store, settings: Settings,
                 events: Any | None = None, *,
                 trainer_factory: Callable[[Structure, Settings], Any] | None = None) -> None:
        self.name = name
        self.structure = structure
        self.store = store
        self.settings = settings
        self.events = events
        self._factory = trainer_factory or default_trainer
        self.feed = DataFeed(name, structure, store, settings)
        self.history = EstimateHistory(settings.history_limit)
        self.monitoring = Monitoring(name, structure, store, settings)
        REFINE_LOCK.monitor_fits = settings.monitor_fits  # the process's setting
        self.monitor = self.monitoring.monitor
        self._snap_lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._dirty = threading.Event()
        self._dirty.set()
        self._thread = threading.Thread(target=self._run, name=f"siva-trainer-{name}", daemon=True)
        self._refiner = (Refiner(name, structure, on_best=self._set_best,
                                 on_anchor=self._set_anchor, on_verdicts=self._set_verdicts,
                                 on_error=self._set_best_error,
                                 headline_theta=self._headline_theta, step=self._monitor_step)
                         if settings.refine_every_s > 0 else None)
        # typed state shared with the refiner thread (each a frozen value, swapped whole)
        self.data: DataSet | None = None          # the data set the trainer uses
        self.anchor: Anchor | None = None         # the output-error phase's anchor
        self._pending_anchor: Anchor | None = None
        self._best: Best | None = None            # the first recommend_best
        self._best_error: str | None = None
        self._best_job_at: tuple[int, float] | None = None  # (data version, monotonic)
        self._anchor_job_version = 0              # data version of the last anchor job
        self._verdicts: tuple[Verdict | None, Verdict | None] = (None, None)
        self._validation_key: tuple[Any, ...] | None = None
        self._last_final: dict[str, Any] | None = None  # last final ensemble (JSON)
        self._idle_since_epoch: int | None = None
        self._data_epoch = 0
        self.trainer: Any = None
        self.epoch = 0
        self.checkpoint_epoch: int | None = None
        self.checkpoint_error: str | None = None
        self.heartbeat = time.monotonic()
        self._last_log: Any = None
        self._state = "starting"
        self._error: str | None = None
        self._epoch_times: list[float] = []
        self._new_epochs = 0
        self._published_at = time.monotonic()
        self._snapshot: dict[str, Any] = base_snapshot(name, self._state)
        self._drift_report: dict[str, Any] = self._report()

    # ------------------------------------------------------------------ compatibility
    @property
    def buffer(self) -> Any:
        return self.feed.buffer

    @property
    def rejected(self) -> dict[str, str]:
        return self.feed.rejected

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
        t = self._thread
        return t.ident is not None and not t.is_alive() and not self._stop.is_set()

    @property
    def error(self) -> str | None:
        return self._error

    def problem(self) -> str | None:
        return None

    def snapshot(self) -> dict[str, Any]:
        """The latest published snapshot (immutable by convention: never mutated)."""
        return self._snapshot

    def drift_report(self) -> dict[str, Any]:
        return self._drift_report

    def reset_drift(self) -> dict[str, Any]:
        """Forget baseline and alarms (after a repair): the next records form a new baseline."""
        self.monitoring.reset(self.epoch)
        with self._snap_lock:
            self._refresh_snapshot()
        return self._drift_report

    def _report(self) -> dict[str, Any]:
        view = self.monitoring.view
        snap = getattr(self, "_snapshot", {}) or {}
        return {**view["report"], "headline": {
                    "parameters": snap.get("parameters", {}),
                    "estimate_source": snap.get("estimate_source"),
                    "estimate": snap.get("estimate"), "modal": snap.get("modal"),
                    "validation": snap.get("validation")},
                "history": self.history.last()}

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
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
                except SystemDeleted:
                    self._stop.set()
                    break
                except Exception as exc:  # noqa: BLE001
                    log.exception("%s: data refresh failed", self.name)
                    self._fail(f"data refresh failed: {type(exc).__name__}: {exc}")
                    self._stop.wait(5.0)
                    self._dirty.set()
                    continue
            if not self.feed.ready or self.data is None:
                self._state = ("waiting_for_data" if not self.feed.train_ids
                               else "waiting_for_validation")
                if self._snapshot.get("state") != self._state:
                    self._publish()
                self._wake.wait(self.settings.idle_sleep_s)
                self._wake.clear()
                continue
            self._apply_pending_anchor()
            # a per-record fit of any system goes first (priority.py), within a bound
            REFINE_LOCK.yield_to_monitoring(self.settings.monitor_yield_s, self._stop)
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
            self._new_epochs += 1
            self._state = "converged" if self.trainer.converged else "training"
            if self._snapshot_due():
                self._publish(observe=True)
                self._offer_best()
                self._offer_validation()
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
                if self._new_epochs:
                    self._publish(observe=True)
                self._checkpoint()
            except Exception:  # noqa: BLE001
                log.exception("%s: final checkpoint failed", self.name)

    def _snapshot_due(self) -> bool:
        s = self.settings
        if self._new_epochs >= s.snapshot_every:
            return True
        return bool(self._new_epochs) and s.snapshot_max_interval_s > 0 and (
            time.monotonic() - self._published_at >= s.snapshot_max_interval_s)

    def _ensemble_final(self) -> bool:
        tr = self.trainer
        if tr is None or not tr.converged:
            return False
        if output_error_wanted(tr) and self._refiner is not None:
            return getattr(tr, "oe", None) is not None and self._pending_anchor is None and (
                self.anchor is not None and self.data is not None
                and self.anchor.data.version == self.data.version
                and len(tr.ensemble) >= ENSEMBLE_MIN_SAMPLES)
        return True

    def _should_idle(self) -> bool:
        """The ensemble is final on the current data, ``idle_after_epochs`` epochs have
        passed on it and the first ``best`` exists: more epochs would only re-sample the
        same posterior."""
        n = self.settings.idle_after_epochs
        tr = self.trainer
        if n <= 0 or tr is None or self._dirty.is_set() or not self._ensemble_final():
            return False
        if self._idle_since_epoch is None:
            self._idle_since_epoch = int(tr.epoch)
        due = int(tr.epoch) - max(self._idle_since_epoch, self._data_epoch) >= n
        return due and (self._refiner is None or self._best is not None)

    def _idle(self) -> None:
        self._state = "idle"
        self._publish(observe=bool(self._new_epochs))
        self._checkpoint()
        log.info("%s: idle at epoch %d (ensemble final, data unchanged); resumes on new data",
                 self.name, self.epoch)
        while not self._stop.is_set() and not self._dirty.is_set():
            self.heartbeat = time.monotonic()
            self._wake.wait(10.0)
            self._wake.clear()
            if self._pending_anchor is not None:
                break  # a re-anchor (or the validation) arrived: train on it
        self._idle_since_epoch = None
        self._state = "converged"

    # ------------------------------------------------------------------ setup / checkpoint
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
                    self.history.load_state_dict(ckpt.get("drift", {}))
                    self.monitoring.load_state_dict(ckpt.get("monitor", {}),
                                                    int(self.trainer.epoch))
                    self._best = best_from(ckpt.get("best"))
                    self._resume_anchor = ckpt.get("anchor")
                except Exception:  # noqa: BLE001 - e.g. a trainer of another version
                    log.exception("%s: checkpoint unusable; training starts over", self.name)
                    self.trainer = self._factory(self.structure, self.settings)
                    self.history.load_state_dict({})
                    self._resume_anchor = None
                else:
                    self.epoch = int(self.trainer.epoch)
                    self.checkpoint_epoch = self.epoch
                    log.info("%s: resumed from checkpoint at epoch %d", self.name, self.epoch)
        self._error = None
        self._state = "starting"
        self._publish()

    def _restore_anchor(self, ds: DataSet | None) -> bool:
        """After a restart in the output-error phase: the checkpoint's anchor, recomputed
        (deterministic) on its records, so training continues exactly.  True when it was
        made on the data set ``ds`` (no re-anchoring needed)."""
        rec = getattr(self, "_resume_anchor", None)
        self._resume_anchor = None
        if not rec or self.trainer is None or getattr(self.trainer, "oe", None) is not None:
            return False
        ids = list(rec["train"]) + list(rec["validation"])
        if any(i not in self.feed.recs for i in ids):
            log.warning("%s: the checkpoint's anchor records are gone; re-anchoring", self.name)
            return False
        same = ds is not None and (ds.train, ds.validation) == (tuple(rec["train"]),
                                                                  tuple(rec["validation"]))
        data = DataSet(ds.version if same and ds is not None else 0, int(self.trainer.epoch),
                       tuple(rec["train"]), tuple(rec["validation"]),
                       processing_from(rec.get("processing")))
        anchor = build_anchor(self.structure, np.asarray(rec["theta"], dtype=float), data,
                              self.feed.records(data.train), self.feed.records(data.validation),
                              source=str(rec.get("source")), n_noise=int(rec["n_noise"]),
                              seed=int(rec["seed"]))
        apply_anchor(self.trainer, anchor, resume=True)
        self.anchor = anchor
        self._log_anchor(anchor, resume=True)
        return same

    def _checkpoint(self) -> None:
        if self.trainer is None:
            return
        extra = {"monitor": self.monitoring.state_dict(),
                 "best": None if self._best is None else self._best.to_json(),
                 "anchor": None if self.anchor is None else anchor_record(self.anchor)}
        position = getattr(self.events, "position", None)
        if position is not None:  # which log explains this state (service/reconcile.py)
            try:
                extra["log"] = position(self.name)
            except Exception:  # noqa: BLE001 - an audit aid, never a reason not to checkpoint
                pass
        state = checkpoint_state(self.structure.spec, self.trainer, self.history,
                                 self.feed.train_ids, self.feed.val_ids, extra)
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

    def _trim_history(self) -> None:
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
        ds = self.feed.refresh(int(self.trainer.epoch),
                               force=getattr(self.trainer, "train", None) is None)
        restored = bool(getattr(self, "_resume_anchor", None)) and self._restore_anchor(ds)
        if ds is None:
            return
        self.trainer.set_data(self.feed.train_states(), self.feed.val_states())
        self.data = ds
        self._data_epoch = int(self.trainer.epoch)
        if self.events is not None:
            self.events.log_dataset(self.name, int(self.trainer.epoch), list(ds.train),
                                    list(ds.validation), processing=ds.processing)
        if self._refiner is not None and not restored and (self.anchor is not None
                                                           or self._pending_anchor is not None):
            # re-anchor at the headline once the refiner has fitted the new records
            self._anchor_job_version = ds.version
            self._refiner.submit(self._job("anchor", ds))

    def _job(self, kind: str, ds: DataSet, **kw: Any) -> RefineJob:
        tr = self.trainer
        return RefineJob(kind=kind, data=ds, epoch=int(tr.epoch),  # type: ignore[arg-type]
                         train_records=self.feed.records(ds.train),
                         val_records=self.feed.records(ds.validation),
                         n_noise=int(getattr(tr.settings, "oe_noise", 0)),
                         seed=int(getattr(tr.settings, "seed", 0)),
                         anchor=output_error_wanted(tr), **kw)

    # ------------------------------------------------------------------ anchors (phase 2)
    def _set_anchor(self, anchor: Anchor) -> None:
        """Refiner thread: hand the trainer thread a new anchor (applied between epochs)."""
        self._pending_anchor = anchor
        self._wake.set()

    def _apply_pending_anchor(self) -> None:
        anchor, self._pending_anchor = self._pending_anchor, None
        if anchor is None or self.trainer is None:
            return
        if self.anchor is not None and anchor.data.version <= self.anchor.data.version:
            return  # not newer than the one in use
        # (an anchor on a data set that has since grown is still applied: it is newer than
        # the one in use, and the re-anchor on the newest records is already queued)
        self._log_anchor(anchor)
        apply_anchor(self.trainer, anchor)
        self.anchor = anchor
        self._data_epoch = int(self.trainer.epoch)
        if (self.data is not None and anchor.data.version < self.data.version
                and self._refiner is not None and self._anchor_job_version < self.data.version):
            # the data changed while the first anchor was computed: re-anchor on them
            self._anchor_job_version = self.data.version
            self._refiner.submit(self._job("anchor", self.data))
        log.info("%s: output-error phase anchored (%s, data version %d) at epoch %d",
                 self.name, anchor.source, anchor.data.version, self.trainer.epoch)

    def _log_anchor(self, anchor: Anchor, resume: bool = False) -> None:
        if self.events is None or not hasattr(self.events, "log_anchor"):
            return
        try:
            self.events.log_anchor(self.name, int(self.trainer.epoch), anchor_record(anchor),
                                   resume=resume)
        except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
            log.exception("%s: event log failed", self.name)

    def _headline_theta(self) -> np.ndarray | None:
        """Refiner thread: the current headline (per-record fits), else the first best."""
        best = self._current_best()
        if best is None:
            return None
        return best.theta(self.structure.free)

    # ------------------------------------------------------------------ best (refiner)
    def _offer_best(self) -> None:
        """Trainer thread: hand the refiner the first ``best`` job once the equation-error
        phase has converged (cheap: copies only)."""
        tr = self.trainer
        if self._refiner is None or tr is None or not tr.converged or self.data is None:
            return
        if self._best is not None or self.monitor.ready:
            return  # from now on the per-record fits carry the headline
        now = time.monotonic()
        last = self._best_job_at
        if last is not None and (last[0] == self.data.version
                                 or now - last[1] < self.settings.refine_every_s):
            return
        samples = candidates(tr, self._data_epoch)
        if samples is None:
            return
        ds = self.data
        refine_ids = ds.train[-self.settings.refine_max_records:]
        self._best_job_at = (ds.version, now)
        self._anchor_job_version = ds.version
        self._refiner.submit(self._job("best", ds, candidates=samples[-self.settings.refine_candidates:],
                                       refine_records=self.feed.records(refine_ids)))

    def _set_best(self, best: Best, job: RefineJob) -> None:
        """Refiner thread: the first ``best``; it seeds the per-record monitor."""
        with self._snap_lock:
            self._best = best
            self._best_error = None
            proc = job.data.processing if job.data.processing is not None else Processing()
            self.monitoring.seed(best.theta(self.structure.free), proc)
            self._refresh_snapshot()

    def _set_best_error(self, message: str) -> None:
        self._best_error = message

    def _current_best(self) -> Best | None:
        """The monitor's headline once it has one, else the first ``best``."""
        return best_from(self.monitoring.view.get("best")) or self._best

    # ------------------------------------------------------------------ validation
    def _offer_validation(self) -> None:
        """Trainer thread: validate the headline and the ensemble once both exist on this
        data set (again when the headline or the anchor changed)."""
        if self._refiner is None or self.data is None:
            return
        best = self._current_best()
        if best is None:
            return
        ens = read_ensemble(self.structure, self.trainer)
        final = self._ensemble_final()
        if not final and output_error_wanted(self.trainer):
            return  # wait for the ensemble to be final on this anchor (one job, both tests)
        theta_h = best.theta(self.structure.free)
        theta_e = (np.array([ens.parameters[p]["mean"] for p in self.structure.free])
                   if ens.parameters else None)
        key = (self.data.version, tuple(np.round(theta_h, 12)),
               None if self.anchor is None else self.anchor.data.version)
        if key == self._validation_key:
            return
        self._validation_key = key
        self._refiner.submit_validation(ValidationJob(
            self.data, self.feed.records(self.data.validation), theta_h, theta_e, key))

    def _set_verdicts(self, job: ValidationJob, headline: Verdict | None,
                      ensemble: Verdict | None) -> None:
        with self._snap_lock:
            self._verdicts = (headline, ensemble)
            self._refresh_snapshot()
        if self.events is not None:
            try:
                self.events.log_snapshot(self.name, estimate_view(self._snapshot, self._counts()))
            except Exception:  # noqa: BLE001
                log.exception("%s: event log failed", self.name)

    # ------------------------------------------------------------------ snapshots
    def _parts(self, ens: EnsembleReadout | None) -> SnapshotParts:
        tr = self.trainer
        return SnapshotParts(
            system=self.name, state=self._state, epoch=self.epoch, error=self._error,
            structure=self.structure, trainer=tr, ensemble=ens,
            best=self._current_best(), first_best=self._best, best_error=self._best_error,
            monitor_view=self.monitoring.view, anchor=self.anchor, data=self.data,
            train_ids=tuple(self.feed.train_ids), val_ids=tuple(self.feed.val_ids),
            train_samples=self.feed.samples(self.feed.train_ids),
            validation_samples=self.feed.samples(self.feed.val_ids),
            processing=self.feed.processing, rejected=self.feed.problems(),
            verdicts=self._verdicts, last_final=self._last_final,
            checkpoint_epoch=self.checkpoint_epoch,
            seconds_per_epoch=float(np.mean(self._epoch_times)) if self._epoch_times else None,
            last_log=self._last_log, ensemble_final=self._ensemble_final())

    def _publish(self, observe: bool = False) -> None:
        self._published_at = time.monotonic()
        self._new_epochs = 0
        tr = self.trainer
        ens = None
        if tr is not None:
            try:
                ens = read_ensemble(self.structure, tr)
            except Exception:  # noqa: BLE001 - a read-out must not kill training
                log.exception("%s: reading the ensemble failed", self.name)
        with self._snap_lock:
            snap = build_snapshot(self._parts(ens))
            if snap.get("ensemble_state") == "final":
                self._last_final = {"parameters": snap.get("ensemble"), "epoch": snap["epoch"],
                                    "data_version": None if self.data is None else self.data.version}
            self._snapshot = snap
            if observe and tr is not None:
                self.history.add(history_entry(snap))
            self._drift_report = self._report()
        if self.events is not None and observe:
            try:
                self.events.log_snapshot(self.name, estimate_view(snap, self._counts()))
            except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
                log.exception("%s: event log failed", self.name)

    def _refresh_snapshot(self) -> None:
        """Refiner thread (under ``_snap_lock``): the headline keys follow a new ``best``,
        verdict or alarm at once, even while the trainer is idle; the ensemble part is the
        last published one (the trainer's state is not read from this thread)."""
        old = self._snapshot
        parts = self._parts(None)
        snap = build_snapshot(parts, previous=old)
        self._snapshot = snap
        self._drift_report = self._report()

    # ------------------------------------------------------------------ monitoring
    def _monitor_step(self) -> bool:
        """Refiner thread: one per-record fit (``monitoring.py``); False when none is due."""
        changes = self.monitoring.step(self.epoch, self._stop)
        if changes is None:
            return False
        for a in changes:
            log.warning("%s: drift alarm %s: %s", self.name, a["state"], a["message"])
        with self._snap_lock:
            self.monitoring.update_view(self.epoch)
            self._refresh_snapshot()
        if changes and self.events is not None:
            try:
                self.events.log_snapshot(self.name, estimate_view(self._snapshot, self._counts()))
            except Exception:  # noqa: BLE001
                log.exception("%s: event log failed", self.name)
        self._wake.set()  # the trainer may validate the new headline
        return True

    def _counts(self) -> dict[str, int]:
        try:
            return self.store.counts(self.name)
        except UnknownSystem:
            return {"train": 0, "validation": 0}


