"""Approach III's candidates moved strictly inside the physical bounds before one is
chosen (a negative damping becomes positive; the refinement's log scale cannot start at 0)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass
class MovedCandidates:
    """Candidates inside the bounds, and the parameters that had to move."""

    candidates: np.ndarray
    names: list[str]


def physical_candidates(cand: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        names: Sequence[str] | None = None) -> MovedCandidates:
    """Candidates with every value strictly inside the physical bounds
    (:meth:`Structure.physical_bounds`): a value below ``lo`` is reflected above it (a
    damping of -0.9 becomes 0.9: same magnitude, physical sign), one on the bound is moved
    1e-3 of the parameter's typical size inside (the refinement's log scale cannot start at
    0).  Returns the moved candidates and the indices (or ``names``) of the parameters that
    had to move."""
    cand = np.array(cand, dtype=float, copy=True)
    typical = np.nanmedian(np.abs(cand), axis=0)
    typical = np.where(np.isfinite(typical) & (typical > 0), typical, 1.0)
    moved: list[int] = []
    for k in range(cand.shape[1]):
        col = cand[:, k]
        bad = ~((col > lo[k]) & (col < hi[k])) & np.isfinite(col)
        if not bad.any():
            continue
        moved.append(k)
        gap = 1e-3 * typical[k]
        below = col <= lo[k]
        col[below] = lo[k] + np.maximum(lo[k] - col[below], gap)
        above = col >= hi[k]
        col[above] = hi[k] - np.maximum(col[above] - hi[k], gap)
        if np.isfinite(lo[k]) and np.isfinite(hi[k]):
            out = ~((col > lo[k]) & (col < hi[k]))
            col[out] = 0.5 * (lo[k] + hi[k])
    labels = [names[k] for k in moved] if names is not None else [str(k) for k in moved]
    return MovedCandidates(cand, labels)
