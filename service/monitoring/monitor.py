"""Per-record monitoring: one output-error fit per record, the headline estimate, drift.

Why here and not in the trainer: the headline a monitoring user acts on must be unbiased
and available while records stream, and a drift test needs the scatter across records.
Both come from the same per-record fits (``record_fit.fit_record``), warm-started from the
headline, which the refiner thread runs once per new record - never again on unchanged
data, so an idle system costs nothing.

Headline (``parameters`` of the estimate once available, ``estimate_source = "best"``):
per parameter, the precision-weighted mean of the per-record estimates over the last
``window`` records since the latest change point of an active (or cleared) alarm; its
standard error is the larger of the weighted one (per-record errors scaled by the
baseline's calibration) and the scatter of the window's estimates / sqrt(n); the 95 %
interval uses Student's t with n - 1 degrees of freedom.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import asdict
from typing import Any, Mapping, Sequence

import numpy as np

from siva_core import Processing, Recording, Structure

from .detector import ChangeDetector, DetectorSettings
from .monitor_values import (AlarmChange, HeadlineEstimate, MonitorReport, MonitorSummary,
                             MonitorView)
from .record_fit import RECORD_MAX_NFEV, RecordFit, fit_record, modal_names, modal_values

#: per-record fits kept in memory (the detector keeps its own bounded series)
FITS_KEPT = 500


class RecordMonitor:
    """Per-record fits -> detector and headline.  Not thread-safe: one thread feeds it
    (the refiner); readers take the frozen values of ``headline``/``report``/``view``."""

    def __init__(self, structure: Structure, settings: DetectorSettings | None = None, *,
                 window: int = 8, max_nfev: int = RECORD_MAX_NFEV,
                 max_records: int = 2000) -> None:
        self.structure = structure
        self.settings = settings or DetectorSettings()
        self.window = max(1, int(window))
        self.max_nfev = max_nfev
        self.max_records = max_records
        self.processing: Processing | None = None
        self.theta0: np.ndarray | None = None        # warm start: the latest headline
        self.detector: ChangeDetector | None = None
        self.fits: deque[dict[str, Any]] = deque(maxlen=FITS_KEPT)
        self.processed_index = -1                   # highest store index handled
        self.failures: dict[str, str] = {}
        self.past_alarms: list[dict[str, Any]] = []  # alarms of baselines before a reset
        self._headline: HeadlineEstimate | None = None

    # ------------------------------------------------------------------ setup
    @property
    def ready(self) -> bool:
        return self.theta0 is not None and self.processing is not None

    def seed(self, theta: Sequence[float], processing: Processing) -> None:
        """Start from the first ``best`` (recommend_best) and the chain it was fitted with;
        the chain stays fixed so that every record is processed the same way."""
        self.theta0 = np.asarray(theta, dtype=float).copy()
        if self.processing is None:
            self.processing = processing
        if self.detector is None:
            self.detector = self._new_detector()

    def _new_detector(self) -> ChangeDetector:
        free = list(self.structure.free)
        modal, _ = modal_values(self.structure, self.theta0)
        names = free + [n for n in modal_names(len(modal) // 2) if n in modal]
        kinds = {q: ("parameter" if q in free else "modal") for q in names}
        return ChangeDetector(names, self.settings, kinds, max_records=self.max_records)

    def reset(self) -> None:
        """``POST .../drift/reset``: a new baseline from the next records; the headline
        window restarts there too (the structure was repaired or deliberately changed)."""
        if self.detector is not None:
            for a in self.detector.alarms:
                self.past_alarms.append({**a, "active": False, "reset_before_index":
                                         self.processed_index + 1})
            del self.past_alarms[:-FITS_KEPT]
            self.detector.reset()
        self._reset_index = self.processed_index + 1

    # ------------------------------------------------------------------ one record
    def process(self, rid: str, index: int, record: Recording, received_at: float | None = None,
                epoch: int | None = None) -> tuple[AlarmChange, ...]:
        """Fit one record, feed the detector, update the headline; returns the alarms that
        changed state (each alarm records the trainer ``epoch`` of its new state)."""
        assert self.ready, "seed() first"
        self.processed_index = max(self.processed_index, int(index))
        try:
            fit = fit_record(self.structure, self.theta0, record, self.processing,
                             max_nfev=self.max_nfev)
        except Exception as exc:  # noqa: BLE001 - one unusable record must not stop monitoring
            self.failures[rid] = f"{type(exc).__name__}: {exc}"
            del_oldest(self.failures, FITS_KEPT)
            fit = None
        ok = fit is not None and fit.success is not False and bool(np.all(np.isfinite(fit.theta)))
        entry = {"id": rid, "index": int(index), "time": received_at or time.time(), "ok": ok}
        if fit is not None:
            entry.update(_fit_entry(self.structure, fit))
        self.fits.append(entry)
        values: dict[str, float | None] = {}
        errors: dict[str, float | None] = {}
        if ok:
            values.update(entry["parameters"])
            errors.update(entry.get("se") or {})
            values.update(entry["modal"])
            errors.update(entry["modal_se"])
        changes = self.detector.observe(entry, values, errors) if self.detector else []
        if epoch is not None:
            for a in changes:
                a.setdefault(f"epoch_{a['state']}", epoch)
                a.setdefault("epoch", epoch)
        if ok:
            self._headline = self._compute_headline()
            if self._headline is not None:
                self.theta0 = np.array([self._headline.mean(p) for p in self.structure.free],
                                       dtype=float)
        return tuple(AlarmChange.of(a) for a in changes)

    # ------------------------------------------------------------------ headline
    def _window_start(self) -> int:
        start = getattr(self, "_reset_index", -1)
        for a in (self.detector.alarms if self.detector else []):
            cp = a.get("change_point") or {}
            if a["active"] and cp.get("record_index") is not None:
                start = max(start, int(cp["record_index"]))
            elif a["state"] == "cleared" and a.get("confirmed_record") is not None:
                start = max(start, int(a.get("cleared_index", -1)) - self.settings.clear_records + 1)
        return start

    def _compute_headline(self) -> HeadlineEstimate | None:
        start = self._window_start()
        fits = [f for f in self.fits if f["ok"] and f["index"] >= start][-self.window:]
        if not fits:
            return None
        base = (self.detector.baseline or {}).get("quantities", {}) if self.detector else {}
        params: dict[str, Any] = {}
        for p in self.structure.free:
            x = np.array([f["parameters"][p] for f in fits], dtype=float)
            se = np.array([(f.get("se") or {}).get(p) or np.nan for f in fits], dtype=float)
            calib = (base.get(p) or {}).get("se_calibration") or 1.0
            params[p] = combine(x, se * calib)
        theta = [params[p]["mean"] for p in self.structure.free]
        modal, _ = modal_values(self.structure, np.asarray(theta, dtype=float))
        return HeadlineEstimate(
            parameters=params, modal=modal, records=tuple(f["id"] for f in fits),
            n_records=len(fits), first_index=fits[0]["index"], last_index=fits[-1]["index"],
            time=time.time(),
            method=f"precision-weighted mean of per-record output-error fits over the "
                   f"last {len(fits)} record(s) since the latest change")

    def headline(self) -> HeadlineEstimate | None:
        return self._headline

    # ------------------------------------------------------------------ read-out
    def report(self, limit: int | None = None) -> MonitorReport:
        det = self.detector.report() if self.detector else {
            "rule": {**asdict(self.settings), "threshold_h": None, "quantities": None,
                     "false_alarms_per_1000_records_nominal": 1000.0 / self.settings.arl0_records,
                     "note": "the detector starts with the first best (the monitored "
                             "quantities are known then)"},
            "reference": None, "n_records": 0, "alarms": [], "active_alarms": []}
        fits = list(self.fits)[-limit:] if limit else list(self.fits)
        seconds = [f["seconds"] for f in fits if f.get("seconds") is not None]
        return MonitorReport(
            rule=det["rule"], reference=det["reference"],
            young_baseline=det.get("young_baseline"), n_records=int(det["n_records"]),
            alarms=tuple(det["alarms"]), active_alarms=tuple(det["active_alarms"]),
            alarm_history=tuple(self.past_alarms + det["alarms"]), records=tuple(fits),
            failures=dict(self.failures),
            seconds_per_record=float(np.mean(seconds)) if seconds else None,
            processed_index=self.processed_index)

    def view(self, epoch: int, limit: int | None = None) -> MonitorView:
        """What readers get: the drift ``report``, the headline (the estimate's ``best``
        from ``epoch``; None before the first per-record fit) and a ``summary``."""
        report = self.report(limit=limit)
        summary = MonitorSummary(
            records_fitted=len(self.fits), processed_index=self.processed_index,
            baseline=(report.reference or {}).get("n_records"),
            seconds_per_record=report.seconds_per_record, active_alarms=report.active_alarms)
        return MonitorView(report=report, headline=self._headline, epoch=epoch,
                           summary=summary)

    def state_dict(self) -> dict[str, Any]:
        return {"theta0": None if self.theta0 is None else self.theta0.tolist(),
                "processing": self.processing, "fits": list(self.fits),
                "processed_index": self.processed_index, "headline": None if self._headline is None else self._headline.to_json(),
                "detector": self.detector.state_dict() if self.detector else None,
                "reset_index": getattr(self, "_reset_index", -1),
                "past_alarms": self.past_alarms}

    def load_state_dict(self, d: Mapping[str, Any]) -> None:
        if not d:
            return
        if d.get("theta0") is not None:
            self.theta0 = np.asarray(d["theta0"], dtype=float)
        self.processing = d.get("processing") or self.processing
        self.fits = deque(d.get("fits", []), maxlen=FITS_KEPT)
        self.processed_index = int(d.get("processed_index", -1))
        hl = d.get("headline")
        self._headline = HeadlineEstimate.from_json(hl) if hl else None
        self._reset_index = int(d.get("reset_index", -1))
        self.past_alarms = list(d.get("past_alarms", []))
        if self.theta0 is not None:
            self.detector = self._new_detector()
            self.detector.load_state_dict(d.get("detector") or {})


def del_oldest(d: dict[str, Any], keep: int) -> None:
    """Bound a dict kept in insertion order to its ``keep`` newest entries."""
    for key in list(d)[:-keep]:
        del d[key]


def combine(x: np.ndarray, se: np.ndarray) -> dict[str, Any]:
    """Precision-weighted mean of per-record estimates with an honest interval (see the
    module docstring); records without an error get the median error."""
    from scipy import stats

    n = len(x)
    se = np.where(np.isfinite(se) & (se > 0), se, np.nan)
    if np.all(np.isnan(se)):
        se = np.full(n, np.nan)
        w = np.ones(n)
    else:
        se = np.where(np.isnan(se), np.nanmedian(se), se)
        w = 1.0 / se ** 2
    mean = float(np.sum(w * x) / np.sum(w))
    weighted = float(math.sqrt(1.0 / np.sum(w))) if np.all(np.isfinite(se)) else 0.0
    empirical = float(np.std(x, ddof=1) / math.sqrt(n)) if n >= 2 else 0.0
    std = max(weighted, empirical)
    q = float(stats.t.ppf(0.975, n - 1)) if n >= 2 and empirical >= weighted else 1.96
    if std == 0.0:
        return {"mean": mean, "std": None, "ci95": None, "n": n}
    return {"mean": mean, "std": std, "ci95": [mean - q * std, mean + q * std], "n": n}


def _fit_entry(structure: Structure, fit: RecordFit) -> dict[str, Any]:
    free = structure.free
    return {"parameters": {p: float(fit.theta[k]) for k, p in enumerate(free)},
            "se": None if fit.se is None else {p: float(fit.se[k]) for k, p in enumerate(free)},
            "modal": dict(fit.modal), "modal_se": dict(fit.modal_se),
            "cost": fit.cost, "nfev": fit.nfev, "seconds": fit.seconds,
            "force_scale": fit.force_scale}
