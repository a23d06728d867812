"""``simulate``: validate the inputs, choose backend and substeps, run, package the result."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .backends import choose_backend, run
from .numba_kernel import run_numba
from .substeps import OMEGA_H, pilot_substeps


@dataclass
class Simulation:
    """Simulated states; arrays (B, T, n_dof), the B axis dropped when theta was 1-D."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    substeps: int = 1
    backend: str = "numpy"


def simulate(structure: Any, theta: Any, t: Any, q0: Any, v0: Any, force: Any | None = None, *,
             substeps: int | str | None = 1, backend: str = "auto",
             omega_h: float = OMEGA_H, interp: str = "linear",
             force_scale: Any | None = None, staged_force: np.ndarray | None = None
             ) -> Simulation:
    """Simulate ``structure`` for one or many parameter sets on the uniform time axis ``t``.

    theta (n_free,) or (B, n_free); q0, v0 (n_dof,) or (B, n_dof); force (T, n_dof), or one
    per set (B, T, n_dof) (integer ``substeps``), or None,
    applied through the structure's force gains and linearly interpolated between samples.
    ``substeps`` RK4 steps per sample; ``"auto"``/``None`` chooses them (``auto_substeps``)
    so that omega*h <= ``omega_h`` for the fastest linearised *and* amplitude-dependent
    (tangent) frequency.  ``backend`` = "auto" | "numba" | "numpy".  ``interp`` = "linear"
    (default) | "moments" | "cubic": how the force is evaluated between samples (``stage_force``).
    ``force_scale`` (B,) multiplies the force of each set (a per-set calibration factor,
    used by ``refine`` to absorb an impact's impulse error).  ``staged_force``: the force
    already on the stage grid (``stage_force``) for integer ``substeps``, to skip that step
    when the same record is simulated many times.
    """
    theta = np.asarray(theta, dtype=float)
    single = theta.ndim == 1
    th = np.atleast_2d(theta)
    B = th.shape[0]
    n = structure.n_dof
    if th.shape[1] != len(structure.free):
        raise ValueError(f"theta has {th.shape[1]} values per set, the model has "
                         f"{len(structure.free)} free parameters {structure.free}")
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or len(t) < 2:
        raise ValueError("t must be a 1-D time axis with at least 2 samples")
    dt = float(t[-1] - t[0]) / (len(t) - 1)  # mean step: CSV rounding must not matter
    if not dt > 0 or np.max(np.abs(np.diff(t) - dt)) > 1e-3 * dt:
        raise ValueError("t must be uniformly sampled (within 0.1 %) and increasing")
    Q0 = np.broadcast_to(np.asarray(q0, dtype=float), (B, n)).copy()
    V0 = np.broadcast_to(np.asarray(v0, dtype=float), (B, n)).copy()
    F = None
    if force is not None:
        F = np.asarray(force, dtype=float)
        if F.ndim == 1 and n == 1:
            F = F[:, None]
        if F.shape != (len(t), n) and F.shape != (B, len(t), n):
            raise ValueError(f"force must have shape (T, n_dof) = {(len(t), n)} or one per "
                             f"parameter set (B, T, n_dof), got {F.shape}")
        if F.ndim == 3 and (substeps is None or substeps == "auto"):
            raise ValueError("a force per parameter set needs integer substeps")
        if not np.all(np.isfinite(F)):
            raise ValueError("force contains non-finite values")
    use = choose_backend(structure, backend)
    pilot_run = None
    if substeps is None or substeps == "auto":
        m, pilot_run = pilot_substeps(structure, th, dt, Q0, V0, F, len(t), omega_h, use, True,
                                      4096, interp)
    else:
        m = int(substeps)
        if m < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
    gs = None
    if force_scale is not None:
        gs = np.broadcast_to(np.asarray(force_scale, dtype=float).ravel(), (B,)).copy()
    staged = None
    if staged_force is not None and F is not None:
        staged = np.asarray(staged_force, dtype=float)
        if staged.shape[-2:] != (2 * m * (len(t) - 1) + 1, n) or staged.ndim != F.ndim:
            raise ValueError("staged_force does not match the force and substeps")
    if pilot_run is not None and gs is None and staged is None:
        Q, V, A = pilot_run  # the pilot already simulated every set at these substeps
    else:
        Q, V, A = run(structure, th, dt, len(t), Q0, V0, F, m, use, interp, gs, staged)
    if single:
        Q, V, A = Q[0], V[0], A[0]
    return Simulation(t.copy(), Q, V, A, m, use)


def warmup(structure: Any) -> None:
    """Compile (or load from numba's disk cache) the kernel now, e.g. before timing: numba
    compiles lazily, on the first call, so this runs a two-sample simulation."""
    if choose_backend(structure, "auto") == "numba":
        n = structure.n_dof
        theta = np.ones((1, len(structure.free)))
        run_numba(structure, theta, 1e-3, 2, np.zeros((1, n)), np.zeros((1, n)),
                  np.zeros((3, n)), 1)


def simulate_split(structure: Any, theta: np.ndarray, t: np.ndarray, q0: Any, v0: Any,
                   head: np.ndarray, shared: np.ndarray, m: int,
                   force_scale: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Q, V, A), each (B, T, n), of ``simulate`` (numba backend, integer substeps ``m``)
    with a stage force per set only in the record's head: ``head`` (B, 2 m w + 1, n) up to
    sample w, ``shared`` (rows, n) the one force of every set (its rows from sample w on).

    Why: a kick at a hammer pulse changes a few stage rows of each set's force; a
    (B, rows, n) copy of the whole staged record per call cost more than the kick's
    simulation (docs/perf.md 8.3).  Two kernel runs, the second from the first's state at
    sample w, take the same steps on the same numbers as one (a sample's step reads only
    the state and the force rows of its interval): bit-identical."""
    th = np.atleast_2d(np.asarray(theta, dtype=float))
    B, n = th.shape[0], structure.n_dof
    T = len(t)
    w = (head.shape[1] - 1) // (2 * m)
    if head.shape != (B, 2 * m * w + 1, n) or not 0 < w < T - 1:
        raise ValueError("head must be (B, 2 m w + 1, n_dof) with 0 < w < T - 1")
    dt = float(t[-1] - t[0]) / (T - 1)  # as ``simulate``
    Q0 = np.broadcast_to(np.asarray(q0, dtype=float), (B, n)).copy()
    V0 = np.broadcast_to(np.asarray(v0, dtype=float), (B, n)).copy()
    gs = (None if force_scale is None
          else np.broadcast_to(np.asarray(force_scale, dtype=float).ravel(), (B,)).copy())
    Q1, V1, A1 = run_numba(structure, th, dt, w + 1, Q0, V0, head, m, gs)
    Q2, V2, A2 = run_numba(structure, th, dt, T - w, Q1[:, w].copy(), V1[:, w].copy(),
                           shared[2 * m * w:], m, gs)
    return tuple(np.concatenate([x1[:, :w], x2], axis=1)
                 for x1, x2 in ((Q1, Q2), (V1, V2), (A1, A2)))
