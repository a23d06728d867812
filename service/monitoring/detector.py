"""Drift detection on per-record estimates: a sequential test with a stated false-alarm rate.

Why per record: every record is an independent measurement of the structure, so one
estimate per record (``record_fit.py``) gives a series whose scatter is the
scatter *across records* - the thing a change has to stand out from.  Testing the trainer's
per-epoch jitter against an ensemble interval (the previous rule) compared two unrelated
scales and raised false alarms on static data.

The test, per monitored quantity (each free parameter and each linear mode's frequency and
damping ratio):

1. **Baseline.** The first ``baseline_records`` records observed (after start-up or after
   ``reset``) fix the reference; afterwards it is *self-starting*: a record joins the
   baseline of a quantity ``baseline_guard`` records later if that quantity is in control
   (no alarm, CUSUM below h/2), up to ``baseline_max`` records, so the error of the centre
   (which a CUSUM would otherwise accumulate like a drift) keeps shrinking.  The baseline
   gives a *centre* and a *scale calibration* ``c``: the robust scatter
   (1.4826 MAD) of the baseline values in units of each record's own standard error,
   at least 1.  A record's scatter is then ``s_i = max(c * se_i, min_rel_scatter * |centre|)``
   (``se_i``: that record's fit standard error; the whole baseline's robust scatter when a
   quantity has none), so a weakly excited record (a light tap) counts for less, and
   changes far below ``min_rel_scatter`` (temperature, mounting) are not what alarms are for.
   The centre is the precision-weighted mean of the baseline records within 4 calibrated
   errors of the median (the median when there are no errors), ``se_c`` its standard error.
2. **Standardised value.** ``z_i = (x_i - centre) / sqrt(s_i^2 + (3 se_c)^2)``, clipped to
   ``+-clip`` so that one bad record cannot raise an alarm alone.  The centre's error is
   the same for every record, so a CUSUM sums it like a real shift: counting it three times
   (``centre_inflation``) keeps that from alarming while the baseline is young.
3. **Two-sided CUSUM.** ``S+ = max(0, S+ + z - k)``, ``S- = max(0, S- - z - k)``; an alarm is
   *raised* when either exceeds ``h``.  ``h`` comes from Siegmund's approximation of the
   in-control average run length (ARL) of a one-sided CUSUM,
   ``ARL = (exp(2kb) - 2kb - 1) / (2k^2)``, ``b = h + 1.166``, solved for a per-side ARL of
   ``2 M arl0_records`` (Bonferroni over the ``M`` quantities and the two sides), so that
   the whole detector's nominal in-control ARL is ``arl0_records`` records, i.e. at most
   ``1000 / arl0_records`` false alarms per 1000 records.  The measured rate is in
   ``benchmarks/bench_monitoring.py``.
4. **States.** raised -> *confirmed* once the CUSUM stays above ``h`` for
   ``confirm_records`` more records; a raised alarm whose CUSUM falls back below ``h``
   first is *cleared* as transient.  A confirmed alarm is *cleared* once the last
   ``clear_records`` values all lie within ``|z| < 2`` (the quantity is back to baseline,
   e.g. after a repair); its CUSUM restarts from 0.
5. **Change point.** At each state change the series of the quantity since the baseline's
   start is segmented with ``ruptures`` (exact dynamic programming, one break, l2 cost on
   the standardised values): the record where it changed, the set of break positions whose
   cost is within the chi-square(1) 95 % quantile of the best (an interval on *when*), and
   the mean change after vs before with a 95 % interval (*by how much*).
"""
from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any, Mapping, Sequence

import numpy as np

from .alarm_text import alarm_message
from .change_point import CHANGE_POINT_WINDOW, change_point, cusum_change
from .cusum import CLEAR_Z, DetectorSettings
from .forming_baseline import YOUNG_MIN_SEGMENT, YOUNG_Z, young_change


class ChangeDetector:
    """Per-quantity CUSUM over per-record estimates, with alarm states and change points."""

    def __init__(self, quantities: Sequence[str], settings: DetectorSettings | None = None,
                 kinds: Mapping[str, str] | None = None, max_records: int = 2000) -> None:
        self.quantities = list(quantities)
        self.max_records = max(50, int(max_records))
        self.kinds = dict(kinds or {})
        self.settings = settings or DetectorSettings()
        self.h = self.settings.threshold(len(self.quantities))
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget baseline, CUSUMs and alarms; the next records form a new baseline."""
        self.records: list[dict[str, Any]] = []      # {"id", "index", "time"} per observation
        self.values: dict[str, list[float | None]] = {q: [] for q in self.quantities}
        self.errors: dict[str, list[float | None]] = {q: [] for q in self.quantities}
        self.z: dict[str, list[float | None]] = {q: [] for q in self.quantities}
        self.baseline: dict[str, Any] | None = None
        self.base: dict[str, list[list[float | None]]] = {q: [] for q in self.quantities}
        self.seen = 0  # records observed since the last reset
        self.cusum: dict[str, list[float]] = {q: [0.0, 0.0] for q in self.quantities}
        self.alarms: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ update
    def observe(self, record: Mapping[str, Any], values: Mapping[str, float | None],
                errors: Mapping[str, float | None] | None = None) -> list[dict[str, Any]]:
        """Add one record's estimates (``values``) and standard errors; returns the alarms
        whose state changed (raised, confirmed or cleared) with this record."""
        errors = errors or {}
        self.records.append({k: record.get(k) for k in ("id", "index", "time")})
        for q in self.quantities:
            self.values[q].append(_finite(values.get(q)))
            self.errors[q].append(_finite(errors.get(q)))
            self.z[q].append(None)
        if len(self.records) > self.max_records:  # bounded memory; the baseline is kept apart
            del self.records[0]
            for d in (self.values, self.errors, self.z):
                for q in self.quantities:
                    del d[q][0]
        n = len(self.records)
        self.seen += 1
        if self.baseline is None:
            for q in self.quantities:
                self.base[q].append([self.values[q][-1], self.errors[q][-1]])
            young = self._young_test()
            if young:
                return young
            if self.seen >= self.settings.baseline_records:
                self.baseline = self._fit_baseline()
                for q in self.quantities:  # baseline values standardised for change points
                    self.z[q] = [self._z(q, i) for i in range(n)]
            return []
        self._extend_baseline()
        changed: list[dict[str, Any]] = []
        for q in self.quantities:
            z = self._z(q, n - 1)
            self.z[q][-1] = z
            if z is None:
                continue
            c = self.cusum[q]
            c[0] = max(0.0, c[0] + z - self.settings.k)
            c[1] = max(0.0, c[1] - z - self.settings.k)
            changed.extend(self._update_alarm(q, n - 1))
        return changed

    # ------------------------------------------------------------------ forming baseline
    def _young_test(self) -> list[dict[str, Any]]:
        """A change *inside* the forming baseline (``forming_baseline.py``): alarms, and the
        baseline restarts with the records after the change."""
        m = len(self.base[self.quantities[0]]) if self.quantities else 0
        found = young_change(self.base, self.records[len(self.records) - m:], self.kinds,
                             self.settings.min_rel_scatter, len(self.alarms) + 1)
        if found is None:
            return []
        t, alarms = found
        self.alarms.extend(alarms)
        for q in self.quantities:
            self.base[q] = self.base[q][t:]
        self.seen = m - t
        return alarms

    def young_report(self) -> dict[str, Any]:
        """What the forming-baseline test can see now (for the drift status)."""
        m = len(self.base[self.quantities[0]]) if self.quantities else 0
        s = self.settings
        detectable = None
        if m >= YOUNG_MIN_SEGMENT + 1:
            nb = max(YOUNG_MIN_SEGMENT, m + 1 - YOUNG_MIN_SEGMENT)
            detectable = YOUNG_Z * s.min_rel_scatter * math.sqrt(1 / nb + 1 / YOUNG_MIN_SEGMENT)
        return {"active": self.baseline is None, "records": m, "threshold_z": YOUNG_Z,
                "min_segment": YOUNG_MIN_SEGMENT, "min_detectable_rel": detectable}

    def _extend_baseline(self) -> None:
        """Self-starting reference: the record ``baseline_guard`` records back joins the
        baseline of each quantity that is in control (no alarm, CUSUM below h/2), so the
        centre's own error - which a CUSUM would accumulate as a drift - keeps shrinking.
        A change is detected long before its records are old enough to join."""
        s = self.settings
        i = len(self.records) - 1 - s.baseline_guard
        if i < 0 or self.seen - s.baseline_guard <= s.baseline_records:
            return
        grew = False
        for q in self.quantities:
            if (len(self.base[q]) >= s.baseline_max or self._active(q) is not None
                    or max(self.cusum[q]) > self.h / 2 or self.values[q][i] is None):
                continue
            self.base[q].append([self.values[q][i], self.errors[q][i]])
            grew = True
        if grew:
            first, last = self.baseline["first_index"], self.records[i].get("index")
            self.baseline = self._fit_baseline()
            self.baseline.update(first_index=first, last_index=last)

    def _fit_baseline(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        s = self.settings
        for q in self.quantities:
            pairs = [(v, e) for v, e in self.base[q] if v is not None]
            x = np.array([v for v, _ in pairs], dtype=float)
            if len(x) < max(3, s.baseline_records // 2):
                continue
            centre = float(np.median(x))
            scatter = 1.4826 * float(np.median(np.abs(x - centre)))
            se = np.array([e if e is not None and e > 0 else np.nan for _, e in pairs],
                          dtype=float)
            calib = None
            centre_se = 1.25 * scatter / math.sqrt(len(x))  # the median's standard error
            if np.isfinite(se).sum() >= max(3, s.baseline_records // 2):
                ok = np.isfinite(se)
                r = (x[ok] - centre) / se[ok]
                calib = max(1.0, 1.4826 * float(np.median(np.abs(r - np.median(r)))))
                # precision-weighted mean of the records within 4 calibrated errors
                keep = np.abs(r) <= 4 * calib
                w = 1.0 / (calib * se[ok][keep]) ** 2
                centre = float(np.sum(w * x[ok][keep]) / np.sum(w))
                centre_se = float(1.0 / math.sqrt(np.sum(w)))
            out[q] = {"centre": centre, "centre_se": centre_se, "scatter": scatter,
                      "se_calibration": calib,
                      "floor": s.min_rel_scatter * abs(centre), "n": int(len(x)),
                      "kind": self.kinds.get(q, "parameter")}
        return {"n_records": max((len(b) for b in self.base.values()), default=0),
                "quantities": out, "first_index": self.records[0].get("index"),
                "last_index": self.records[-1].get("index")}

    def _scale(self, q: str, i: int) -> float | None:
        b = (self.baseline or {}).get("quantities", {}).get(q)
        if b is None:
            return None
        e = self.errors[q][i]
        if b["se_calibration"] is not None and e is not None and e > 0:
            s = b["se_calibration"] * e
        else:
            s = b["scatter"]
        s = max(s, b["floor"])
        return s if s > 0 and math.isfinite(s) else None

    def _z(self, q: str, i: int) -> float | None:
        b = (self.baseline or {}).get("quantities", {}).get(q)
        v = self.values[q][i]
        s = self._scale(q, i)
        if b is None or v is None or s is None:
            return None
        z = (v - b["centre"]) / math.hypot(s, self.settings.centre_inflation * b["centre_se"])
        return float(np.clip(z, -self.settings.clip, self.settings.clip))

    # ------------------------------------------------------------------ alarms
    def _active(self, q: str) -> dict[str, Any] | None:
        for a in reversed(self.alarms):
            if a.get("young"):
                continue  # raised inside the baseline: stays until a reset (not a CUSUM)
            if a["parameter"] == q and a["state"] in ("raised", "confirmed"):
                return a
        return None

    def _update_alarm(self, q: str, i: int) -> list[dict[str, Any]]:
        s = self.settings
        up, down = self.cusum[q]
        above = max(up, down) > self.h
        rec = self.records[i]
        active = self._active(q)
        if active is None:
            if not above:
                return []
            direction = "increase" if up >= down else "decrease"
            alarm = {"id": len(self.alarms) + 1, "parameter": q,
                     "kind": self.kinds.get(q, "parameter"), "state": "raised",
                     "active": True, "direction": direction,
                     "raised_record": rec.get("id"), "raised_index": rec.get("index"),
                     "raised_time": rec.get("time"), "records_above": 1,
                     "confirmed_record": None, "cleared_record": None, "threshold": self.h}
            self._describe(alarm, q)
            self.alarms.append(alarm)
            return [alarm]
        side = 0 if active["direction"] == "increase" else 1
        if active["state"] == "raised":
            if self.cusum[q][side] > self.h:
                active["records_above"] += 1
                if active["records_above"] > s.confirm_records:
                    active.update(state="confirmed", confirmed_record=rec.get("id"),
                                  confirmed_index=rec.get("index"), confirmed_time=rec.get("time"))
                    self._describe(active, q)
                    return [active]
                self._describe(active, q)
                return []
            self._clear(active, q, rec, "transient: the CUSUM fell back below the threshold")
            return [active]
        # confirmed: cleared once the quantity is back to baseline
        recent = [z for z in self.z[q][-s.clear_records:] if z is not None]
        if (len(recent) >= s.clear_records and all(abs(z) < CLEAR_Z for z in recent)
                and abs(sum(recent)) / math.sqrt(len(recent)) < CLEAR_Z):
            # each value near the baseline *and* their mean too: a small persistent shift
            # (each |z| < 2, all on one side) is not "back to baseline"
            self._clear(active, q, rec, f"back to baseline for {s.clear_records} records")
            return [active]
        z = self.z[q][i]
        if z is not None and (z > CLEAR_Z if side == 0 else z < -CLEAR_Z):
            self._describe(active, q)  # still shifted: refine when, by how much
        return []

    def _position(self, index: Any) -> int:
        for i in range(len(self.records) - 1, -1, -1):
            if self.records[i].get("index") == index:
                return i
        return -1

    def _clear(self, alarm: dict[str, Any], q: str, rec: Mapping[str, Any], why: str) -> None:
        alarm.update(state="cleared", active=False, cleared_record=rec.get("id"),
                     cleared_index=rec.get("index"), cleared_time=rec.get("time"),
                     cleared_because=why)
        alarm["message"] = alarm_message(alarm)  # the change as last described, new state
        self.cusum[q] = [0.0, 0.0]

    def _describe(self, alarm: dict[str, Any], q: str) -> None:
        """Fill the change point, the change and the message of ``alarm`` (in place)."""
        b = self.baseline["quantities"][q] if self.baseline else {}
        n = len(self.records)
        start = max(0, n - CHANGE_POINT_WINDOW)
        for a in self.alarms:  # after a cleared alarm, the series starts afresh
            if a["parameter"] == q and a["state"] == "cleared" and a.get("cleared_index") is not None:
                start = max(start, self._position(a["cleared_index"]) + 1)
        cp = change_point(self.z[q][start:], self.values[q][start:],
                          [self._scale(q, i) for i in range(start, n)])
        if cp is not None:
            cp["index"] += start
            cp["interval"] = [cp["interval"][0] + start, cp["interval"][1] + start]
        alarm["change_point"] = None
        if cp is not None:
            t, lo, hi = cp["index"], cp["interval"][0], cp["interval"][1]
            cp.update(record=self.records[t].get("id"), record_index=self.records[t].get("index"),
                      interval_records=[self.records[lo].get("index"),
                                        self.records[hi].get("index")])
            alarm["change_point"] = cp
        centre = b.get("centre")
        vals = [v for v in self.values[q] if v is not None]
        alarm["reference"] = centre
        alarm["value"] = vals[-1] if vals else None
        alarm["cusum"] = list(self.cusum[q])
        sign = -1.0 if alarm["direction"] == "decrease" else 1.0
        alarm["change_rel"], alarm["change_rel_ci95"], alarm["change_since_index"] = None, None, None
        alarm["change_estimate"] = None
        if cp is not None and centre:
            ci = [x / abs(centre) for x in cp["change_ci95"]]
            if min(sign * ci[0], sign * ci[1]) > 0:  # significant, in the alarm's direction
                alarm.update(change_rel=cp["change"] / abs(centre), change_rel_ci95=ci,
                             change_since_index=cp["record_index"],
                             change_estimate="change point: mean after - mean before")
        if alarm["change_rel"] is None and centre:
            # the change point does not show the shift the CUSUM saw (e.g. a slow drift):
            # the mean since the CUSUM of the alarm's side last stood at zero, against the
            # reference - the estimate that goes with the evidence that raised the alarm
            est = cusum_change(self.z[q], self.values[q],
                               [self._scale(q, i) for i in range(n)], 0 if sign > 0 else 1,
                               self.settings.k, start, b.get("centre"), b.get("centre_se"))
            if est is not None:
                rel, lo, hi, first = est
                since = self.records[first].get("index")
                alarm.update(change_rel=rel, change_rel_ci95=[lo, hi], change_since_index=since,
                             change_estimate="CUSUM: mean since its last zero - reference")
        alarm["message"] = alarm_message(alarm)

    # ------------------------------------------------------------------ read-out
    def report(self) -> dict[str, Any]:
        return {"rule": {**asdict(self.settings), "threshold_h": self.h,
                         "quantities": self.quantities,
                         "false_alarms_per_1000_records_nominal":
                             1000.0 / self.settings.arl0_records},
                "reference": self.baseline,
                "young_baseline": self.young_report(),
                "n_records": len(self.records),
                "alarms": [dict(a) for a in self.alarms],
                "active_alarms": [a["parameter"] for a in self.alarms if a["active"]]}

    def series(self, limit: int | None = None) -> list[dict[str, Any]]:
        """The per-record estimates and standardised values, oldest first."""
        n = len(self.records)
        start = 0 if limit is None else max(0, n - limit)
        return [{**self.records[i],
                 "values": {q: self.values[q][i] for q in self.quantities},
                 "z": {q: self.z[q][i] for q in self.quantities}}
                for i in range(start, n)]

    def state_dict(self) -> dict[str, Any]:
        return {"quantities": self.quantities, "records": self.records, "values": self.values,
                "errors": self.errors, "z": self.z, "baseline": self.baseline,
                "base": self.base, "seen": self.seen,
                "cusum": self.cusum, "alarms": self.alarms}

    def load_state_dict(self, d: Mapping[str, Any]) -> None:
        self.reset()
        if not d or list(d.get("quantities", [])) != self.quantities:
            return
        self.records = list(d["records"])
        self.values = {q: list(v) for q, v in d["values"].items()}
        self.errors = {q: list(v) for q, v in d["errors"].items()}
        self.z = {q: list(v) for q, v in d["z"].items()}
        self.baseline = d.get("baseline")
        self.base = {q: [list(p) for p in v] for q, v in d.get("base", {}).items()}
        for q in self.quantities:
            self.base.setdefault(q, [])
        self.seen = int(d.get("seen", len(self.records)))
        self.cusum = {q: list(v) for q, v in d["cusum"].items()}
        self.alarms = [dict(a) for a in d.get("alarms", [])]


def _finite(x: Any) -> float | None:
    if x is None:
        return None
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None
