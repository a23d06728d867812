"""The worker's lifecycle around training: set-up from a checkpoint, the checkpoint itself,
and idling once the ensemble is final on unchanged data (no CPU until a record arrives).
A part of :class:`~service.trainer.worker.SystemWorker`."""
from __future__ import annotations

import logging
import time

import numpy as np

from ..errors import UnknownSystem
from ..storage.checkpoints import checkpoint_state, matches
from .anchoring import anchor_record, apply_anchor, build_anchor, processing_from
from .readout import ENSEMBLE_MIN_SAMPLES, output_error_wanted
from .types import DataSet, best_from

log = logging.getLogger("siva.service.worker")


class Lifecycle:
    """SystemWorker's set-up, checkpoints and idling (mixin: the state is the worker's)."""

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
                at = position(self.name)
                extra["log"] = None if at is None else {"file": at.file, "datasets": at.datasets}
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
