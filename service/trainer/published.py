"""The values a trainer publishes to the rest of the service: the snapshot, frozen.

Why a frozen dataclass: the routes, ``/metrics``, the dashboard, the Ray host's poll and
the event log all read the latest snapshot without a lock while the trainer and refiner
threads publish new ones; a field list says what crosses the seam (no ``dict[str, Any]``
whose keys only the writer knows), and it pickles across the Ray executor.  The JSON bodies
(``GET .../estimate``, the MCAP snapshot event) are built from it at the edge
(:meth:`Snapshot.to_json`); nested values are already plain JSON (NaN as None).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..monitoring.drift import HistoryPoint

#: a JSON object nested in the snapshot (parameters, validation, alarms...): plain types only
JsonObject = dict[str, Any]


@dataclass(frozen=True)
class DataView:
    """``snapshot["data"]``: the records the trainer holds and the processing chain."""

    train: tuple[str, ...]
    validation: tuple[str, ...]
    train_samples: int
    validation_samples: int
    processing: JsonObject | None
    version: int | None
    rejected: dict[str, str]

    def to_json(self) -> dict[str, Any]:
        return {"train": list(self.train), "validation": list(self.validation),
                "train_samples": self.train_samples,
                "validation_samples": self.validation_samples, "processing": self.processing,
                "version": self.version, "rejected": dict(self.rejected)}


@dataclass(frozen=True)
class Snapshot:
    """One published state of a system's trainer (swapped whole, never mutated).

    Blocks that a snapshot may lack are ``None`` and absent from its JSON: the trainer's
    read-out (``ensemble_state`` is None before the first read-out), the headline
    (``estimate`` is None before the first epoch) and the monitoring/data keys (``data`` is
    None in the snapshot a system has before its worker published one).
    """

    system: str
    state: str
    epoch: int = 0
    converged: bool = False
    converged_at: int | None = None
    #: the headline {p: {mean, std, ci95 (not while provisional), n?}}
    parameters: dict[str, JsonObject] = field(default_factory=dict)
    estimate_source: str | None = None
    discriminator: JsonObject = field(default_factory=dict)
    error: str | None = None
    time: float = field(default_factory=time.time)
    # --- the trainer's read-out (present when ensemble_state is not None)
    fixed: dict[str, float] | None = None
    ensemble: dict[str, JsonObject] | None = None     # also with the headline alone
    ensemble_source: str | None = None
    ensemble_state: str | None = None                 # none | provisional | final
    phase: str | None = None
    ensemble_samples: int | None = None
    anchor: JsonObject | None = None
    losses: dict[str, float | None] | None = None
    # --- data and monitoring (present when data is not None)
    data: DataView | None = None
    checkpoint_epoch: int | None = None
    seconds_per_epoch: float | None = None
    ensemble_last_final: JsonObject | None = None
    # --- the headline (present when estimate is not None)
    estimate: JsonObject | None = None
    modal: JsonObject | None = None
    best: JsonObject | None = None
    monitoring: JsonObject | None = None
    alarm_history: tuple[JsonObject, ...] = ()
    best_error: str | None = None
    alarms: tuple[JsonObject, ...] = ()               # the active ones
    drift_status: JsonObject | None = None
    validation: JsonObject | None = None
    model_rejected: bool = False
    provisional: bool = True
    agreement: JsonObject | None = None

    @property
    def read_out(self) -> bool:
        """The trainer's ensemble has been read out into this snapshot."""
        return self.ensemble_state is not None

    def to_json(self, n_recordings: Mapping[str, int] | None = None) -> dict[str, Any]:
        """The snapshot as JSON, keys in the order they were always published; with
        ``n_recordings`` the ``GET .../estimate`` body (the contract's keys first)."""
        out: dict[str, Any] = {
            "system": self.system, "state": self.state, "epoch": self.epoch,
            "converged": self.converged, "converged_at": self.converged_at,
            "parameters": self.parameters, "estimate_source": self.estimate_source,
            "discriminator": self.discriminator, "error": self.error, "time": self.time}
        if self.read_out:
            out["fixed"] = self.fixed
        if self.ensemble is not None:
            out.update(ensemble=self.ensemble, ensemble_source=self.ensemble_source)
        if self.read_out:
            out.update(ensemble_state=self.ensemble_state, phase=self.phase,
                       ensemble_samples=self.ensemble_samples, anchor=self.anchor)
            if self.losses is not None:
                out["losses"] = self.losses
        if self.data is not None:
            out.update(data=self.data.to_json(), checkpoint_epoch=self.checkpoint_epoch)
        if self.seconds_per_epoch is not None:
            out["seconds_per_epoch"] = self.seconds_per_epoch
        if self.ensemble_last_final is not None:
            out["ensemble_last_final"] = self.ensemble_last_final
        if self.estimate is not None:
            out.update(estimate=self.estimate, modal=self.modal, best=self.best,
                       monitoring=self.monitoring, alarm_history=list(self.alarm_history))
        if self.best_error:
            out["best_error"] = self.best_error
        if self.data is not None:
            out.update(alarms=list(self.alarms), drift_status=self.drift_status,
                       validation=self.validation, model_rejected=self.model_rejected)
        out["provisional"] = self.provisional
        if self.data is not None:
            out["agreement"] = self.agreement
        if n_recordings is None:
            return out
        return estimate_body(out, n_recordings)


def estimate_body(snap: Mapping[str, Any], n_recordings: Mapping[str, int]) -> dict[str, Any]:
    """The GET .../estimate body from a snapshot's JSON: the contract's keys first, then
    everything else (also ``siva replay``'s report, built from a logged snapshot)."""
    out = {"parameters": {p: {"mean": s.get("mean"), "std": s.get("std"),
                              "ci95": s.get("ci95"),
                              **{k: v for k, v in s.items() if k not in ("mean", "std", "ci95")}}
                          for p, s in snap.get("parameters", {}).items()},
           "discriminator": snap.get("discriminator", {}),
           "epoch": snap.get("epoch", 0),
           "converged": snap.get("converged", False),
           "n_recordings": {"train": int(n_recordings.get("train", 0)),
                            "validation": int(n_recordings.get("validation", 0))}}
    for k, v in snap.items():
        if k not in out:
            out[k] = v
    return out


@dataclass(frozen=True)
class DriftReport:
    """What ``GET .../drift`` shows of a system: the detector's rule and baseline, its
    alarms, the per-record fits, the headline and the history of published estimates.

    Frozen and swapped whole like the snapshot (read by the routes without a lock, fetched
    from a Ray trainer host on demand); its JSON is built at the edge (:meth:`to_json`).
    """

    rule: JsonObject | None = None
    reference: JsonObject | None = None
    young_baseline: JsonObject | None = None          # None: no detector yet (absent)
    n_records: int = 0
    alarms: tuple[JsonObject, ...] = ()
    active_alarms: tuple[str, ...] = ()
    alarm_history: tuple[JsonObject, ...] = ()
    records: tuple[JsonObject, ...] = ()               # the per-record fits, oldest first
    failures: dict[str, str] = field(default_factory=dict)
    seconds_per_record: float | None = None
    processed_index: int = -1
    headline: JsonObject = field(default_factory=dict)
    history: tuple[HistoryPoint, ...] = ()             # one entry per published snapshot

    def to_json(self, history_limit: int | None = None) -> dict[str, Any]:
        """The report as JSON; ``history_limit``: only the last N history entries."""
        hist = [h.to_json() for h in (self.history if history_limit is None
                                      else self.history[-history_limit:])]
        out: dict[str, Any] = {"rule": self.rule, "reference": self.reference}
        if self.young_baseline is not None:
            out["young_baseline"] = self.young_baseline
        out.update(n_records=self.n_records, alarms=list(self.alarms),
                   active_alarms=list(self.active_alarms),
                   alarm_history=list(self.alarm_history), records=list(self.records),
                   failures=dict(self.failures), seconds_per_record=self.seconds_per_record,
                   processed_index=self.processed_index, headline=self.headline,
                   history=hist)
        return out
