"""The drift report: the history of published estimates, modal quantities, and alarms.

The alarms come from ``service.monitoring.detector`` (a CUSUM on per-record estimates, see its
docstring and docs/service.md); this module keeps the bounded history of published
estimates that ``GET .../drift`` shows next to them, and the linear modal quantities.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Mapping, Sequence


@dataclass(frozen=True)
class HistoryPoint:
    """One published estimate in the history: the headline and the ensemble with their
    bands ({p: {mean, std, ci95}}), for the dashboard's traces and the drift export."""

    epoch: int
    time: float
    converged: bool | None
    parameters: dict[str, dict[str, Any]]
    estimate_source: str | None
    ensemble: dict[str, dict[str, Any]]
    ensemble_state: str | None
    modal: dict[str, Any] | None

    def to_json(self) -> dict[str, Any]:
        return {"epoch": self.epoch, "time": self.time, "converged": self.converged,
                "parameters": self.parameters, "estimate_source": self.estimate_source,
                "ensemble": self.ensemble, "ensemble_state": self.ensemble_state,
                "modal": self.modal}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "HistoryPoint":
        """From a checkpoint's history (older checkpoints may lack the ensemble keys)."""
        return cls(epoch=int(d.get("epoch") or 0), time=float(d.get("time") or 0.0),
                   converged=d.get("converged"), parameters=dict(d.get("parameters") or {}),
                   estimate_source=d.get("estimate_source"),
                   ensemble=dict(d.get("ensemble") or {}),
                   ensemble_state=d.get("ensemble_state"), modal=d.get("modal"))


class EstimateHistory:
    """A bounded history of published estimates (one entry per snapshot)."""

    def __init__(self, limit: int = 2000) -> None:
        self.entries: deque[HistoryPoint] = deque(maxlen=limit)

    def add(self, entry: HistoryPoint) -> None:
        self.entries.append(entry)

    def last(self, limit: int | None = None) -> tuple[HistoryPoint, ...]:
        hist = tuple(self.entries)
        return hist if limit is None else hist[-limit:]

    def state_dict(self) -> dict[str, Any]:
        return {"history": [e.to_json() for e in self.entries]}

    def load_state_dict(self, d: Mapping[str, Any]) -> None:
        self.entries.clear()
        self.entries.extend(HistoryPoint.from_json(e) for e in (d.get("history", []) if d else []))


def modal_quantities(structure: Any, theta: Sequence[float]) -> dict[str, list[float]] | None:
    """Natural frequencies [Hz] and damping ratios of the model linearised about rest.

    None when the linearisation has no oscillatory mode (e.g. a purely cubic spring), or
    the parameters make it meaningless; the caller reports that rather than failing.
    """
    try:
        modes = structure.linear_modes(list(theta))
    except Exception:  # noqa: BLE001 - a derived quantity must never break a snapshot
        return None
    freqs = [f for f in modes.get("frequency_hz", []) if math.isfinite(f)]
    if not freqs:
        return None
    return {"frequency_hz": freqs, "damping_ratio": list(modes.get("damping_ratio", []))}
