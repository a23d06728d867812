"""The output error linearised around an anchor: what SIVA's generator is judged on.

Why: an equation-error loss (model acceleration at the processed, *measured* states) is
biased by the processing chain (band-pass, integration, high-pass, decimation distort
amplitude and phase; for a nonlinear term ``H[q^3] != H[q]^3``), and no amount of training
removes that.  The output error is not: each record is simulated with the model from its
measured force and passed through the same chain as the measurement (``refine``).
Simulating every generator sample at every step would cost ~14 ms per parameter set and
record; instead the processed simulation is linearised around an anchor theta_a (one
batched simulation of n+1 sets, plus the nuisance columns):

    r(x) ~= r_a + J x,     x_k = log(theta_k / theta_a,k)  (or (theta_k - theta_a,k)/scale_k)

Nuisance parameters (a force scale per impact record, the initial state of a free decay
recorded by accelerometers) are profiled out by projecting r_a and J onto the complement
of their columns.  The linearisation only describes the output error near its anchor, and
its optimum is the anchor only when the anchor is the output-error optimum: ``settle``
moves the anchor there first (Gauss-Newton on the linearisation, step-halving), so that a
start off the optimum (a refinement stopped early, a headline of other records) cannot
bias what is harvested from it.

``noise`` holds parametric-bootstrap perturbations of the residuals (measurement noise with
the residuals' own spectrum, force-sensor noise through the dynamics; ``replicates.noise_replicates``):
each SIVA epoch fits the anchor's residuals plus one of them, so the spread of the per-epoch
samples (Approach II) is the spread of the estimator over noise realisations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .bootstrap import Series, series_of
from .processing import Processing, States
from .recording import Recording


@dataclass
class Linearization:
    """r(x) ~= r + J x around ``theta`` (nuisance profiled out), for one set of records."""

    theta: np.ndarray               # anchor (n,)
    is_log: np.ndarray              # (n,) bool: x = log(theta/theta_a), else (theta-theta_a)/scale
    scale: np.ndarray               # (n,) scale of the additive parameters
    r: np.ndarray                   # (N,) profiled residuals at the anchor
    J: np.ndarray                   # (N, n) profiled Jacobian in x
    series: list[Series]
    weight: list[np.ndarray]        # per record: (n_dof,) residual = (sim - meas) * weight
    targets: list[np.ndarray]       # per record: (T, n_dof) processed measured quantities
    states: list[States]            # per record: processed measured states (for D's features)
    noise: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (K, N) profiled
    quantities: list[list[str]] = field(default_factory=list)  # per record, per DOF
    records: list[Recording] = field(default_factory=list)
    processing: Processing | None = None

    @property
    def cost(self) -> float:
        return float(self.r @ self.r)

    def cov_x(self) -> np.ndarray:
        """Gauss-Newton covariance of x (a scale for the generator's outputs)."""
        dof = max(1, self.r.size - self.J.shape[1])
        s2 = max(self.cost / dof, 1e-300)
        return s2 * np.linalg.pinv(self.J.T @ self.J)

    def step_matrix(self) -> np.ndarray:
        """(n, n) L with L L^T = cov_x, rows of additive parameters in theta units."""
        c = self.cov_x()
        d = np.sqrt(np.clip(np.diag(c), 1e-300, None))
        corr = c / np.outer(d, d) + 1e-9 * np.eye(len(d))
        L = np.linalg.cholesky(corr) * d[:, None]
        return np.where(self.is_log[:, None], L, L * self.scale[:, None])

    def to_x(self, theta: np.ndarray) -> np.ndarray:
        th = np.atleast_2d(theta)
        with np.errstate(all="ignore"):
            return np.where(self.is_log, np.log(np.abs(th / self.theta)), (th - self.theta) / self.scale)

    def to_theta(self, x: np.ndarray) -> np.ndarray:
        return np.where(self.is_log, self.theta * np.exp(x), self.theta + self.scale * x)

    def residual_series(self, k: int) -> np.ndarray:
        """(T, n_dof) residuals of record ``k`` at the anchor in the record's own units."""
        s = self.series[k]
        return self.r[s.start:s.start + s.T * s.width].reshape(s.T, s.width) / self.weight[k]

    def predicted(self, x: np.ndarray, k: int) -> np.ndarray:
        """(B, T, n_dof) processed simulated quantities of record ``k`` at steps ``x``."""
        s = self.series[k]
        sl = slice(s.start, s.start + s.T * s.width)
        res = self.r[sl][None] + np.atleast_2d(x) @ self.J[sl].T
        return self.targets[k][None] + res.reshape(-1, s.T, s.width) / self.weight[k]


def linearize(structure: Any, theta: np.ndarray, records: Sequence[Recording],
              processing: Processing, *, fit_force_scale: bool | str = "auto",
              fit_force_spread: bool | str = "auto", fit_force_kick: bool | str = "auto",
              n_noise: int = 0, fd_step: float = 1e-6, seed: int = 0,
              substeps: Sequence[int] | None = None, jacobian: bool = True) -> Linearization:
    """Linearise the output error of ``records`` at ``theta`` (see the module doc).
    ``fit_force_spread``: also profile out a change of each record's force spread
    (``adjusted_stage_force``; "auto": with the force scale, when
    ``default_force_spread``: off unless enabled),
    the pulse's width between its few samples (docs/perf.md 6.3).  ``fit_force_kick``:
    also profile out each short pulse's kick (``refine``'s ``fit_force_kick``; "auto":
    with the force scale, where ``force_kick_applicable``).  ``jacobian=False``: only the
    profiled residuals are wanted (``validation_score``): the parameters' columns are not
    simulated and ``J`` has none (the residuals are the same, bit for bit)."""
    from .output_error import OutputErrorProblem, _state_derived, default_force_spread
    from .pulse_kick import KICK_STEP_TOL, KICK_STEPS, default_force_kick, kick_mask
    from .refine import _log_mask
    from .replicates import noise_replicates

    theta = np.asarray(theta, dtype=float).ravel()
    free = list(structure.free)
    recs = list(records)
    if substeps is None:
        prob = OutputErrorProblem.build(structure, recs, processing, theta_ref=theta[None])
        for rr in prob.records:
            rr.substeps = max(1, math.ceil(rr.substeps * 1.25))
    else:
        prob = OutputErrorProblem.build(structure, recs, processing, substeps=list(substeps))
    n, n_rec, n_dof = len(free), len(prob.records), structure.n_dof
    if fit_force_scale == "auto":
        gains = [g for g in structure.force_gains.values() if isinstance(g, str) and g in free]
        fit_force_scale = all(r.force is not None for r in prob.records) and not gains
    fit_initial = all(r.force is None and _state_derived(r.rec, structure.dofs)
                      for r in prob.records)
    is_log = _log_mask(structure, free, theta, "auto")
    scale = np.where(theta != 0, np.abs(theta), 1.0)
    if fit_force_spread == "auto":
        fit_force_spread = bool(fit_force_scale) and default_force_spread(
            structure, theta, recs, prob.interp)
    n_fs = n_rec if fit_force_scale else 0
    n_sp = n_rec if fit_force_spread else 0
    n_ic = 2 * n_dof * n_rec if fit_initial else 0
    if fit_force_kick == "auto":
        fit_force_kick = bool(fit_force_scale) and default_force_kick(structure, prob.records)
    kick_idx = (np.argwhere(np.stack([kick_mask(rr, n_dof, bool(fit_force_scale))
                                      for rr in prob.records]))
                if fit_force_kick else np.zeros((0, 3), dtype=int))
    n_kk = len(kick_idx)
    i_kk = n + n_fs + n_sp + n_ic
    n_x = i_kk + n_kk
    ic_scale = (np.maximum(np.concatenate([r.state_rms for r in prob.records]), 1e-300)
                if fit_initial else np.zeros(0))

    def evaluate(X: np.ndarray) -> np.ndarray:
        th = np.where(is_log, theta * np.exp(X[:, :n]), theta + scale * X[:, :n])
        extra: dict[str, np.ndarray] = {}
        if n_fs:
            extra["force_scales"] = np.exp(X[:, n:n + n_fs])
        if n_sp:
            extra["force_spreads"] = X[:, n + n_fs:n + n_fs + n_sp]
        if n_ic:
            ic = (X[:, n + n_fs + n_sp:i_kk] * ic_scale).reshape(len(X), n_rec, 2, n_dof)
            extra["dq0"], extra["dv0"] = ic[:, :, 0], ic[:, :, 1]
        extra.update(_kicks(X))
        return prob.residuals(th, **extra)

    def _kicks(X: np.ndarray) -> dict[str, np.ndarray]:
        if not n_kk:
            return {}
        kick = np.zeros((len(X), n_rec, 2, n_dof))
        kick[:, kick_idx[:, 0], kick_idx[:, 1], kick_idx[:, 2]] = X[:, i_kk:]
        return {"force_kicks": kick}

    # nuisance at its optimum for the anchor first (Gauss-Newton on those columns only):
    # a strongly nonlinear response depends on the impulse nonlinearly, so projecting out
    # a linearised force scale far from its optimum would leave a residual that moves theta
    base = np.zeros(n_x)
    n_q = n_x - n - n_kk   # the nuisance without the kick
    # with a kick: first the others alone (as without it), then ``KICK_STEPS`` steps on
    # all: a joint step from a multiplier far off overshoots into a kicked minimum that
    # is not the best (``force_profiled_output_error``)
    plan = ([n_q] * 4 + [n_q + n_kk] * KICK_STEPS) if n_kk else [n_x - n] * (4 if n_x > n else 0)
    settled = False  # the nuisance without the kick has converged
    for n_new in plan:
        if n_new == 0 or (settled and n_new == n_q and n_kk):
            continue
        Xn = np.repeat(base[None], n_new + 1, axis=0)
        Xn[1:, n:n + n_new] += np.eye(n_new) * fd_step
        Rn = evaluate(Xn)
        if not np.all(np.isfinite(Rn)):
            break
        Jn = (Rn[1:] - Rn[0]).T / fd_step
        step = -np.linalg.lstsq(Jn, Rn[0], rcond=None)[0]
        base[n:n + n_new] += step
        if n_kk and n_new == n_x - n and np.max(np.abs(step)) < KICK_STEP_TOL:
            break
        if np.max(np.abs(step)) < 1e-9:
            if n_new == n_x - n:
                break
            settled = True
    first = 0 if jacobian else n  # the columns simulated: the parameters' too, or not
    X = np.repeat(base[None], n_x - first + 1, axis=0)
    X[1:, first:] += np.eye(n_x - first) * fd_step
    R = evaluate(X)
    if not np.all(np.isfinite(R[0])):
        raise ValueError("linearize: the simulation diverges at the anchor")
    r0 = R[0]
    Jf = (R[1:] - r0).T / fd_step
    Jf[~np.isfinite(Jf)] = 0.0
    series = series_of([rr.target.shape for rr in prob.records])
    # profile the nuisance columns out: project onto the complement of their span
    proj = lambda M: M
    if n_x > n:
        Jn = Jf[:, n - first:]
        pinv = np.linalg.pinv(Jn)
        proj = lambda M: M - Jn @ (pinv @ M)
    r, J = proj(r0), (proj(Jf[:, :n]) if jacobian else np.zeros((r0.size, 0)))
    noise = np.zeros((0, r0.size))
    if n_noise > 0:
        extra0: dict[str, np.ndarray] = {}
        if n_fs:
            extra0["force_scales"] = np.exp(base[None, n:n + n_fs])
        if n_sp:
            extra0["force_spreads"] = base[None, n + n_fs:n + n_fs + n_sp]
        if n_ic:
            ic = (base[None, n + n_fs + n_sp:i_kk] * ic_scale).reshape(1, n_rec, 2, n_dof)
            extra0["dq0"], extra0["dv0"] = ic[:, :, 0], ic[:, :, 1]
        extra0.update(_kicks(base[None]))
        # the stationary part from the *profiled* residuals: the anchor's raw residuals
        # still hold the impulse error that the force scale absorbs
        noise = proj(noise_replicates(prob, theta[None], extra0, r, series, n_rep=n_noise,
                                      seed=seed).T).T
    weights = [prob.weight(k) for k in range(len(prob.records))]
    states = [prob.chain.apply(rr.rec, structure.dofs) for rr in prob.records]
    return Linearization(theta.copy(), is_log, scale, r, J, series, weights,
                         [rr.target for rr in prob.records], states, noise,
                         [list(rr.quantities) for rr in prob.records], recs, prob.chain)


@dataclass(frozen=True)
class Settled:
    """Where ``settle`` left the anchor: ``theta``, the Gauss-Newton steps taken, the size
    of the last step proposed (max over parameters, in standard errors) and whether that is
    within the tolerance."""

    theta: np.ndarray
    steps: int
    step_se: float
    converged: bool


def gauss_newton_step(lin: Linearization) -> tuple[np.ndarray, float]:
    """The linearisation's own optimum as a step ``x`` from its anchor, and the step's size:
    max over parameters of |x| / (Gauss-Newton standard error)."""
    x = -np.linalg.lstsq(lin.J, lin.r, rcond=None)[0]
    se = np.sqrt(np.clip(np.diag(lin.cov_x()), 1e-300, None))
    return x, float(np.max(np.abs(x) / se)) if len(x) else 0.0


def settle(structure: Any, theta: np.ndarray, records: Sequence[Recording],
           processing: Processing, *, tol_se: float = 0.5, max_steps: int = 8,
           max_move: float = 0.25, fit_force_scale: bool | str = "auto") -> Settled:
    """Move ``theta`` to the output-error optimum of ``records`` before it anchors a
    linearisation: Gauss-Newton steps on the linearised output error (nuisance profiled
    out), at most ``max_move`` per parameter (log units, or relative to its value), each
    kept only when it lowers the output error (else halved, up to 4 times), until the
    proposed step is within ``tol_se`` standard errors.  Never worse than ``theta``: every
    accepted step lowers the output error.

    Why: the output-error phase fits the linearisation r_a + J x; when the anchor is off the
    optimum, its optimum is a Gauss-Newton step away, computed with the anchor's (wrong)
    Jacobian, and the harvested ensemble is centred there -- biased by the nonlinearity and
    with a spread from the wrong J (a 3-DOF chain anchored 50 % off on a damping: ensemble
    +22 %, validation T ~ 1000).  At the optimum the step is ~0 and this costs one
    linearisation without replicates.  Deterministic (no random numbers)."""
    theta = np.asarray(theta, dtype=float).ravel().copy()
    lin = linearize(structure, theta, records, processing, fit_force_scale=fit_force_scale)
    for k in range(max_steps):
        x, size = gauss_newton_step(lin)
        if size <= tol_se:
            return Settled(theta, k, size, True)
        # a trust region: the linearisation says little about the output error more than
        # ``max_move`` (log units or relative) away; far steps are shortened to it
        x = x * min(1.0, max_move / max(float(np.max(np.abs(x))), 1e-300))
        for _ in range(5):
            cand = lin.to_theta(x).ravel()
            try:
                new = linearize(structure, cand, records, processing,
                                fit_force_scale=fit_force_scale)
            except ValueError:  # the simulation diverges there: a shorter step
                new = None
            if new is not None and np.isfinite(new.cost) and new.cost < lin.cost:
                break
            x = 0.5 * x
        else:
            return Settled(theta, k, size, False)
        theta, lin = cand, new
    x, size = gauss_newton_step(lin)
    return Settled(theta, max_steps, size, size <= tol_se)


__all__ = ["Linearization", "linearize", "Settled", "settle", "gauss_newton_step"]
