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

The class is carved into its parts (one module each, over the worker's one state): this
module the state, the control calls and the trainer thread's loop; ``phases.py`` the
phase steps (first ``best``, anchors, validation jobs); ``lifecycle.py`` set-up,
checkpoints and idling; ``publishing.py`` snapshots, the drift report and the monitoring
step.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

from siva_core import Structure

from ..monitoring.drift import EstimateHistory
from ..settings import Settings
from ..storage.store import Store
from .data import DataFeed, SystemDeleted
from .factory import base_snapshot, default_trainer
from .published import DriftReport, Snapshot
from .lifecycle import Lifecycle
from .monitoring import Monitoring
from .phases import PhaseSteps
from .publishing import Publishing
from .refiner import REFINE_LOCK, Refiner
from .types import Anchor, Best, DataSet, Verdict

log = logging.getLogger("siva.service.worker")


class SystemWorker(Lifecycle, PhaseSteps, Publishing):
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
        self._snapshot: Snapshot = base_snapshot(name, self._state)
        self._drift_report: DriftReport = self._report()

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
                if self._snapshot.state != self._state:
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
