"""Automatic convergence detection for SIVA training (the paper judges it by eye).

Rule (documented, measured in benchmarks/bench_siva_choices.py): after ``min_epochs``,
compare the mean of the last ``window`` per-epoch parameter samples with the mean of the
window before.  Converged when, for every parameter, the change is below ``rel_tol`` of
its magnitude *or* below ``z`` standard errors of the window (no detectable trend), on
``patience`` consecutive epochs.  Once converged it stays converged until ``reset``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ConvergenceMonitor:
    window: int = 20
    rel_tol: float = 2e-3
    z: float = 2.0
    min_epochs: int = 40
    patience: int = 5
    converged_at: int | None = None
    _streak: int = 0
    _history: list = field(default_factory=list)

    @property
    def converged(self) -> bool:
        return self.converged_at is not None

    def update(self, epoch: int, theta: np.ndarray) -> bool:
        self._history.append(np.asarray(theta, dtype=float))
        if len(self._history) > 4 * self.window:
            del self._history[: len(self._history) - 4 * self.window]
        if self.converged:
            return True
        w = self.window
        if epoch + 1 < self.min_epochs or len(self._history) < 2 * w:
            return False
        h = np.array(self._history[-2 * w:])
        old, new = h[:w], h[w:]
        change = np.abs(new.mean(0) - old.mean(0))
        se = np.sqrt(old.var(0, ddof=1) / w + new.var(0, ddof=1) / w)
        ok = (change <= self.rel_tol * np.abs(new.mean(0))) | (change <= self.z * se)
        self._streak = self._streak + 1 if bool(ok.all()) else 0
        if self._streak >= self.patience:
            self.converged_at = epoch
        return self.converged

    def reset(self) -> None:
        self.converged_at = None
        self._streak = 0
        self._history.clear()

    def state_dict(self) -> dict:
        return {"converged_at": self.converged_at, "streak": self._streak,
                "history": [h.tolist() for h in self._history]}

    def load_state_dict(self, d: dict) -> None:
        self.converged_at = d["converged_at"]
        self._streak = d["streak"]
        self._history = [np.asarray(h) for h in d["history"]]
