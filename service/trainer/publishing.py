"""What the worker publishes: the immutable snapshot (swapped whole, read without a lock),
the drift report, the snapshot events of the log, and the per-record monitoring step that
updates them.  A part of :class:`~service.trainer.worker.SystemWorker`."""
from __future__ import annotations

import logging
import time

import numpy as np

from ..errors import UnknownSystem
from .published import DriftReport, Snapshot
from .readout import EnsembleReadout, read_ensemble
from .snapshot import SnapshotParts, build_snapshot, history_entry

log = logging.getLogger("siva.service.worker")


class Publishing:
    """SystemWorker's snapshots and drift report (mixin: the state is the worker's)."""

    def snapshot(self) -> Snapshot:
        """The latest published snapshot (frozen: read without a lock)."""
        return self._snapshot

    def drift_report(self) -> DriftReport:
        return self._drift_report

    def reset_drift(self) -> DriftReport:
        """Forget baseline and alarms (after a repair): the next records form a new baseline."""
        self.monitoring.reset(self.epoch)
        with self._snap_lock:
            self._refresh_snapshot()
        return self._drift_report

    def _report(self) -> DriftReport:
        r = self.monitoring.view.report  # the monitor's report, JSON-safe
        snap: Snapshot | None = getattr(self, "_snapshot", None)
        return DriftReport(
            rule=r.rule, reference=r.reference, young_baseline=r.young_baseline,
            n_records=r.n_records, alarms=r.alarms, active_alarms=r.active_alarms,
            alarm_history=r.alarm_history, records=r.records, failures=dict(r.failures),
            seconds_per_record=r.seconds_per_record, processed_index=r.processed_index,
            headline={"parameters": {}, "estimate_source": None, "estimate": None,
                      "modal": None, "validation": None} if snap is None else {
                      "parameters": snap.parameters, "estimate_source": snap.estimate_source,
                      "estimate": snap.estimate, "modal": snap.modal,
                      "validation": snap.validation},
            history=self.history.last())

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
            if snap.ensemble_state == "final":
                self._last_final = {"parameters": snap.ensemble, "epoch": snap.epoch,
                                    "data_version": None if self.data is None else self.data.version}
            self._snapshot = snap
            if observe and tr is not None:
                self.history.add(history_entry(snap))
            self._drift_report = self._report()
        if self.events is not None and observe:
            try:
                self.events.log_snapshot(self.name, snap.to_json(self._counts()))
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
            log.warning("%s: drift alarm %s: %s", self.name, a.state, a.message)
        with self._snap_lock:
            self.monitoring.update_view(self.epoch)
            self._refresh_snapshot()
        if changes and self.events is not None:
            try:
                self.events.log_snapshot(self.name,
                                        self._snapshot.to_json(self._counts()))
            except Exception:  # noqa: BLE001
                log.exception("%s: event log failed", self.name)
        self._wake.set()  # the trainer may validate the new headline
        return True

    def _counts(self) -> dict[str, int]:
        try:
            return self.store.counts(self.name)
        except UnknownSystem:
            return {"train": 0, "validation": 0}
