"""The worker's two phases as the trainer thread sees them: hand the refiner the first
``best`` job, apply the anchors it returns (equation error -> output error), and have the
headline and the ensemble validated.  A part of :class:`~service.trainer.worker.SystemWorker`."""
from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from siva_core import Processing

from .anchoring import anchor_record, apply_anchor
from .readout import candidates, output_error_wanted, read_ensemble
from .types import (Anchor, Best, DataSet, RefineJob, ValidationJob, Verdict,
                    best_from_headline)

log = logging.getLogger("siva.service.worker")


class PhaseSteps:
    """SystemWorker's phase steps (mixin: the state is the worker's, see worker.py)."""

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
        view = self.monitoring.view
        return best_from_headline(view.headline, view.epoch) or self._best

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
                self.events.log_snapshot(self.name,
                                        self._snapshot.to_json(self._counts()))
            except Exception:  # noqa: BLE001
                log.exception("%s: event log failed", self.name)
