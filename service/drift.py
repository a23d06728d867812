"""Drift monitoring: the history of published estimates, modal quantities, and alarms.

Rule (documented in docs/service.md):

1. **Reference.** The ``reference_after``-th snapshot taken while the trainer is converged
   freezes, per parameter, the Approach II mean and 95 % interval.  The *band* is that
   interval widened to at least ``rel_tol * |mean|`` on each side, so that a noise-free
   record (whose interval can be far narrower than any physical change worth reporting)
   does not raise alarms on numerical jitter.
2. **Observation.** Each later snapshot contributes, per parameter, its *recent mean*: the
   mean of the per-epoch parameter samples since the previous snapshot.  Unlike the
   running ensemble (which averages hundreds of epochs) it follows a change within a
   few epochs.
3. **Alarm.** When the recent mean lies outside the band on the same side for
   ``consecutive`` snapshots in a row, an alarm is raised for that parameter (direction
   ``decrease``/``increase``, the relative change, the epoch it first left the band and
   the linear modal frequencies and damping ratios of the reference and of the recent
   values).  A single excursion never alarms.
4. **Clearing.** An active alarm clears after ``consecutive`` snapshots in a row back
   inside the band; it stays in the list with ``active = false``.
5. ``reset()`` (``POST .../drift/reset``) drops the reference and the alarms, e.g. after a
   repair: the next converged snapshots become the new reference.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Mapping, Sequence


@dataclass(frozen=True)
class DriftRule:
    consecutive: int = 5
    rel_tol: float = 0.05
    reference_after: int = 10


class DriftMonitor:
    """Keeps a bounded history of snapshots and raises/clears per-parameter alarms."""

    def __init__(self, parameters: Sequence[str], rule: DriftRule | None = None,
                 history_limit: int = 2000) -> None:
        self.parameters = list(parameters)
        self.rule = rule or DriftRule()
        self.history: deque[dict[str, Any]] = deque(maxlen=history_limit)
        self.reference: dict[str, Any] | None = None
        self.alarms: list[dict[str, Any]] = []
        self._converged_seen = 0
        self._streak: dict[str, tuple[str | None, int, int | None]] = {}  # side, count, first epoch
        self._inside: dict[str, int] = {}

    # ------------------------------------------------------------------ update
    def observe(self, entry: Mapping[str, Any]) -> list[dict[str, Any]]:
        """Add one snapshot; returns the alarms raised by it.

        ``entry`` holds ``epoch``, ``time``, ``converged``, ``recent`` {p: value},
        ``parameters`` {p: {mean, std, ci95}} (the ensemble), ``modal`` (of the recent
        values) and optionally ``modal_estimate`` (of the ensemble means).
        """
        entry = dict(entry)
        self.history.append(entry)
        if entry.get("converged"):
            self._converged_seen += 1
            if self.reference is None and self._converged_seen >= self.rule.reference_after:
                self._freeze_reference(entry)
                return []
        if self.reference is None:
            return []
        raised: list[dict[str, Any]] = []
        recent = entry.get("recent") or {}
        for p, ref in self.reference["parameters"].items():
            value = recent.get(p)
            if value is None or not math.isfinite(value):
                continue
            lo, hi = ref["band"]
            side = "decrease" if value < lo else "increase" if value > hi else None
            active = self._active(p)
            if side is None:
                self._streak[p] = (None, 0, None)
                self._inside[p] = self._inside.get(p, 0) + 1
                if active is not None and self._inside[p] >= self.rule.consecutive:
                    active["active"] = False
                    active["cleared_epoch"] = entry.get("epoch")
                    active["cleared_time"] = entry.get("time")
                continue
            self._inside[p] = 0
            prev_side, count, first = self._streak.get(p, (None, 0, None))
            if prev_side == side:
                count += 1
            else:
                count, first = 1, entry.get("epoch")
            self._streak[p] = (side, count, first)
            if count >= self.rule.consecutive and active is None:
                alarm = self._alarm(p, side, value, ref, first, entry)
                self.alarms.append(alarm)
                raised.append(alarm)
            elif active is not None and active["direction"] == side:
                active["value"] = value
                active["change_rel"] = _rel(value, ref["mean"])
        return raised

    def _freeze_reference(self, entry: Mapping[str, Any]) -> None:
        params: dict[str, Any] = {}
        for p in self.parameters:
            s = (entry.get("parameters") or {}).get(p)
            if not s or s.get("mean") is None or s.get("ci95") is None:
                continue
            mean = float(s["mean"])
            lo, hi = (float(x) for x in s["ci95"])
            tol = self.rule.rel_tol * abs(mean)
            params[p] = {"mean": mean, "ci95": [lo, hi],
                         "band": [min(lo, mean - tol), max(hi, mean + tol)]}
        self.reference = {"epoch": entry.get("epoch"), "time": entry.get("time"),
                          "parameters": params,
                          "modal": entry.get("modal_estimate") or entry.get("modal")}

    def _active(self, p: str) -> dict[str, Any] | None:
        for a in reversed(self.alarms):
            if a["parameter"] == p and a["active"]:
                return a
        return None

    def _alarm(self, p: str, side: str, value: float, ref: Mapping[str, Any], first: Any,
               entry: Mapping[str, Any]) -> dict[str, Any]:
        return {
            "id": len(self.alarms) + 1,
            "parameter": p,
            "direction": side,
            "active": True,
            "value": value,
            "reference_mean": ref["mean"],
            "reference_ci95": list(ref["ci95"]),
            "band": list(ref["band"]),
            "change_rel": _rel(value, ref["mean"]),
            "first_epoch": first,
            "epoch": entry.get("epoch"),
            "time": entry.get("time"),
            "modal_reference": (self.reference or {}).get("modal"),
            "modal_now": entry.get("modal"),
            "message": (f"{p} {side}d by {abs(_rel(value, ref['mean'])) * 100:.1f} % "
                        f"(now {value:.6g}, reference {ref['mean']:.6g}, band "
                        f"[{ref['band'][0]:.6g}, {ref['band'][1]:.6g}]) for "
                        f"{self.rule.consecutive} consecutive snapshots since epoch {first}"),
        }

    def reset(self) -> None:
        """Forget the reference and the alarms (after a repair or a deliberate change)."""
        self.reference = None
        self.alarms = []
        self._converged_seen = 0
        self._streak.clear()
        self._inside.clear()

    # ------------------------------------------------------------------ read-out
    def report(self, limit: int | None = None) -> dict[str, Any]:
        hist = list(self.history)
        if limit is not None:
            hist = hist[-limit:]
        return {"rule": asdict(self.rule), "reference": self.reference, "history": hist,
                "history_total": len(self.history),
                "alarms": [dict(a) for a in self.alarms],
                "active_alarms": [a["parameter"] for a in self.alarms if a["active"]]}

    def state_dict(self) -> dict[str, Any]:
        return {"history": list(self.history), "reference": self.reference,
                "alarms": self.alarms, "converged_seen": self._converged_seen,
                "streak": dict(self._streak), "inside": dict(self._inside)}

    def load_state_dict(self, d: Mapping[str, Any]) -> None:
        self.history.clear()
        self.history.extend(d.get("history", []))
        self.reference = d.get("reference")
        self.alarms = [dict(a) for a in d.get("alarms", [])]
        self._converged_seen = int(d.get("converged_seen", 0))
        self._streak = {k: tuple(v) for k, v in d.get("streak", {}).items()}  # type: ignore[misc]
        self._inside = dict(d.get("inside", {}))


def _rel(value: float, ref: float) -> float:
    return (value - ref) / abs(ref) if ref else math.inf if value else 0.0


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
