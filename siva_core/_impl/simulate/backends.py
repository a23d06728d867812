"""Backend choice and dispatch: the generated numba kernel when the structure's kinds all
have a translatable ``expr`` and numba is installed, generic numpy RK4 otherwise."""
from __future__ import annotations

from typing import Any

import numpy as np

from .grid import stage_force
from .numba_kernel import numba_unusable, run_numba
from .rk4_numpy import run_numpy


def choose_backend(structure: Any, backend: str) -> str:
    """"auto" | "numba" | "numpy" -> the backend that will run (``numba`` raises when it
    cannot be used, ``auto`` falls back to numpy)."""
    if backend not in ("auto", "numba", "numpy"):
        raise ValueError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
    if backend == "numpy":
        return "numpy"
    reason = numba_unusable(structure)
    if reason is None:
        return "numba"
    if backend == "numba":
        raise ValueError(f"numba backend unavailable: {reason}")
    return "numpy"


def run(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray, V0: np.ndarray,
        F: np.ndarray | None, m: int, backend: str, interp: str = "linear",
        force_scale: np.ndarray | None = None, staged: np.ndarray | None = None
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Q, V, A), each (B, T, n_dof), on the chosen backend; ``staged`` =
    ``stage_force(F, m, interp)`` precomputed by a caller that simulates the same record
    many times (refine)."""
    if staged is not None:
        Fh = staged
    else:
        Fh = None if F is None else stage_force(F, m, interp)
    if backend == "numba":
        return run_numba(structure, theta, dt, T, Q0, V0, Fh, m, force_scale)
    return run_numpy(structure, theta, dt, T, Q0, V0, Fh, m, force_scale)
