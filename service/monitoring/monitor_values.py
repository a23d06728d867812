"""What the per-record monitor hands the trainer: its headline, report and view, frozen.

Why frozen dataclasses: the refiner thread builds them and the snapshot, the drift report
and the HTTP readers take them without a lock; a field list says what crosses from the
monitoring layer to the trainer (no ``dict[str, Any]`` whose keys only the monitor knows).
Nested values (alarms, per-record fits, the detector's rule) stay plain JSON objects: the
detector's own format, also stored in the checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping


@dataclass(frozen=True)
class HeadlineEstimate:
    """The monitor's headline: per parameter the precision-weighted mean of the per-record
    fits in its window ({p: {mean, std, ci95, n}}), their modal quantities, which records."""

    parameters: dict[str, dict[str, Any]]
    modal: dict[str, Any] | None
    records: tuple[str, ...]
    n_records: int
    first_index: int
    last_index: int
    time: float
    method: str

    def mean(self, p: str) -> float:
        return float(self.parameters[p]["mean"])

    def to_json(self) -> dict[str, Any]:
        """Its part of the checkpoint file."""
        return {"parameters": self.parameters, "modal": self.modal,
                "records": list(self.records), "n_records": self.n_records,
                "first_index": self.first_index, "last_index": self.last_index,
                "time": self.time, "method": self.method}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "HeadlineEstimate":
        return cls(parameters=dict(d["parameters"]), modal=d.get("modal"),
                   records=tuple(d.get("records") or ()), n_records=int(d["n_records"]),
                   first_index=int(d.get("first_index", -1)),
                   last_index=int(d.get("last_index", -1)), time=float(d["time"]),
                   method=str(d.get("method") or ""))


@dataclass(frozen=True)
class AlarmChange:
    """An alarm that changed state at a record (raised, confirmed, cleared): what the
    refiner logs.  The alarm itself stays the detector's record (in its report)."""

    parameter: str
    state: str
    message: str
    change_point_index: int | None          # the record index where the change began
    change_rel: float | None                # the relative change, when estimated

    @classmethod
    def of(cls, alarm: Mapping[str, Any]) -> "AlarmChange":
        cp = alarm.get("change_point") or {}
        return cls(parameter=str(alarm["parameter"]), state=str(alarm["state"]),
                   message=str(alarm.get("message") or ""),
                   change_point_index=cp.get("record_index"),
                   change_rel=alarm.get("change_rel"))


@dataclass(frozen=True)
class MonitorReport:
    """The detector's report (rule, baseline ``reference``, the forming baseline's test,
    alarms) with the monitor's per-record fits and failures."""

    rule: dict[str, Any] | None
    reference: dict[str, Any] | None
    young_baseline: dict[str, Any] | None     # None: no detector yet
    n_records: int
    alarms: tuple[dict[str, Any], ...]
    active_alarms: tuple[str, ...]
    alarm_history: tuple[dict[str, Any], ...]
    records: tuple[dict[str, Any], ...]
    failures: dict[str, str]
    seconds_per_record: float | None
    processed_index: int


@dataclass(frozen=True)
class MonitorSummary:
    """``snapshot["monitoring"]``: how far the monitor is."""

    records_fitted: int
    processed_index: int
    baseline: int | None                      # records in the drift reference
    seconds_per_record: float | None
    active_alarms: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"records_fitted": self.records_fitted, "processed_index": self.processed_index,
                "baseline": self.baseline, "seconds_per_record": self.seconds_per_record,
                "active_alarms": list(self.active_alarms)}


@dataclass(frozen=True)
class MonitorView:
    """What readers get of the monitor: its report, its headline (the estimate's ``best``
    from epoch ``epoch`` on; None before the first per-record fit) and the summary (None
    until the trainer first reads the monitor's view)."""

    report: MonitorReport
    headline: HeadlineEstimate | None
    epoch: int
    summary: MonitorSummary | None
