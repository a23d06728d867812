"""``refine``'s variables: which parameters are log-scaled, and the bounds of the scaled
variables (from the spec's or the caller's bounds on theta)."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

#: a log-scaled parameter stays within this factor of theta0 (see ``_x_bounds``)
LOG_RANGE = 20.0


def _bound(v: float | None, default: float) -> float:
    return default if v is None else float(v)


def _log_mask(structure: Any, free: list[str], theta0: np.ndarray,
              log_scale: bool | str | Sequence[str]) -> np.ndarray:
    if log_scale is True or log_scale is False:
        mask = np.full(len(free), bool(log_scale))
    elif log_scale == "auto":
        # log unless the spec explicitly allows the parameter to change sign
        mask = np.array([
            not ((th0 > 0 and structure.parameters[p].lower is not None
                  and structure.parameters[p].lower < 0)
                 or (th0 < 0 and structure.parameters[p].upper is not None
                     and structure.parameters[p].upper > 0))
            for p, th0 in zip(free, theta0)])
    elif isinstance(log_scale, str):
        raise ValueError(f"log_scale must be 'auto', a bool or parameter names, got {log_scale!r}")
    else:
        names = set(log_scale)
        unknown = names - set(free)
        if unknown:
            raise ValueError(f"log_scale: {sorted(unknown)} are not free parameters {free}")
        mask = np.array([p in names for p in free])
    return mask & (theta0 != 0)


def _x_bounds(theta0: np.ndarray, scale: np.ndarray, is_log: np.ndarray, lo: np.ndarray,
              hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scaled variables.  A log-scaled parameter is also kept within a factor
    LOG_RANGE of theta0: exp(x) -> 0 has a vanishing gradient, so a parameter an early,
    uninformative stage pushed towards 0 could never come back."""
    xl = np.where(is_log, -math.log(LOG_RANGE), -np.inf)
    xh = np.where(is_log, math.log(LOG_RANGE), np.inf)
    with np.errstate(all="ignore"):
        for k in range(theta0.size):
            if is_log[k]:
                a, b = lo[k] / theta0[k], hi[k] / theta0[k]
                a, b = min(a, b), max(a, b)  # a negative theta0 flips the ratios
                if a > 0:
                    xl[k] = max(xl[k], math.log(a))
                if b > 0 and np.isfinite(b):
                    xh[k] = min(xh[k], math.log(b))
            else:
                xl[k] = (lo[k] - theta0[k]) / scale[k]
                xh[k] = (hi[k] - theta0[k]) / scale[k]
    if np.any(xl >= 0) or np.any(xh <= 0):
        bad = np.flatnonzero((xl >= 0) | (xh <= 0))
        raise ValueError(f"theta0 is on or outside the spec bounds for parameter(s) {bad.tolist()}")
    return xl, xh
