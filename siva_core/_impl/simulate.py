"""Batched fixed-step simulation of a Structure for many parameter sets at once.

Why fixed-step RK4 and not an adaptive solver: output-error refinement differentiates the
simulated response with respect to the parameters by finite differences, which needs a
response that is a smooth function of theta (adaptive step control is not), and Approach III
/ Jacobians need hundreds of parameter sets simulated together, which vectorises only when
every set takes the same steps.  RK4 with ``substeps`` steps per sample, the force linearly
interpolated between samples (as MATLAB ``interp1`` in the paper; a cubic spline on request),
matches ``solve_ivp(DOP853, rtol=1e-10)`` to ~1e-7 relative at omega*h <= 0.05, the target
of the automatic step choice (``auto_substeps``).  Force laws with a kink (clearance, the
|dv| of a quadratic damper) lose RK4's order where it is crossed: ~1e-4 at that step, less
with more substeps.

Two backends:

- ``numba``: a kernel generated from the element kinds' ``expr`` strings (straight-line
  scalar code, ``prange`` over the parameter sets), compiled once per structure *signature*
  (kinds, topology, parameter slots; masses and parameter values are arguments) and cached
  in-process and on disk (a generated module under ``$SIVA_CACHE_DIR`` or
  ``~/.cache/siva/kernels`` so numba's own cache can persist the machine code).
- ``numpy``: generic RK4 on ``structure.accelerations`` vectorised over the batch; used for
  user-defined kinds without ``expr`` or when numba is unavailable.
"""
from __future__ import annotations

import ast
import hashlib
import importlib.util
import math
import os
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .processing import Processing
from .recording import Recording

#: default target for omega*h in the automatic choice of substeps (see ``auto_substeps``)
OMEGA_H = 0.05
#: a state beyond this magnitude is treated as a diverged simulation (rest filled with NaN)
_BLOWUP = 1e100


@dataclass
class Simulation:
    """Simulated states; arrays (B, T, n_dof), the B axis dropped when theta was 1-D."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    substeps: int = 1
    backend: str = "numpy"


# ---------------------------------------------------------------------------- public API
def simulate(structure: Any, theta: Any, t: Any, q0: Any, v0: Any, force: Any | None = None, *,
             substeps: int | str | None = 1, backend: str = "auto",
             omega_h: float = OMEGA_H, interp: str = "linear",
             force_scale: Any | None = None, staged_force: np.ndarray | None = None
             ) -> Simulation:
    """Simulate ``structure`` for one or many parameter sets on the uniform time axis ``t``.

    theta (n_free,) or (B, n_free); q0, v0 (n_dof,) or (B, n_dof); force (T, n_dof) or None,
    applied through the structure's force gains and linearly interpolated between samples.
    ``substeps`` RK4 steps per sample; ``"auto"``/``None`` chooses them (``auto_substeps``)
    so that omega*h <= ``omega_h`` for the fastest linearised *and* amplitude-dependent
    (tangent) frequency.  ``backend`` = "auto" | "numba" | "numpy".  ``interp`` = "linear"
    (default) | "cubic": how the force is evaluated between samples (``stage_force``).
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
        if F.shape != (len(t), n):
            raise ValueError(f"force must have shape (T, n_dof) = {(len(t), n)}, got {F.shape}")
        if not np.all(np.isfinite(F)):
            raise ValueError("force contains non-finite values")
    use = _choose_backend(structure, backend)
    pilot_run = None
    if substeps is None or substeps == "auto":
        m, pilot_run = _auto_substeps(structure, th, dt, Q0, V0, F, len(t), omega_h, use, True,
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
        if staged.shape != (2 * m * (len(t) - 1) + 1, n):
            raise ValueError("staged_force does not match the force and substeps")
    if pilot_run is not None and gs is None and staged is None:
        Q, V, A = pilot_run  # the pilot already simulated every set at these substeps
    else:
        Q, V, A = _run(structure, th, dt, len(t), Q0, V0, F, m, use, interp, gs, staged)
    if single:
        Q, V, A = Q[0], V[0], A[0]
    return Simulation(t.copy(), Q, V, A, m, use)


def simulate_like(structure: Any, theta: Any, rec: Recording, processing: Processing | None = None,
                  *, initial: str = "auto", force_gate: str | None = "auto",
                  **kw: Any) -> Simulation:
    """Simulate what ``rec`` recorded: its time axis and force columns, starting from the
    chain's derived state at the record's first sample (``processing.derive`` row 0).

    The whole record is simulated even when the chain later cuts it (``start="impact"``):
    the simulated record then goes through the same chain and is cut at the same sample.
    ``initial`` and ``force_gate``: see ``initial_state_and_force``.
    """
    q0, v0, force = initial_state_and_force(structure, rec, processing or Processing(),
                                            initial=initial, force_gate=force_gate)
    return simulate(structure, theta, rec.time, q0, v0, force, **kw)


def initial_state_and_force(structure: Any, rec: Recording, processing: Processing, *,
                            initial: str = "auto", force_gate: str | None = "auto"
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(q0, v0, force or None) of a record, as ``simulate_like`` uses them.

    ``initial``: "derived" = the chain's state at the first sample; "rest" = zero; "auto" =
    rest when the record has an impulsive force that starts after the first sample (a
    pre-triggered impact test starts at rest, while a zero-phase band-pass smears the
    impact backwards and would put a spurious initial velocity of ~1 % of the peak into
    the derived state), the derived state otherwise (free decays, continuous excitation).
    ``force_gate``: "auto" zeroes an impulsive force outside its pulse; when the chain
    gates the force itself (``processing.gate_force``) its gating is used, so that the
    simulation is driven by the force the chain reports.
    """
    if initial not in ("auto", "derived", "rest"):
        raise ValueError(f"initial must be 'auto', 'derived' or 'rest', got {initial!r}")
    force = rec.stack("force", structure.dofs, fill=0.0) if rec.has_force(structure.dofs) else None
    pulse = impulse_window(force)
    if initial == "rest" or (initial == "auto" and pulse is not None and pulse[0] > 0):
        q0 = np.zeros(structure.n_dof)
        v0 = np.zeros(structure.n_dof)
    else:
        q, v, _, _ = processing.derive(rec, structure.dofs)
        q0, v0 = q[0].copy(), v[0].copy()
    if force is not None and force_gate is not None and getattr(processing, "gate_force", False):
        return q0, v0, np.asarray(processing._force(rec, structure.dofs), dtype=float)
    return q0, v0, gate_force(force, force_gate)


def impulse_window(force: np.ndarray | None) -> tuple[int, int] | None:
    """[lo, hi) sample range of an impulsive force, None if there is none.  A force counts
    as impulsive when it exceeds 5 % of its peak on less than 5 % of the record (a hammer
    pulse); a continuous excitation (a multisine, a shaker) is not.  The range is widened
    by 2 samples on each side to keep the pulse's flanks."""
    if force is None:
        return None
    mag = np.max(np.abs(force), axis=1)
    peak = mag.max()
    if not peak > 0:
        return None
    above = np.flatnonzero(mag > 0.05 * peak)
    if above.size > 0.05 * len(mag):
        return None
    return max(0, int(above[0]) - 2), min(len(mag), int(above[-1]) + 3)


def gate_force(force: np.ndarray | None, mode: str | None = "auto") -> np.ndarray | None:
    """Zero a measured *impulsive* force outside its pulse, as the paper applies the hammer
    force only up to the pulse end: sensor noise on the force channel is not a force, and
    integrated over a long free decay it drives a spurious random response (5 % of the
    LO-NO response at 0.2 % force noise).  Continuous excitation is left untouched."""
    if force is None or mode is None:
        return force
    if mode != "auto":
        raise ValueError(f"force_gate must be 'auto' or None, got {mode!r}")
    win = impulse_window(force)
    if win is None:
        return force
    gated = np.zeros_like(force)
    gated[win[0]:win[1]] = force[win[0]:win[1]]
    return gated


def simulated_recording(rec: Recording, structure: Any, q: np.ndarray, v: np.ndarray,
                        a: np.ndarray, name: str | None = None) -> Recording:
    """A Recording with exactly the channels of ``rec``, filled from one simulated set
    (q, v, a of shape (T, n_dof)); force columns are copied from ``rec`` (they are inputs).
    Kept here for callers of this module; the chain's own version does the work."""
    from .processing import simulated_recording as _chain_simulated_recording

    return _chain_simulated_recording(rec, structure, q, v, a, name=name)


def auto_substeps(structure: Any, theta: np.ndarray, dt: float, q0: np.ndarray, v0: np.ndarray,
                  force: np.ndarray | None, *, n_samples: int | None = None,
                  omega_h: float = OMEGA_H, backend: str = "numpy", pilot: bool = True,
                  max_substeps: int = 4096, interp: str = "linear") -> int:
    """Substeps per sample so that rho*h <= omega_h, rho the fastest rate of the model.

    rho starts from the linearisation about rest (the structure's linear modes, batched over
    the sets).  Linear frequencies alone underestimate hardening systems (the Duffing at
    5 m/s runs at ~16x its linear frequency), so a pilot run of a few representative sets
    (the first and the extremes of each parameter) gives the amplitudes actually reached,
    and the tangent stiffness/damping along it bounds rho there.  Bounded by
    ``max_substeps``.
    """
    return _auto_substeps(structure, np.atleast_2d(theta), dt, q0, v0, force, n_samples,
                          omega_h, backend, pilot, max_substeps, interp)[0]


def _auto_substeps(structure: Any, th: np.ndarray, dt: float, q0: Any, v0: Any,
                   force: np.ndarray | None, n_samples: int | None, omega_h: float,
                   backend: str, pilot: bool, max_substeps: int, interp: str
                   ) -> tuple[int, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """(substeps, the pilot's (Q, V, A) when it covered every set at those substeps)."""
    n = structure.n_dof
    rho = _max_rate(structure, th, np.zeros((1, th.shape[0], n)), np.zeros((1, th.shape[0], n)))
    m = _steps_for(rho, dt, omega_h, max_substeps)
    if not pilot:
        return m, None
    if n_samples is None:
        if force is None:
            raise ValueError("auto_substeps needs n_samples when there is no force")
        n_samples = len(force)
    idx = sorted({0, *np.argmax(th, axis=0).tolist(), *np.argmin(th, axis=0).tolist()})
    sub = th[idx]
    Q0 = np.broadcast_to(np.asarray(q0, dtype=float), (th.shape[0], n))[idx].copy()
    V0 = np.broadcast_to(np.asarray(v0, dtype=float), (th.shape[0], n))[idx].copy()
    covers_all = len(idx) == th.shape[0]
    for _ in range(6):
        Q, V, A = _run(structure, sub, dt, n_samples, Q0, V0, force, m, backend, interp)
        if not np.all(np.isfinite(Q)):
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
                                 np.moveaxis(V[:, rows], 1, 0)))
        m_new = _steps_for(rho, dt, omega_h, max_substeps)
        if m_new <= m:
            return m, ((Q, V, A) if covers_all else None)
        if m_new <= 2 * m or m_new >= max_substeps:
            return m_new, None  # the pilot's amplitudes are close enough to trust
        m = m_new  # the pilot was far too coarse: its amplitudes may be off, re-pilot
    return m, None


def _steps_for(rho: float, dt: float, omega_h: float, max_substeps: int) -> int:
    if not np.isfinite(rho):
        return max_substeps
    return int(min(max_substeps, max(1, math.ceil(rho * dt / omega_h - 1e-9))))


def _max_rate(structure: Any, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> float:
    """Largest |eigenvalue| of the tangent state matrix over sets and states.

    theta (B, n_free); q, v (S, B, n_dof).  Element tangents by central differences of each
    kind's force law (works for every registered kind, no ``expr`` needed).
    """
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
    if not np.all(np.isfinite(Asys)):
        return float("inf")
    lam = np.linalg.eigvals(Asys)
    return float(np.max(np.abs(lam))) if lam.size else 0.0


# ---------------------------------------------------------------------------- dispatch
def _choose_backend(structure: Any, backend: str) -> str:
    if backend not in ("auto", "numba", "numpy"):
        raise ValueError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
    if backend == "numpy":
        return "numpy"
    reason = _numba_unusable(structure)
    if reason is None:
        return "numba"
    if backend == "numba":
        raise ValueError(f"numba backend unavailable: {reason}")
    return "numpy"


def _numba_unusable(structure: Any) -> str | None:
    try:
        import numba  # noqa: F401
    except ImportError:
        return "numba is not installed"
    try:
        _kernel_source(structure)
    except _NotCompilable as exc:
        return str(exc)
    return None


def _run(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray, V0: np.ndarray,
         F: np.ndarray | None, m: int, backend: str, interp: str = "linear",
         force_scale: np.ndarray | None = None, staged: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dispatch; ``staged`` = ``stage_force(F, m, interp)`` precomputed by a caller that
    simulates the same record many times (refine)."""
    if staged is not None:
        Fh = staged
    else:
        Fh = None if F is None else stage_force(F, m, interp)
    if backend == "numba":
        return _run_numba(structure, theta, dt, T, Q0, V0, Fh, m, force_scale)
    return _run_numpy(structure, theta, dt, T, Q0, V0, Fh, m, force_scale)


def stage_force(F: np.ndarray, m: int, interp: str = "linear") -> np.ndarray:
    """The sampled force (T, n) at every RK4 stage time: (2 m (T-1) + 1, n), i.e. on the
    grid t_0 + k h/2.  "linear": straight lines between samples (MATLAB interp1, as the
    paper); "cubic": a not-a-knot cubic spline through the samples, much closer to a smooth
    physical force sampled a dozen times per pulse (an impact hammer at 2 kHz) or to a
    band-limited excitation sampled a few times per period (Silverbox)."""
    T, n = F.shape
    if interp == "linear":
        w = (np.arange(2 * m) / (2.0 * m))[None, :, None]
        out = np.empty((2 * m * (T - 1) + 1, n))
        out[:-1] = (F[:-1, None, :] * (1.0 - w) + F[1:, None, :] * w).reshape(-1, n)
        out[-1] = F[-1]
        return out
    x = np.arange(2 * m * (T - 1) + 1) / (2.0 * m)  # in sample units
    if interp == "cubic":
        from scipy.interpolate import CubicSpline

        return CubicSpline(np.arange(T, dtype=float), F, axis=0)(x)
    raise ValueError(f"force interpolation must be 'linear' or 'cubic', got {interp!r}")


def _gains(structure: Any, theta: np.ndarray) -> np.ndarray:
    """(B, n_dof) force gain of each DOF for each parameter set."""
    values = structure.full_values(theta)
    G = np.ones((theta.shape[0], structure.n_dof))
    for k, d in enumerate(structure.dofs):
        g = structure.force_gains.get(d, 1.0)
        G[:, k] = values[g] if isinstance(g, str) else g
    return G


# ---------------------------------------------------------------------------- numpy backend
def _run_numpy(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray,
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
        return F[j] if fsc is None else F[j] * fsc

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
                bad = ~(np.all(np.abs(q) < _BLOWUP, axis=1) & np.all(np.abs(v) < _BLOWUP, axis=1))
                if np.any(bad & alive):
                    alive &= ~bad
                    q[bad], v[bad] = np.nan, np.nan
    return Q, V, A


# ---------------------------------------------------------------------------- numba backend
class _NotCompilable(Exception):
    """An element expression the kernel generator cannot translate."""


_FUNCS = {"abs": "abs", "tanh": "math.tanh", "copysign": "math.copysign", "exp": "math.exp",
          "sqrt": "math.sqrt", "log": "math.log", "sin": "math.sin", "cos": "math.cos",
          "atan": "math.atan", "min": "min", "max": "max"}
_CONSTS = {"pi": "math.pi", "e": "math.e"}


class _Renamer(ast.NodeTransformer):
    def __init__(self, names: dict[str, str]):
        self.names = names

    def visit_Call(self, node: ast.Call) -> ast.AST:
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCS or node.keywords:
            raise _NotCompilable(f"call {ast.unparse(node.func)!r} is not supported in expr")
        node.args = [self.visit(a) for a in node.args]
        node.func = ast.parse(_FUNCS[node.func.id], mode="eval").body
        return node

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if node.id in self.names:
            return ast.copy_location(ast.Name(self.names[node.id], ast.Load()), node)
        if node.id in _CONSTS:
            return ast.parse(_CONSTS[node.id], mode="eval").body
        raise _NotCompilable(f"unknown name {node.id!r} in expr")

    def generic_visit(self, node: ast.AST) -> ast.AST:
        allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.IfExp, ast.Compare, ast.BoolOp,
                   ast.Constant, ast.operator, ast.unaryop, ast.cmpop, ast.boolop, ast.Load)
        if not isinstance(node, allowed):
            raise _NotCompilable(f"{type(node).__name__} is not supported in expr")
        return super().generic_visit(node)


def _translate(expr: str | None, names: dict[str, str]) -> str:
    if not expr:
        raise _NotCompilable("kind has no scalar 'expr'")
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise _NotCompilable(f"expr {expr!r} is not valid Python ({exc.msg})") from None
    tree = _Renamer(names).visit(tree)
    return ast.unparse(tree)


def _kernel_source(structure: Any) -> str:
    """Python/numba source of the kernel for this structure's signature."""
    n = structure.n_dof
    pnames = list(structure.parameters)
    slot = {p: k for k, p in enumerate(pnames)}
    codes: list[str] = []
    for e, el in enumerate(structure.elements):
        names = {"d": f"d_{e}", "dv": f"dv_{e}"}
        names.update({c: f"p_{slot[p]}" for c, p in zip(el.kind.coefficients, el.params)})
        try:
            codes.append(_translate(el.kind.expr, names))
        except _NotCompilable as exc:
            raise _NotCompilable(f"element kind {el.kind.name!r}: {exc}") from None

    def acc_block(qn: str, vn: str, un: str, out: str) -> list[str]:
        """The model's accelerations as straight-line code, written out at each RK4 stage
        (a helper function would need 3n + n_params + n arguments; numba refuses ~24+)."""
        lines: list[str] = []
        terms: list[list[str]] = [[] for _ in range(n)]
        for e, el in enumerate(structure.elements):
            if el.j >= 0:
                lines.append(f"d_{e} = {qn}{el.i} - {qn}{el.j}")
                lines.append(f"dv_{e} = {vn}{el.i} - {vn}{el.j}")
                terms[el.j].append(f"+ f_{e}")
            else:
                lines.append(f"d_{e} = {qn}{el.i}")
                lines.append(f"dv_{e} = {vn}{el.i}")
            terms[el.i].append(f"- f_{e}")
            lines.append(f"f_{e} = {codes[e]}  # {el.kind.name}")
        lines += [f"{out}{k} = ({un}{k} {' '.join(terms[k])}) * im_{k}" for k in range(n)]
        return lines

    K: list[str] = []
    ind = " " * 8
    K += [f"{ind}p_{k} = P[b, {k}]" for k in range(len(pnames))]
    K += [f"{ind}g_{k} = G[b, {k}]" for k in range(n)]
    K += [f"{ind}im_{k} = invm[{k}]" for k in range(n)]
    K += [f"{ind}q_{k} = Q0[b, {k}]" for k in range(n)]
    K += [f"{ind}v_{k} = V0[b, {k}]" for k in range(n)]
    K += [f"{ind}for i in range(T):"]
    i2, i3, i4 = ind + " " * 4, ind + " " * 8, ind + " " * 12
    K += [f"{i2}base = i * m2"]
    K += [f"{i2}u_{k} = g_{k} * F[base, {k}]" for k in range(n)]
    K += [i2 + line for line in acc_block("q_", "v_", "u_", "a_")]
    for k in range(n):
        K += [f"{i2}Q[b, i, {k}] = q_{k}", f"{i2}V[b, i, {k}] = v_{k}", f"{i2}A[b, i, {k}] = a_{k}"]
    ok = " and ".join([f"abs(q_{k}) < {_BLOWUP!r} and abs(v_{k}) < {_BLOWUP!r}" for k in range(n)])
    K += [f"{i2}if not ({ok}):",
          f"{i3}for j in range(i + 1, T):",
          f"{i3}    for k in range({n}):",
          f"{i3}        Q[b, j, k] = np.nan",
          f"{i3}        V[b, j, k] = np.nan",
          f"{i3}        A[b, j, k] = np.nan",
          f"{i3}break",
          f"{i2}if i == T - 1:",
          f"{i3}break"]
    K += [f"{i2}for s in range(m):",
          f"{i3}j = base + 2 * s"]
    K += [f"{i3}ua_{k} = g_{k} * F[j, {k}]" for k in range(n)]
    K += [f"{i3}um_{k} = g_{k} * F[j + 1, {k}]" for k in range(n)]
    K += [f"{i3}ub_{k} = g_{k} * F[j + 2, {k}]" for k in range(n)]
    K += [f"{i3}if s == 0:"]
    K += [f"{i4}k1_{k} = a_{k}" for k in range(n)]
    K += [f"{i3}else:"] + [i4 + line for line in acc_block("q_", "v_", "ua_", "k1_")]
    K += [f"{i3}q2_{k} = q_{k} + hh * v_{k}" for k in range(n)]
    K += [f"{i3}v2_{k} = v_{k} + hh * k1_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q2_", "v2_", "um_", "k2_")]
    K += [f"{i3}q3_{k} = q_{k} + hh * v2_{k}" for k in range(n)]
    K += [f"{i3}v3_{k} = v_{k} + hh * k2_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q3_", "v3_", "um_", "k3_")]
    K += [f"{i3}q4_{k} = q_{k} + h * v3_{k}" for k in range(n)]
    K += [f"{i3}v4_{k} = v_{k} + h * k3_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q4_", "v4_", "ub_", "k4_")]
    K += [f"{i3}q_{k} = q_{k} + h6 * (v_{k} + 2.0 * v2_{k} + 2.0 * v3_{k} + v4_{k})"
          for k in range(n)]
    K += [f"{i3}v_{k} = v_{k} + h6 * (k1_{k} + 2.0 * k2_{k} + 2.0 * k3_{k} + k4_{k})"
          for k in range(n)]

    src = [
        '"""Generated by siva_core._impl.simulate for one structure signature. Do not edit."""',
        "import math",
        "import numpy as np",
        "import numba as nb",
        "",
        "",
        "@nb.njit(parallel=True, cache=CACHE, nogil=True, error_model='numpy',",
        f"         fastmath={_fastmath_literal()})",
        "def kernel(P, G, F, invm, Q0, V0, dt, m, Q, V, A):",
        "    # F: force at every RK4 stage time, (2 m (T - 1) + 1, n_dof): sample i, substep s",
        "    # -> rows i*2m + 2s (start), +1 (midpoint), +2 (end)",
        "    B = P.shape[0]",
        "    T = Q.shape[1]",
        "    m2 = 2 * m",
        "    h = dt / m",
        "    hh = 0.5 * h",
        "    h6 = h / 6.0",
        "    for b in nb.prange(B):",
        *K,
        "",
    ]
    return "\n".join(src)


#: LLVM may reassociate and contract (FMA) the RK4 combinations (~1.5x faster, differences at
#: rounding level); no 'nnan'/'ninf' (the divergence check must see NaN/inf) and no 'afn'
#: (tanh, pow keep libm accuracy)
_FASTMATH = ("arcp", "contract", "nsz", "reassoc")


def _fastmath_literal() -> str:
    """A set literal in fixed order: the source (hence the cache key) must not depend on
    the process's string-hash seed."""
    return "{" + ", ".join(repr(f) for f in _FASTMATH) + "}"


_KERNELS: dict[str, Callable[..., None]] = {}
_KERNEL_LOCK = threading.Lock()  # numba's default (workqueue) layer is not re-entrant


def _cache_dir() -> Path | None:
    for cand in (os.environ.get("SIVA_CACHE_DIR"),
                 str(Path.home() / ".cache" / "siva" / "kernels"),
                 os.path.join(tempfile.gettempdir(), f"siva-kernels-{os.getuid()}")):
        if not cand:
            continue
        p = Path(cand)
        try:
            p.mkdir(parents=True, exist_ok=True)
            probe = p / f".probe-{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            return p
        except OSError:
            continue
    return None


def compiled_kernel(structure: Any) -> Callable[..., None]:
    """The compiled numba kernel of this structure's signature (in-process + on-disk cache)."""
    src = _kernel_source(structure)
    key = hashlib.sha256(src.encode()).hexdigest()[:20]
    fn = _KERNELS.get(key)
    if fn is not None:
        return fn
    with _KERNEL_LOCK:
        fn = _KERNELS.get(key)
        if fn is not None:
            return fn
        directory = _cache_dir()
        modname = f"siva_kernel_{key}"
        if directory is not None:
            path = directory / f"{modname}.py"
            text = src.replace("CACHE", "True")
            if not path.exists() or path.read_text() != text:
                tmp = directory / f".{modname}.{os.getpid()}.tmp"
                tmp.write_text(text)
                os.replace(tmp, path)
            spec = importlib.util.spec_from_file_location(modname, path)
            assert spec is not None and spec.loader is not None
            mod = importlib.util.module_from_spec(spec)
            sys.modules[modname] = mod
            spec.loader.exec_module(mod)
            fn = mod.kernel
        else:
            ns: dict[str, Any] = {}
            exec(compile(src.replace("CACHE", "False"), f"<{modname}>", "exec"), ns)
            fn = ns["kernel"]
        _KERNELS[key] = fn
        return fn


def _run_numba(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray,
               V0: np.ndarray, F: np.ndarray | None, m: int,
               force_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    kernel = compiled_kernel(structure)
    values = structure.full_values(theta)
    B, n = Q0.shape
    P = np.empty((B, len(structure.parameters)))
    for k, p in enumerate(structure.parameters):
        P[:, k] = values[p]
    G = _gains(structure, theta)
    if force_scale is not None:
        G = G * force_scale[:, None]
    Fa = np.zeros((2 * m * (T - 1) + 1, n)) if F is None else np.ascontiguousarray(F, dtype=float)
    Q = np.empty((B, T, n))
    V = np.empty((B, T, n))
    A = np.empty((B, T, n))
    invm = np.ascontiguousarray(1.0 / structure.masses)
    with _KERNEL_LOCK:
        kernel(P, G, Fa, invm, np.ascontiguousarray(Q0), np.ascontiguousarray(V0),
               float(dt), int(m), Q, V, A)
    return Q, V, A


def warmup(structure: Any) -> None:
    """Compile (or load from numba's disk cache) the kernel now, e.g. before timing: numba
    compiles lazily, on the first call, so this runs a two-sample simulation."""
    if _choose_backend(structure, "auto") == "numba":
        n = structure.n_dof
        theta = np.ones((1, len(structure.free)))
        _run_numba(structure, theta, 1e-3, 2, np.zeros((1, n)), np.zeros((1, n)),
                   np.zeros((3, n)), 1)


__all__ = ["Simulation", "simulate", "simulate_like", "auto_substeps", "simulated_recording",
           "initial_state_and_force", "impulse_window", "gate_force", "compiled_kernel",
           "warmup", "stage_force", "OMEGA_H"]


