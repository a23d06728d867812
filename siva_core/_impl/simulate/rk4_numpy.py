"""Generic RK4 backend: ``structure.accelerations`` vectorised over the parameter sets.

Used for user-defined element kinds without ``expr`` or when numba is unavailable; slower
than the generated kernel (one numpy call per stage) but works for any force law.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .grid import BLOWUP


def run_numpy(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray,
              V0: np.ndarray, F: np.ndarray | None, m: int,
              force_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Generic RK4 over the batch with ``structure.accelerations`` (one call per stage).
    ``F`` is the force on the stage grid (see ``stage_force``) or None."""
    B, n = Q0.shape
    Q = np.empty((B, T, n))
    V = np.empty((B, T, n))
    A = np.empty((B, T, n))
    h = dt / m
    q, v = Q0.copy(), V0.copy()

    def acc(q: np.ndarray, v: np.ndarray, f: np.ndarray | None) -> np.ndarray:
        return structure.accelerations(theta, q, v, f)

    fsc = None if force_scale is None else force_scale[:, None]

    def f_at(j: int) -> np.ndarray | None:
        if F is None:
            return None
        f = F[j] if F.ndim == 2 else F[:, j]  # shared, or one force per set (B, rows, n)
        return f if fsc is None else f * fsc

    alive = np.ones(B, dtype=bool)
    with np.errstate(all="ignore"):
        for k in range(T):
            base = 2 * m * k
            a = acc(q, v, f_at(base))
            Q[:, k], V[:, k], A[:, k] = q, v, a
            if k == T - 1:
                break
            for s in range(m):
                j = base + 2 * s
                k1 = a if s == 0 else acc(q, v, f_at(j))
                fm = f_at(j + 1)
                q2, v2 = q + 0.5 * h * v, v + 0.5 * h * k1
                k2 = acc(q2, v2, fm)
                q3, v3 = q + 0.5 * h * v2, v + 0.5 * h * k2
                k3 = acc(q3, v3, fm)
                q4, v4 = q + h * v3, v + h * k3
                k4 = acc(q4, v4, f_at(j + 2))
                q = q + (h / 6.0) * (v + 2.0 * v2 + 2.0 * v3 + v4)
                v = v + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            if k % 256 == 0:
                bad = ~(np.all(np.abs(q) < BLOWUP, axis=1) & np.all(np.abs(v) < BLOWUP, axis=1))
                if np.any(bad & alive):
                    alive &= ~bad
                    q[bad], v[bad] = np.nan, np.nan
    return Q, V, A

