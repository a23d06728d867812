"""The drift report: the history of published estimates, modal quantities, and alarms.

The alarms come from ``service.monitoring.detector`` (a CUSUM on per-record estimates, see its
docstring and docs/service.md); this module keeps the bounded history of published
estimates that ``GET .../drift`` shows next to them, and the linear modal quantities.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Mapping, Sequence


class EstimateHistory:
    """A bounded history of published estimates (one entry per snapshot)."""

    def __init__(self, limit: int = 2000) -> None:
        self.entries: deque[dict[str, Any]] = deque(maxlen=limit)

    def add(self, entry: Mapping[str, Any]) -> None:
        self.entries.append(dict(entry))

    def last(self, limit: int | None = None) -> list[dict[str, Any]]:
        hist = list(self.entries)
        return hist if limit is None else hist[-limit:]

    def state_dict(self) -> dict[str, Any]:
        return {"history": list(self.entries)}

    def load_state_dict(self, d: Mapping[str, Any]) -> None:
        self.entries.clear()
        self.entries.extend(d.get("history", []) if d else [])


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
