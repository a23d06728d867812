"""The per-record monitor of one system as the trainer's parts use it.

Why apart: the monitor (one output-error fit per stored record, the headline, the drift
test: ``service/monitor.py``) is fed by the refiner thread, reset by an HTTP request and
read by every snapshot; this class owns it, the lock that keeps a fit from being
half-applied, and the immutable JSON view readers get.
"""
from __future__ import annotations

import threading
from dataclasses import fields, is_dataclass, replace
from typing import Any, TypeVar

import numpy as np

from siva_core import Processing, Recording, RecordingError, Structure

from ..errors import UnknownSystem
from ..monitoring.detector import DetectorSettings
from ..monitoring.monitor import RecordMonitor
from ..monitoring.monitor_values import AlarmChange, MonitorView
from ..settings import Settings
from ..storage.store import Store
from .estimate import jsonable
from .priority import MONITOR
from .refiner import REFINE_LOCK


class Monitoring:
    def __init__(self, name: str, structure: Structure, store: Store, settings: Settings) -> None:
        self.name = name
        self.structure = structure
        self.store = store
        self.limit = settings.history_limit
        self.monitor = RecordMonitor(structure, DetectorSettings(
            baseline_records=settings.drift_baseline_records,
            arl0_records=settings.drift_arl0_records,
            min_rel_scatter=settings.drift_min_rel_scatter),
            window=settings.headline_window, max_nfev=settings.record_max_nfev,
            max_records=settings.history_limit)
        self.lock = threading.Lock()  # the monitor changes under it (refiner, reset)
        self.view = MonitorView(report=json_safe(self.monitor.report(limit=0)), headline=None,
                                epoch=0, summary=None)

    @property
    def ready(self) -> bool:
        return self.monitor.ready

    def seed(self, theta: np.ndarray, processing: Processing) -> None:
        with self.lock:
            if not self.monitor.ready:
                self.monitor.seed(theta, processing)

    def reset(self, epoch: int) -> None:
        with self.lock:
            self.monitor.reset()
            self.update_view(epoch)

    def update_view(self, epoch: int) -> None:
        """Immutable, JSON-safe copies of what the monitor holds, for readers."""
        self.view = json_safe(self.monitor.view(epoch, self.limit))

    def step(self, epoch: int, stopping: threading.Event) -> tuple[AlarmChange, ...] | None:
        """Fit the oldest stored record not yet monitored: its alarm changes, or None when
        there is nothing to do (no record left, no ``best`` to start from, stopping)."""
        if not self.monitor.ready or stopping.is_set():
            return None
        try:
            metas = self.store.recordings(self.name)
        except UnknownSystem:
            return None
        pending = [m for m in metas if m.index > self.monitor.processed_index]
        if not pending:
            return None
        meta = min(pending, key=lambda m: m.index)
        try:
            raw = self.store.read_raw(self.name, meta)
            rec = Recording.read(raw, self.structure.dofs, name=meta.id, fmt=meta.fmt,
                                 **meta.read_options(self.structure))
        except (OSError, RecordingError) as exc:
            self.monitor.processed_index = meta.index
            self.monitor.failures[meta.id] = str(exc)
            return ()
        with REFINE_LOCK.hold(MONITOR), self.lock:
            if stopping.is_set():
                return None
            return self.monitor.process(meta.id, meta.index, rec,
                                        getattr(meta, "received_at", None), epoch=epoch)

    def state_dict(self) -> dict[str, Any]:
        with self.lock:  # a consistent monitor (no fit half-applied)
            return self.monitor.state_dict()

    def load_state_dict(self, d: dict[str, Any], epoch: int) -> None:
        self.monitor.load_state_dict(d)
        self.update_view(epoch)


V = TypeVar("V")


def json_safe(value: V) -> V:
    """A copy of a frozen dataclass whose nested values are plain JSON (NaN as None, no
    numpy), its nested dataclasses too; tuples stay tuples."""
    if value is None or not is_dataclass(value) or isinstance(value, type):
        return value
    out: dict[str, Any] = {}
    for f in fields(value):
        v = getattr(value, f.name)
        if is_dataclass(v) and not isinstance(v, type):
            out[f.name] = json_safe(v)
        elif isinstance(v, tuple):
            out[f.name] = tuple(jsonable(list(v)))
        else:
            out[f.name] = jsonable(v)
    return replace(value, **out)  # type: ignore[type-var]
