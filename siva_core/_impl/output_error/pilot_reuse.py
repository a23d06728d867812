"""The substep pilot's simulation taken instead of simulating the same sets again (speed).

``OutputErrorProblem.build`` chooses each record's substeps by a pilot run of the
reference sets (``simulate.substeps.pilot_substeps``: the first set and the extremes of
each parameter).  When that run is at the chosen substeps it *is* the simulation the
first ``cost(theta_ref)`` would run -- ``output_error`` of a batch of starts, a fitted
model's validation gap -- so it is taken instead (measured on fresh seed 17436, a 3-DOF
pair: the pilots were 62 of 230 s of the diagnosis, half of them repeated right after).
The numba kernel simulates each set by the same scalar code whatever the batch
(a loop over the sets), so a set's run is the same alone or beside others, bit for
bit; the numpy backend vectorises over the batch, so there only the very same batch is
taken.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..simulate import simulate
from .records import _Record


def reuse_pilot(prob: Any, r: _Record, thetas: np.ndarray, q0: np.ndarray, v0: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(Q, V, A) of record ``r`` for ``thetas`` (B, n_free) at its substeps, the sets the
    pilot ran taken from it and the others simulated; None when the pilot has none of
    them (or the backend needs the same batch and this is another).  The pilot is taken
    once (its arrays are modified in place downstream and freed)."""
    p = r.pilot
    if p is None:
        return None
    m, sets, Qp, Vp, Ap = p
    if m != r.substeps:  # refine's margin changed the substeps: the pilot does not apply
        r.pilot = None
        return None
    B = thetas.shape[0]
    match = np.full(B, -1)
    for b in range(B):
        for j in range(len(sets)):
            if np.array_equal(thetas[b], sets[j]):
                match[b] = j
                break
    if not np.any(match >= 0):
        return None
    same_batch = B == len(sets) and np.array_equal(match, np.arange(B))
    if prob.backend != "numba" and not same_batch:
        return None
    r.pilot = None
    if same_batch:
        return Qp, Vp, Ap
    T, n = Qp.shape[1], Qp.shape[2]
    Q, V, A = (np.empty((B, T, n)) for _ in range(3))
    got = match >= 0
    Q[got], V[got], A[got] = Qp[match[got]], Vp[match[got]], Ap[match[got]]
    rest = np.flatnonzero(~got)
    if rest.size:
        sim = simulate(prob.structure, thetas[rest], r.rec.time, q0, v0, r.force,
                       substeps=r.substeps, backend=prob.backend, interp=prob.interp,
                       staged_force=r.staged(prob.interp))
        Q[rest], V[rest], A[rest] = sim.q, sim.v, sim.a
    return Q, V, A
