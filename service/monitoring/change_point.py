"""Where and by how much a monitored quantity changed: the change point of a standardised
series (``ruptures``, exact) and, when it does not show the shift, the mean since the
one-sided CUSUM was last zero.  Both with 95 % intervals."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

#: chi-square(1) 95 % quantile: change-point positions within this much cost of the best
CHI2_1_95 = 3.841
#: records segmented when locating a change (exact segmentation is quadratic in this)
CHANGE_POINT_WINDOW = 300


def change_point(z: Sequence[float | None], values: Sequence[float | None],
                 scales: Sequence[float | None]) -> dict[str, Any] | None:
    """One mean change in a standardised series (``ruptures``, exact, l2 cost).

    Returns the first index after the change, a 95 % set of such indices (costs within
    the chi-square(1) 95 % quantile of the best, the likelihood-ratio interval for a known
    unit scatter), and the change in the raw values (mean after - mean before) with a
    95 % interval from the scatter.  None when the series is too short.
    """
    import ruptures as rpt

    idx = [i for i, (a, v) in enumerate(zip(z, values)) if a is not None and v is not None]
    if len(idx) < 4:
        return None
    signal = np.array([z[i] for i in idx], dtype=float)
    bkps = rpt.Dynp(model="l2", min_size=1, jump=1).fit(signal[:, None]).predict(n_bkps=1)
    tau = int(bkps[0])
    costs = np.array([_split_cost(signal, t) for t in range(1, len(signal))])
    ok = np.flatnonzero(costs - costs.min() <= CHI2_1_95) + 1
    x = np.array([values[i] for i in idx], dtype=float)
    s = np.array([scales[i] if scales[i] else np.nan for i in idx], dtype=float)
    before, after = x[:tau], x[tau:]
    sb, sa = np.nanmean(s[:tau]), np.nanmean(s[tau:])
    change = float(after.mean() - before.mean())
    se = float(math.sqrt(sb * sb / len(before) + sa * sa / len(after)))
    return {"index": idx[tau], "interval": [idx[int(ok.min())], idx[int(ok.max())]],
            "change": change, "change_ci95": [change - 1.96 * se, change + 1.96 * se],
            "before_mean": float(before.mean()), "after_mean": float(after.mean()),
            "n_before": int(len(before)), "n_after": int(len(after))}


def _split_cost(x: np.ndarray, t: int) -> float:
    a, b = x[:t], x[t:]
    return float(((a - a.mean()) ** 2).sum() + ((b - b.mean()) ** 2).sum())


def cusum_change(z: Sequence[float | None], values: Sequence[float | None],
                 scales: Sequence[float | None], side: int, k: float, start: int,
                 centre: float | None, centre_se: float | None
                 ) -> tuple[float, float, float, int] | None:
    """(relative change, 95 % interval, position of the first record) of the values since
    the one-sided CUSUM ``side`` (0: up, 1: down) was last zero, against ``centre``."""
    acc, last_zero = 0.0, start - 1
    n = len(z)
    for i in range(start, n):
        zi = z[i]
        if zi is None:
            continue
        acc = max(0.0, acc + (zi if side == 0 else -zi) - k)
        if acc == 0.0:
            last_zero = i
    idx = [i for i in range(last_zero + 1, n) if values[i] is not None]
    if not idx or not centre:
        return None
    x = np.array([values[i] for i in idx], dtype=float)
    s = np.array([scales[i] or np.nan for i in idx], dtype=float)
    var = float(np.nanmean(s ** 2)) / len(idx) if np.isfinite(s).any() else 0.0
    se = math.sqrt(var + float(centre_se or 0.0) ** 2)
    change = float(x.mean()) - centre
    return (change / abs(centre), (change - 1.96 * se) / abs(centre),
            (change + 1.96 * se) / abs(centre), idx[0])
