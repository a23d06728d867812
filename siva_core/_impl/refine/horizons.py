"""``refine``'s growing fitting horizons: fit leading parts of the records first, so that
a start whose phase error would slip a cycle by the records' end reaches the basin."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..output_error import OutputErrorProblem

#: full-record cost below which theta0 is taken to be in the basin (no growing horizons):
#: a mean NMSE of 0.05 means no cycle has slipped anywhere in the records
HORIZON_SKIP_COST = 0.05


def _horizons(prob: OutputErrorProblem, horizons: Sequence[float] | str | None,
              to_theta: Any, x0: np.ndarray, n_x: int) -> list[float]:
    if horizons is None:
        return [1.0]
    if isinstance(horizons, str):
        if horizons != "auto":
            raise ValueError(f"horizons must be 'auto', None or fractions, got {horizons!r}")
        th, extra = to_theta(x0[None])
        cost0 = float(np.sum(prob.residuals(th, **extra) ** 2))
        if np.isfinite(cost0) and cost0 < HORIZON_SKIP_COST:
            return [1.0]
        return _auto_horizons(prob, min_samples=8 * n_x)
    fr = sorted(float(f) for f in horizons)
    if not fr or not all(0 < f <= 1 for f in fr):
        raise ValueError(f"horizons must be fractions in (0, 1], got {horizons}")
    return fr if fr[-1] == 1.0 else fr + [1.0]


def _auto_horizons(prob: OutputErrorProblem, first_cycles: float = 2.5,
                   growth: float = 1.6, min_samples: int = 0) -> list[float]:
    """Fractions of the records holding 2.5, 4, 6.4, ... oscillation cycles of the measured
    signal (hysteresis zero crossings at 10 % of the peak, averaged over DOFs; the longest
    record decides).  Starting at a couple of cycles matters: a start 10 % off in a
    power-law exponent changes the nonlinear force 2.5x, and only the first cycles are
    then still in phase (LO-NO: a first horizon of 5 cycles already ends in a wrong
    minimum, 2.5 cycles does not).  Each horizon keeps at least ``min_samples`` samples
    after the signal's onset, so that every parameter has data to act on."""
    counts = []
    for r in prob.records:
        c = np.zeros(len(r.target))
        for k in range(r.target.shape[1]):
            c += _crossings(r.target[:, k]) / r.target.shape[1]
        counts.append(c)
    fractions: list[float] = []
    need = 2 * first_cycles
    while True:
        f = max(min(1.0, (max(int(np.searchsorted(c, need)),
                              int(np.searchsorted(c, 0.5)) + min_samples) + 1) / len(c))
                for c in counts)
        if f >= 0.75:
            break
        if not fractions or f >= fractions[-1] * 1.25:
            fractions.append(f)
        need *= growth
    return fractions + [1.0]


def _crossings(x: np.ndarray, level: float = 0.1) -> np.ndarray:
    """Cumulative count of zero crossings with hysteresis +-level*max|x| (noise-proof)."""
    thr = level * float(np.max(np.abs(x)))
    s = np.where(x > thr, 1, np.where(x < -thr, -1, 0))
    idx = np.flatnonzero(s)
    out = np.zeros(len(x))
    if idx.size < 2:
        return out
    flips = idx[1:][s[idx[1:]] != s[idx[:-1]]]
    out[flips] = 1
    return np.cumsum(out)
