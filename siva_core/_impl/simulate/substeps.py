"""Automatic RK4 substeps: enough steps per sample that rho*h <= omega_h for the fastest
linearised *and* amplitude-dependent (tangent) rate of the model."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .backends import run
from .pilot_memo import memo_key, recall, remember

#: default target for omega*h in the automatic choice of substeps (see ``auto_substeps``)
OMEGA_H = 0.05

#: bound on |lambda*h| for the tangent's dissipative (real-axis) rates in a *fit*
#: (``OutputErrorProblem.build``).  RK4's stability reaches |lambda h| = 2.78 on the negative
#: real axis; at 0.5 the one-step decay factor R(-0.5) = 0.60677 is within 4e-4 of e^-0.5
#: and the fast mode (the tanh friction's stick slope fc / V_SMOOTH) has decayed to 0.6 per
#: step, so its error stays ~1e-3 of a transient that is itself brief.  Oscillatory rates
#: keep ``omega_h``.  None (``simulate``'s default) counts every rate at ``omega_h``.
REAL_H_FIT = 0.5


def auto_substeps(structure: Any, theta: np.ndarray, dt: float, q0: np.ndarray, v0: np.ndarray,
                  force: np.ndarray | None, *, n_samples: int | None = None,
                  omega_h: float = OMEGA_H, backend: str = "numpy", pilot: bool = True,
                  max_substeps: int = 4096, interp: str = "linear",
                  real_h: float | None = None, pilot_out: list[Any] | None = None) -> int:
    """Substeps per sample so that rho*h <= omega_h, rho the fastest rate of the model.

    rho starts from the linearisation about rest (the structure's linear modes, batched over
    the sets).  Linear frequencies alone underestimate hardening systems (the Duffing at
    5 m/s runs at ~16x its linear frequency), so a pilot run of a few representative sets
    (the first and the extremes of each parameter) gives the amplitudes actually reached,
    and the tangent stiffness/damping along it bounds rho there.  Bounded by
    ``max_substeps``.  ``real_h``: see ``REAL_H_FIT`` (each eigenvalue then needs
    |Im lambda| h <= omega_h and |lambda| h <= real_h).  ``pilot_out``: see
    ``pilot_substeps``.
    """
    return pilot_substeps(structure, np.atleast_2d(theta), dt, q0, v0, force, n_samples,
                          omega_h, backend, pilot, max_substeps, interp, real_h,
                          pilot_out)[0]


def pilot_substeps(structure: Any, th: np.ndarray, dt: float, q0: Any, v0: Any,
                   force: np.ndarray | None, n_samples: int | None, omega_h: float,
                   backend: str, pilot: bool, max_substeps: int, interp: str,
                   real_h: float | None = None, pilot_out: list[Any] | None = None
                   ) -> tuple[int, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """(substeps, the pilot's (Q, V, A) when it covered every set at those substeps).

    ``pilot_out``: a list that receives (rows of ``th``, Q, V, A) of the pilot's last run when
    it ran at the returned substeps with every one of those sets finite, covering all sets
    or not: a caller about to simulate the same sets at those substeps
    (``OutputErrorProblem``) takes them instead of simulating them again."""
    n = structure.n_dof
    # a real-axis rate |lambda| weighs omega_h / real_h of an oscillatory one
    weight = 1.0 if real_h is None else min(1.0, omega_h / real_h)
    rho = _max_rate(structure, th, np.zeros((1, th.shape[0], n)), np.zeros((1, th.shape[0], n)),
                    weight)
    m = _steps_for(rho, dt, omega_h, max_substeps)
    if not pilot:
        return m, None
    if n_samples is None:
        if force is None:
            raise ValueError("auto_substeps needs n_samples when there is no force")
        n_samples = len(force)
    key = memo_key(structure, th, dt, q0, v0, force, n_samples, omega_h, backend,
                   max_substeps, interp, real_h)
    known = recall(key, structure)
    if known is not None:  # the same pilot ran before: its choice, without running it
        return known, None
    m, run_out = _pilot(structure, th, dt, q0, v0, force, n_samples, omega_h, backend,
                        max_substeps, interp, weight, rho, m, pilot_out)
    remember(key, structure, m)
    return m, run_out


def _pilot(structure: Any, th: np.ndarray, dt: float, q0: Any, v0: Any,
           force: np.ndarray | None, n_samples: int, omega_h: float, backend: str,
           max_substeps: int, interp: str, weight: float, rho: float, m: int,
           pilot_out: list[Any] | None) -> tuple[int, Any]:
    """The pilot runs of ``pilot_substeps`` from the linear choice ``m`` (rate ``rho``)."""
    n = structure.n_dof
    idx = sorted({0, *np.argmax(th, axis=0).tolist(), *np.argmin(th, axis=0).tolist()})
    sub = th[idx]
    Q0 = np.broadcast_to(np.asarray(q0, dtype=float), (th.shape[0], n))[idx].copy()
    V0 = np.broadcast_to(np.asarray(v0, dtype=float), (th.shape[0], n))[idx].copy()
    covers_all = len(idx) == th.shape[0]
    sets = np.asarray(idx, dtype=int)  # the pilot's sets, as rows of th
    prev: list[np.ndarray] = []  # each pilot set's first non-finite sample, earlier runs
    for _ in range(6):
        Q, V, A = run(structure, sub, dt, n_samples, Q0, V0, force, m, backend, interp)
        if not np.all(np.isfinite(Q)):
            bad = _first_bad(Q)
            esc = escaping(structure, sub, Q, V, bad, prev)
            if np.any(esc):  # no step saves these: pilot the others at this m
                keep = ~esc
                if not np.any(keep):
                    break
                sub, Q0, V0, sets = sub[keep], Q0[keep], V0[keep], sets[keep]
                prev = [p[keep] for p in prev]  # the others run again at this m
                covers_all = False
                continue
            prev.append(bad)
            if m >= max_substeps:
                break
            m = min(max_substeps, 4 * m)  # the pilot itself blew up: refine and retry
            continue
        # tangent rate on ~300 states per set plus the peak-amplitude states of each DOF,
        # where hardening elements are stiffest
        stride = max(1, n_samples // 300)
        keep = set(range(0, n_samples, stride))
        keep.update(np.argmax(np.abs(Q), axis=1).ravel().tolist())
        keep.update(np.argmax(np.abs(V), axis=1).ravel().tolist())
        rows = np.array(sorted(keep))
        rho = max(rho, _max_rate(structure, sub, np.moveaxis(Q[:, rows], 1, 0),
                                 np.moveaxis(V[:, rows], 1, 0), weight))
        m_new = _steps_for(rho, dt, omega_h, max_substeps)
        if m_new <= m:
            if pilot_out is not None:
                pilot_out.append((sets, Q, V, A))
            return m, ((Q, V, A) if covers_all else None)
        if m_new <= 2 * m or m_new >= max_substeps:
            return m_new, None  # the pilot's amplitudes are close enough to trust
        m = m_new  # the pilot was far too coarse: its amplitudes may be off, re-pilot
    return m, None


#: a blow-up that moves by at most this share of its time (or 2 samples) when the step is
#: cut 4 x, twice (``ESCAPE_RUNS`` runs), has converged: it is the model's, not the
#: integrator's (``escaping``)
ESCAPE_TOL = 0.02
ESCAPE_RUNS = 3


def _first_bad(Q: np.ndarray) -> np.ndarray:
    """(B,) each set's first sample with a non-finite state (T when there is none)."""
    fin = np.all(np.isfinite(Q), axis=2)
    return np.where(np.all(fin, axis=1), Q.shape[1], np.argmin(fin, axis=1))


def escaping(structure: Any, theta: np.ndarray, Q: np.ndarray, V: np.ndarray,
             bad: np.ndarray, prev: Sequence[np.ndarray]) -> np.ndarray:
    """(B,) sets whose run escapes whatever the step: the blow-up sample ``bad`` stayed
    where it was in the last ``ESCAPE_RUNS`` - 1 runs (``prev``, the earlier runs at 4, 16
    ... x fewer substeps) within ``ESCAPE_TOL``, and the tangent just before it is unstable
    (an eigenvalue with Re > 0: a softening past its turning point, a negative damper).
    An integrator's instability moves when the step shrinks; an escape converges to a
    finite escape time.  Two refinements, not one: an unstable step on a hardening element
    can throw the state past a softening one's turning point at the same sample twice
    (measured: 24206's 4-DOF frame, cubic springs; one refinement stopped at a step that
    then diverged on a start that converges at a finer one).
    Why: least squares can start a fit at a softening cubic of -1.7e14 (truth +6.3e11); the
    blow-up loop then refined 2 -> 4096 substeps and the cost was simulated again there
    (2 GB of stage force, ~45 s of one nominal fit) to give infinity anyway."""
    out = np.zeros(len(bad), dtype=bool)
    if len(prev) < ESCAPE_RUNS - 1:
        return out
    T = Q.shape[1]
    for b in range(len(bad)):
        k = int(bad[b])
        ks = [int(p[b]) for p in prev[-(ESCAPE_RUNS - 1):]]
        if k >= T or k < 2 or any(k0 >= T or abs(k - k0) > max(2.0, ESCAPE_TOL * k0)
                                  for k0 in ks):
            continue
        rows = np.arange(max(0, k - 4), k)
        out[b] = _max_growth(structure, theta[b:b + 1], Q[b, rows][:, None],
                             V[b, rows][:, None]) > 0.0
    return out


def _max_growth(structure: Any, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> float:
    """Largest Re lambda of the tangent state matrix over the states where it is finite
    (-inf when it is nowhere), less round-off of the largest |lambda|."""
    with np.errstate(all="ignore"):
        lam = _tangent_eigs(structure, theta, q, v, finite_only=True)
    lam = lam[np.isfinite(lam)] if lam is not None else np.zeros(0)
    if not lam.size:
        return -math.inf
    return float(np.max(lam.real) - 1e-9 * np.max(np.abs(lam)))


def _steps_for(rho: float, dt: float, omega_h: float, max_substeps: int) -> int:
    if not np.isfinite(rho):
        return max_substeps
    return int(min(max_substeps, max(1, math.ceil(rho * dt / omega_h - 1e-9))))


def _max_rate(structure: Any, theta: np.ndarray, q: np.ndarray, v: np.ndarray,
              real_weight: float = 1.0) -> float:
    """Largest rate max(|Im lambda|, real_weight |lambda|) of the tangent state matrix over
    sets and states (``real_weight`` = 1: the largest |eigenvalue|).

    theta (B, n_free); q, v (S, B, n_dof)."""
    lam = _tangent_eigs(structure, theta, q, v)
    if lam is None:
        return float("inf")
    if not lam.size:
        return 0.0
    if real_weight >= 1.0:
        return float(np.max(np.abs(lam)))
    return float(np.max(np.maximum(np.abs(lam.imag), real_weight * np.abs(lam))))


def _tangent_eigs(structure: Any, theta: np.ndarray, q: np.ndarray, v: np.ndarray,
                  finite_only: bool = False) -> np.ndarray | None:
    """Eigenvalues of the tangent state matrix at every (state, set), None when one matrix
    is not finite (``finite_only``: those are skipped).  theta (B, n_free); q, v (S, B,
    n_dof).  Element tangents by central differences of each kind's force law (works for
    every registered kind, no ``expr`` needed)."""
    n = structure.n_dof
    S, B = q.shape[0], theta.shape[0]
    values = structure.full_values(theta)
    K = np.zeros((S, B, n, n))
    C = np.zeros((S, B, n, n))
    for el in structure.elements:
        coeffs = {c: np.asarray(values[p], dtype=float)
                  for c, p in zip(el.kind.coefficients, el.params)}
        d = q[..., el.i] - (q[..., el.j] if el.j >= 0 else 0.0)
        dv = v[..., el.i] - (v[..., el.j] if el.j >= 0 else 0.0)
        ed = 1e-7 * np.maximum(np.abs(d), 1e-6)
        ev = 1e-7 * np.maximum(np.abs(dv), 1e-6)
        f = el.kind.force
        with np.errstate(all="ignore"):
            kd = (f(d + ed, dv, **coeffs) - f(d - ed, dv, **coeffs)) / (2 * ed)
            cd = (f(d, dv + ev, **coeffs) - f(d, dv - ev, **coeffs)) / (2 * ev)
        for M, val in ((K, kd), (C, cd)):
            val = np.broadcast_to(np.nan_to_num(val, nan=0.0, posinf=1e300, neginf=-1e300), (S, B))
            M[..., el.i, el.i] += val
            if el.j >= 0:
                M[..., el.j, el.j] += val
                M[..., el.i, el.j] -= val
                M[..., el.j, el.i] -= val
    minv = 1.0 / structure.masses
    Asys = np.zeros((S, B, 2 * n, 2 * n))
    Asys[..., :n, n:] = np.eye(n)
    Asys[..., n:, :n] = -minv[:, None] * K
    Asys[..., n:, n:] = -minv[:, None] * C
    Asys = Asys.reshape(-1, 2 * n, 2 * n)
    if finite_only:
        Asys = Asys[np.all(np.isfinite(Asys), axis=(1, 2))]
    elif not np.all(np.isfinite(Asys)):
        return None
    return np.linalg.eigvals(Asys) if len(Asys) else np.zeros(0, complex)
