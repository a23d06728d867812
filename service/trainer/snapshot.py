"""Building the published snapshot (the GET .../estimate body) from the trainer's parts.

Why here: the snapshot is the one place where typed values (ensemble read-out, ``Best``,
verdicts, anchor) become the published :class:`~.published.Snapshot`: the worker hands a
frozen :class:`SnapshotParts` and gets a new frozen snapshot back (its JSON, the body the
HTTP contract promises, is built at the edge by ``Snapshot.to_json``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from typing import Any, Mapping

from siva_core import Processing, Structure

from ..monitoring.drift import HistoryPoint, modal_quantities
from ..monitoring.monitor_values import MonitorReport, MonitorView
from .estimate import headline, jsonable
from .published import DataView, Snapshot
from .readout import EnsembleReadout
from .types import Anchor, Best, DataSet, Verdict
from .validation import validation_view

#: keys that come from the trainer (kept as they were when another thread refreshes)
TRAINER_KEYS = ("epoch", "converged", "converged_at", "fixed", "discriminator", "ensemble",
                "ensemble_source", "ensemble_state", "phase", "losses", "anchor",
                "ensemble_samples")
#: |ensemble mean - headline mean| / combined std above which the two are said to differ
AGREE_Z = 3.0


@dataclass(frozen=True)
class SnapshotParts:
    system: str
    state: str
    epoch: int
    error: str | None
    structure: Structure
    trainer: Any
    ensemble: EnsembleReadout | None       # None: keep the previous snapshot's trainer keys
    best: Best | None                       # the headline's source (monitor, else first best)
    first_best: Best | None
    best_error: str | None
    monitor_view: MonitorView
    anchor: Anchor | None
    data: DataSet | None
    train_ids: tuple[str, ...]
    val_ids: tuple[str, ...]
    train_samples: int
    validation_samples: int
    processing: Processing | None
    rejected: Mapping[str, str]
    verdicts: tuple[Verdict | None, Verdict | None]
    last_final: Mapping[str, Any] | None
    checkpoint_epoch: int | None
    seconds_per_epoch: float | None
    last_log: Any
    ensemble_final: bool


def build_snapshot(p: SnapshotParts, previous: Snapshot | None = None) -> Snapshot:
    """The snapshot of ``p``; with ``previous`` and no ensemble read-out in ``p``, the
    trainer's keys are the previous snapshot's (the refiner thread's refresh)."""
    return _typed(_snapshot_json(p, None if previous is None else previous.to_json()))


_FIELDS = tuple(f.name for f in fields(Snapshot))


def _typed(snap: Mapping[str, Any]) -> Snapshot:
    """The frozen snapshot of the assembled JSON (keys a snapshot lacks stay None)."""
    kw = {k: snap[k] for k in _FIELDS if k in snap}
    if "data" in kw:
        d = kw["data"]
        kw["data"] = DataView(tuple(d["train"]), tuple(d["validation"]), d["train_samples"],
                              d["validation_samples"], d["processing"], d["version"],
                              dict(d["rejected"]))
    for k in ("alarms", "alarm_history"):
        if k in kw:
            kw[k] = tuple(kw[k] or ())
    return Snapshot(**kw)


def _snapshot_json(p: SnapshotParts, previous: Mapping[str, Any] | None) -> dict[str, Any]:
    snap: dict[str, Any] = {"system": p.system, "state": p.state, "epoch": p.epoch,
                            "converged": False, "converged_at": None, "parameters": {},
                            "estimate_source": None, "discriminator": {}, "error": p.error,
                            "time": time.time()}
    tr = p.trainer
    if p.ensemble is None and previous is not None:
        snap.update({k: previous[k] for k in TRAINER_KEYS if k in previous})
    elif tr is not None and p.ensemble is not None:
        snap.update(_trainer_keys(p))
    snap["data"] = {"train": list(p.train_ids), "validation": list(p.val_ids),
                    "train_samples": p.train_samples, "validation_samples": p.validation_samples,
                    "processing": jsonable(p.processing) if p.processing is not None else None,
                    "version": None if p.data is None else p.data.version,
                    "rejected": dict(p.rejected)}
    snap["checkpoint_epoch"] = p.checkpoint_epoch
    if p.seconds_per_epoch is not None:
        snap["seconds_per_epoch"] = p.seconds_per_epoch
    if p.last_final is not None:
        snap["ensemble_last_final"] = dict(p.last_final)
    if tr is not None and snap.get("epoch"):
        keys = headline(p.structure, snap.get("ensemble") or {}, snap.get("ensemble_source"),
                        None if p.best is None else p.best.to_json())
        snap.update(keys)
        means = [keys["parameters"].get(q, {}).get("mean") for q in p.structure.free]
        snap["modal"] = (modal_quantities(p.structure, means)
                         if means and all(m is not None for m in means) else None)
        snap["best"] = None if p.best is None else p.best.to_json()
        summary = p.monitor_view.summary
        snap["monitoring"] = None if summary is None else summary.to_json()
        snap["alarm_history"] = list(p.monitor_view.report.alarm_history)
    if p.best_error:
        snap["best_error"] = p.best_error
    snap["alarms"] = [a for a in p.monitor_view.report.alarms if a["active"]]
    snap["drift_status"] = drift_status(p.monitor_view.report)
    head_v, ens_v = p.verdicts
    pending = None
    if head_v is None and ens_v is None:
        pending = ("waiting for the output-error ensemble to converge and for a headline"
                   if tr is not None and snap.get("epoch") else "no training yet")
    snap["validation"] = validation_view(head_v, ens_v, snap.get("discriminator"), pending)
    snap["model_rejected"] = snap["validation"]["verdict"] == "rejected"
    snap["provisional"] = _provisional(snap)
    if snap["provisional"]:
        for v in (snap.get("parameters") or {}).values():
            if isinstance(v, dict):
                v.pop("ci95", None)
    snap["agreement"] = agreement(p.structure, snap, p)
    return jsonable(snap)


def _trainer_keys(p: SnapshotParts) -> dict[str, Any]:
    tr, ens = p.trainer, p.ensemble
    assert ens is not None
    try:
        disc = tr.discriminator_scores() if (p.train_ids and tr.epoch > 0) else {}
    except Exception as exc:  # noqa: BLE001 - a read-out must not kill training
        disc = {"error": f"{type(exc).__name__}: {exc}"}
    out: dict[str, Any] = {
        "epoch": int(tr.epoch), "converged": bool(tr.converged),
        "converged_at": getattr(getattr(tr, "monitor", None), "converged_at", None),
        "fixed": {q: i.fixed for q, i in p.structure.parameters.items()
                  if i.fixed is not None and not q.startswith("_fixed_")},
        "discriminator": disc, "ensemble": ens.to_json(), "ensemble_source": ens.source,
        "ensemble_state": ens.state, "phase": ens.phase, "ensemble_samples": ens.n_samples,
        "anchor": None if p.anchor is None else {
            "theta": p.structure.as_dict(p.anchor.theta), "source": p.anchor.source,
            "data_version": p.anchor.data.version, "train": list(p.anchor.data.train),
            "validation": list(p.anchor.data.validation)}}
    if p.last_log is not None:
        out["losses"] = {"loss_d": p.last_log.loss_d, "loss_adv": p.last_log.loss_adv,
                         "loss_mse": p.last_log.loss_mse}
    return out


def _provisional(snap: Mapping[str, Any]) -> bool:
    """The headline is ``best`` (an output-error fit with a measured interval) or a final
    ensemble; anything else is provisional."""
    if snap.get("estimate_source") == "best":
        return False
    return snap.get("ensemble_state") != "final"


def drift_status(report: MonitorReport) -> dict[str, Any]:
    """Plain words on what the drift test can judge yet."""
    rule = report.rule or {}
    need = rule.get("baseline_records")
    ref = report.reference
    young = report.young_baseline or {}
    n = int(report.n_records or 0)
    if ref:
        return {"status": "monitoring", "baseline_records": ref.get("n_records"),
                "message": f"CUSUM against a baseline of {ref.get('n_records')} records"}
    if n < 3:
        return {"status": "too_short", "records": n, "baseline_records": need,
                "message": f"{n} record(s) fitted: too few to judge a change "
                           f"(a change is tested from the 3rd record; the full baseline "
                           f"needs {need})"}
    return {"status": "forming", "records": n, "baseline_records": need,
            "min_detectable_rel": young.get("min_detectable_rel"),
            "message": f"baseline forming ({n} of {need} records): a change inside it is "
                       "tested record by record (change-point test)"}


def agreement(structure: Structure, snap: Mapping[str, Any], p: SnapshotParts) -> dict[str, Any]:
    """Do the ensemble and the headline agree (|difference| < 3 combined std per
    parameter), and if not, why."""
    if snap.get("estimate_source") != "best":
        return {"status": "n/a", "why": "no output-error headline yet: the headline is the "
                                        "ensemble itself"}
    if snap.get("ensemble_state") != "final":
        return {"status": "pending", "why": "the ensemble is provisional (equation-error "
                                            "phase, or re-converging on new data)"}
    ens, head = snap.get("ensemble") or {}, snap.get("parameters") or {}
    z: dict[str, float | None] = {}
    for q in structure.free:
        e, h = ens.get(q) or {}, head.get(q) or {}
        if e.get("mean") is None or h.get("mean") is None:
            z[q] = None
            continue
        s = math.hypot(e.get("std") or 0.0, h.get("std") or 0.0)
        z[q] = abs(e["mean"] - h["mean"]) / s if s > 0 else None
    worst = max((v for v in z.values() if v is not None), default=0.0)
    if worst <= AGREE_Z:
        return {"status": "agree", "z": z, "max_z": worst,
                "why": f"every parameter within {AGREE_Z:g} combined standard errors"}
    why: list[str] = []
    if snap.get("alarms"):
        why.append("a drift alarm is active: the headline averages the records since the "
                   "change point, the ensemble is anchored on the training buffer")
    head_v, _ = p.verdicts
    if head_v is not None and head_v.verdict == "rejected":
        why.append("validation rejects the model: the ensemble (all training records at "
                   "once) and the per-record fits settle on different compromises of a "
                   "model that cannot explain the data")
    if p.anchor is not None and p.data is not None and p.anchor.data.version < p.data.version:
        why.append("the ensemble's anchor predates the newest records (re-anchoring)")
    if not why:
        why.append("the headline averages per-record output-error fits over its window "
                   f"({', '.join((snap.get('best') or {}).get('records') or [])}); the "
                   "ensemble fits the training buffer jointly "
                   f"({', '.join(p.anchor.data.train) if p.anchor else '?'}): different "
                   "records, or a model that fits them differently")
    return {"status": "differ", "z": z, "max_z": worst, "why": "; ".join(why)}


def history_entry(snap: Snapshot) -> HistoryPoint:
    """One point of the dashboard's traces: the headline and the ensemble with bands."""
    return HistoryPoint(
        epoch=snap.epoch, time=snap.time, converged=snap.converged,
        parameters={q: {k: v.get(k) for k in ("mean", "std", "ci95")}
                    for q, v in (snap.parameters or {}).items()},
        estimate_source=snap.estimate_source,
        ensemble={q: {k: v.get(k) for k in ("mean", "std", "ci95")}
                  for q, v in (snap.ensemble or {}).items()},
        ensemble_state=snap.ensemble_state, modal=snap.modal)
