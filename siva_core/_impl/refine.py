"""Output-error refinement: fit parameters by simulating what was recorded.

Equation-error estimates (least squares, SINDy, SIVA's acceleration MSE) regress on states
that the processing chain produced, so they inherit the chain's bias (band-pass, high-pass
and decimation distort amplitude and phase; see the data README: b2 -68 %, k2 +32 % on
noise-free LO-NO accelerations).  Output error removes it: each record is *simulated* from
its force and initial state, the simulated signals are put into a Recording with the same
channels as the measured one, and that record goes through the *same* chain.  Whatever the
chain does to the measurement it also does to the simulation, so the comparison is fair.

What is simulated (``simulate.initial_state_and_force``): the whole raw record, from the
chain's derived state at its first sample, or from rest for a pre-triggered impact (a
zero-phase band-pass smears the impact backwards into that state), driven by the measured
force gated to its pulse (force-sensor noise between hits is not a force).  The chain is
then run on all parameter sets at once (``Processing.apply_simulated``), so a chain that
starts after the impact or decimates is handled like any other.

``refine`` minimises those residuals with ``scipy.optimize.least_squares`` (trust-region
reflective), the finite-difference Jacobian computed from one batched simulation of n+1
parameter sets, and reports the Gauss-Newton covariance.  What makes it converge from
starts 10-20 % off on strongly nonlinear records (see ``refine``): log-scaled parameters
and a growing fitting horizon; and, optionally, a per-record force scale as a nuisance
parameter for impact records, whose response is very sensitive to the impulse.
"""
from __future__ import annotations
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from .bootstrap import bootstrap_covariance, perturbation_solutions, series_of
from .ensemble import Z95
from .output_error import (OutputErrorProblem, _state_derived, displacement_mse,  # noqa: F401
                           force_profiled_output_error, output_error)
from .pulse_kick import KICK_BOUNDS, default_force_kick, kick_mask
from .processing import Processing
from .recording import Recording
from .simulate import OMEGA_H
from .replicates import noise_replicates

#: relative standard error below which no interval is reported (simulation accuracy)
NUMERICAL_REL_STD = 1e-6
#: a log-scaled parameter stays within this factor of theta0 (see ``_x_bounds``)
LOG_RANGE = 20.0
#: full-record cost below which theta0 is taken to be in the basin (no growing horizons):
#: a mean NMSE of 0.05 means no cycle has slipped anywhere in the records
HORIZON_SKIP_COST = 0.05


# ---------------------------------------------------------------------------- refine
@dataclass
class RefineResult:
    """Refined parameters with Gauss-Newton uncertainty.

    ``std``/``ci95``/``cov``: by default (``uncertainty="bootstrap"``) the moving-block
    bootstrap of the linearised fit at the optimum (``bootstrap.py``), which holds for the
    correlated residuals of filtered records and for misfit; ``std_gauss_newton`` is the
    textbook s^2 (J^T J)^-1 (independent residuals), kept for comparison, and
    ``ci_inflation`` the RMS ratio of the two.  ``jac``/``residuals``/``dtheta_dx``: the
    linearisation at the optimum in the fitted variables (theta, then nuisance).
    """

    theta: np.ndarray
    std: np.ndarray
    ci95: np.ndarray  # (n, 2)
    cov: np.ndarray
    cost: float
    nfev: int
    success: bool
    message: str
    njev: int = 0
    substeps: list[int] = field(default_factory=list)
    time_s: float = 0.0
    ci_inflation: float = 1.0
    names: list[str] = field(default_factory=list)
    force_scale: np.ndarray | None = None   # per record, when fit_force_scale
    force_shift: np.ndarray | None = None   # per record [samples], when fit_force_shift
    force_spread: np.ndarray | None = None  # per record [samples^2], when fit_force_spread
    force_kick: np.ndarray | None = None    # (n_records, 2, n_dof), when the kick is fitted
    stages: list[dict[str, Any]] = field(default_factory=list)
    std_gauss_newton: np.ndarray | None = None
    uncertainty: str = "bootstrap"
    block_length: int = 1
    stopped: bool = False  # ended by ``stop`` (a loser's fit cut short), not converged
    jac: np.ndarray | None = field(default=None, repr=False)
    residuals: np.ndarray | None = field(default=None, repr=False)
    dtheta_dx: np.ndarray | None = field(default=None, repr=False)

    @property
    def correlation(self) -> np.ndarray:
        """Parameter correlation matrix (e.g. alpha and beta of a power law trade off)."""
        s = np.sqrt(np.clip(np.diag(self.cov), 1e-300, None))
        return self.cov / np.outer(s, s)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """{name: {"mean", "std", "ci95"}}, the shape of the service's estimate."""
        return {n: {"mean": float(m), "std": float(s), "ci95": [float(lo), float(hi)]}
                for n, m, s, (lo, hi) in zip(self.names, self.theta, self.std, self.ci95)}


def refine(structure: Any, theta0: Any, records: Recording | Sequence[Recording],
           processing: Processing | None = None, *, max_nfev: int = 50,
           quantity: str | Sequence[str] = "auto", substeps: int | str | None = "auto",
           backend: str = "auto", force_gate: str | None = "auto", initial: str = "auto",
           interp: str | None = None, omega_h: float = OMEGA_H,
           horizons: Sequence[float] | str | None = "auto",
           log_scale: bool | str | Sequence[str] = "auto", fit_force_scale: bool = False,
           fit_force_shift: bool = False, fit_force_spread: bool = False,
           fit_force_kick: bool | str = "auto",
           bounds: tuple[np.ndarray, np.ndarray] | None = None,
           fit_initial: bool | str = "auto",
           fd_step: float = 1e-6, ftol: float = 1e-10, xtol: float = 1e-10,
           gtol: float = 1e-10, substep_margin: float = 1.25, verbose: int = 0,
           uncertainty: str = "bootstrap", n_boot: int = 400,
           stop: Callable[[int, bool, int, float, OutputErrorProblem], bool] | None = None
           ) -> RefineResult:
    """Output-error refinement from theta0 (e.g. SIVA's Approach III).

    Minimises the residuals of ``output_error`` with ``least_squares`` (TRF, bounds from the
    spec's lower/upper); the forward-difference Jacobian comes from ONE batched simulation of
    the n+1 parameter sets.  Covariance s^2 (J^T J)^-1 at the optimum, 95 % CI theta +-
    1.96 std.  The substeps are fixed from theta0 (x ``substep_margin``).

    Variables are relative to theta0: ``log_scale`` parameters as theta = theta0 exp(x)
    (sign kept, can't cross 0), the others as theta = theta0 + |theta0| x.  Log scaling turns
    the curved valleys of exponent-coupled parameters (alpha |d|^beta: alpha ~ d^-beta
    along the valley) into straight ones, which trust-region steps follow; "auto" = every
    parameter with theta0 != 0 whose spec bounds do not straddle 0; or a list of names.

    ``horizons``: fit growing leading parts of the records first.  Long oscillatory records
    have an output-error landscape with local minima once the start's phase error reaches
    ~half a period by the end (a Duffing start 5 % off gets stuck); a short horizon is
    benign and brings theta close enough for the next.  "auto": the full records only when
    theta0 already simulates them to a mean NMSE < 0.05 (no cycle slipped, the basin is
    reached); otherwise a first horizon of 2.5 oscillation cycles of the measured signal
    (zero crossings, at least 8 samples per variable), each next one 1.6x longer, up to the
    full records.  Or a list of fractions of the processed records; None = full only.
    ``max_nfev`` bounds the cost evaluations of the final (full) stage; earlier stages get
    ``max(5, max_nfev // 4)`` each.

    ``bounds``: (lower, upper) per free parameter instead of the spec's (e.g.
    :meth:`Structure.physical_bounds`).
    ``fit_force_scale``: also fit one force multiplier per record (a nuisance parameter,
    log-scaled from 1).  An impact's response depends so strongly on its impulse that 0.2 %
    force-sensor noise in the pulse (0.1 % impulse) moves a hardening record's late response
    by several %; without this the parameters absorb the error.
    ``fit_force_shift``: also fit one sub-sample delay of the force per record, within
    +-half a sample (a nuisance next to the multiplier).  Why: where a hammer pulse of a
    few samples falls between them shifts the estimates deterministically (chain4 c1 -5 %
    to +4 % with nothing else changed, docs/perf.md 6.3).
    ``fit_force_spread``: also fit a change of the force's spread (second moment) per
    record, within +-0.5 dt^2 (``simulate.grid.adjusted_stage_force``): the pulse's width
    between its samples, which its few samples leave undetermined.
    ``fit_force_kick``: also fit, per record that is one short hammer pulse, a kick at the
    pulse: an impulse (but on the hit DOF when the multiplier is fitted) and a doublet on
    every DOF (``output_error.force_kick_patterns``), i.e. the structure's state just after
    the pulse, which a pulse of few samples leaves undetermined (docs/perf.md 6.5).
    "auto": with ``fit_force_scale``, where ``output_error.force_kick_applicable``.
    ``fit_initial``: also fit offsets of each record's initial displacement and velocity
    (nuisance parameters, scaled by the record's state RMS).  "auto": for records without
    force whose displacement or velocity is derived rather than measured (a free decay
    recorded by accelerometers: its starting state is only known through integration).
    ``stop``: called after every iteration as ``stop(stage, last, iteration, cost,
    problem)`` (the stage's index, whether it is the full-record stage, the iteration
    within it, the cost on that stage's records, that stage's problem); True ends the
    refinement there (``stopped``; the remaining stages are skipped).  A caller comparing fits cuts short one that cannot win; without
    ``stop`` nothing changes (the same iterations, bit for bit).
    """
    t_start = time.perf_counter()
    theta0 = np.asarray(theta0, dtype=float).ravel()
    free = list(structure.free)
    if theta0.size != len(free):
        raise ValueError(f"theta0 has {theta0.size} values, the model has {len(free)} free "
                         f"parameters {free}")
    if not np.all(np.isfinite(theta0)):
        raise ValueError("theta0 must be finite")
    processing = processing or Processing()
    opts = dict(backend=backend, force_gate=force_gate, initial=initial, interp=interp,
                omega_h=omega_h)
    recs = [records] if isinstance(records, Recording) else list(records)
    if isinstance(substeps, (int, np.integer)):
        full = OutputErrorProblem.build(structure, recs, processing, quantity=quantity,
                                        substeps=int(substeps), **opts)
    else:
        full = OutputErrorProblem.build(structure, recs, processing, quantity=quantity,
                                        theta_ref=theta0[None], substeps="auto", **opts)
        ms = [max(1, math.ceil(r.substeps * substep_margin)) for r in full.records]
        for r, m in zip(full.records, ms):
            r.substeps = m
    n_rec = len(full.records)
    if fit_force_scale and not all(r.force is not None for r in full.records):
        raise ValueError("fit_force_scale needs a force column in every record")
    for flag, what in ((fit_force_shift, "fit_force_shift"), (fit_force_spread, "fit_force_spread")):
        if flag and not all(r.force is not None for r in full.records):
            raise ValueError(f"{what} needs a force column in every record")
        if flag and full.interp not in ("linear", "moments"):
            raise ValueError(f"{what} needs interp 'linear' or 'moments', got {full.interp!r}")

    # ---- variable map x <-> (theta, force scales)
    is_log = _log_mask(structure, free, theta0, log_scale)
    scale = np.where(theta0 != 0, np.abs(theta0), 1.0)
    for k, p in enumerate(free):
        if theta0[k] == 0 and structure.parameters[p].scale:
            scale[k] = structure.parameters[p].scale
    if bounds is not None:  # e.g. Structure.physical_bounds(): no negative damping
        lo_th, hi_th = (np.asarray(b, dtype=float).ravel() for b in bounds)
    else:
        lo_th = np.array([_bound(structure.parameters[p].lower, -np.inf) for p in free])
        hi_th = np.array([_bound(structure.parameters[p].upper, np.inf) for p in free])
    lower, upper = _x_bounds(theta0, scale, is_log, lo_th, hi_th)
    n_dof = structure.n_dof
    if fit_initial == "auto":
        fit_initial = all(r.force is None and _state_derived(r.rec, structure.dofs)
                          for r in full.records)
    n_fs = n_rec if fit_force_scale else 0
    n_sh = n_rec if fit_force_shift else 0
    n_sp = n_rec if fit_force_spread else 0
    n_ic = 2 * n_dof * n_rec if fit_initial else 0
    if fit_force_kick == "auto":
        fit_force_kick = fit_force_scale and default_force_kick(structure, full.records)
    if fit_force_kick and not any(r.kick_pulse is not None for r in full.records):
        raise ValueError("fit_force_kick needs a record whose force is one short pulse")
    # (record, kind, dof) of each fitted kick component
    kick_idx = (np.argwhere(np.stack([kick_mask(r, n_dof, fit_force_scale)
                                      for r in full.records]))
                if fit_force_kick else np.zeros((0, 3), dtype=int))
    n_kk = len(kick_idx)
    n_x = len(free) + n_fs + n_sh + n_sp + n_ic + n_kk
    if fit_force_scale:
        lower = np.concatenate([lower, np.full(n_rec, math.log(0.5))])
        upper = np.concatenate([upper, np.full(n_rec, math.log(2.0))])
    if fit_force_shift:  # delay in samples
        lower = np.concatenate([lower, np.full(n_rec, -0.5)])
        upper = np.concatenate([upper, np.full(n_rec, 0.5)])
    if fit_force_spread:  # change of the spread in samples^2
        lower = np.concatenate([lower, np.full(n_rec, -0.5)])
        upper = np.concatenate([upper, np.full(n_rec, 0.5)])
    ic_scale = np.zeros(0)
    if fit_initial:
        # offsets in units of each record's (processed) displacement / velocity RMS
        ic_scale = np.maximum(np.concatenate([r.state_rms for r in full.records]), 1e-300)
        lower = np.concatenate([lower, np.full(n_ic, -np.inf)])
        upper = np.concatenate([upper, np.full(n_ic, np.inf)])
    if n_kk:
        lower = np.concatenate([lower, [KICK_BOUNDS[kind][0] for _, kind, _ in kick_idx]])
        upper = np.concatenate([upper, [KICK_BOUNDS[kind][1] for _, kind, _ in kick_idx]])
    i_kk = len(free) + n_fs + n_sh + n_sp + n_ic

    def to_theta(X: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        Xp = X[:, :len(free)]
        th = np.where(is_log, theta0 * np.exp(np.where(is_log, Xp, 0.0)), theta0 + scale * Xp)
        extra: dict[str, np.ndarray] = {}
        if fit_force_scale:
            extra["force_scales"] = np.exp(X[:, len(free):len(free) + n_fs])
        if fit_force_shift:
            extra["force_shifts"] = X[:, len(free) + n_fs:len(free) + n_fs + n_sh]
        if fit_force_spread:
            i0 = len(free) + n_fs + n_sh
            extra["force_spreads"] = X[:, i0:i0 + n_sp]
        if fit_initial:
            ic = (X[:, len(free) + n_fs + n_sh + n_sp:i_kk] * ic_scale).reshape(len(X), n_rec, 2,
                                                                               n_dof)
            extra["dq0"], extra["dv0"] = ic[:, :, 0], ic[:, :, 1]
        if n_kk:
            kick = np.zeros((len(X), n_rec, 2, n_dof))
            kick[:, kick_idx[:, 0], kick_idx[:, 1], kick_idx[:, 2]] = X[:, i_kk:]
            extra["force_kicks"] = kick
        return th, extra

    x = np.zeros(n_x)
    x = np.clip(x, lower, upper)

    # ---- horizons
    fractions = _horizons(full, horizons, to_theta, x, n_x)
    nfev = njev = 0
    res = None
    stopped = False
    prob = full
    stages = []
    for stage, frac in enumerate(fractions):
        last = stage == len(fractions) - 1
        if last:
            prob = full
        else:
            prob = full.head([max(16, int(round(frac * len(r.target)))) for r in full.records])
        budget = max(5, max_nfev) if last else max(5, max_nfev // 4)
        halt = None if stop is None else _stage_stop(stop, stage, last, prob)
        res = _solve(prob, to_theta, x, lower, upper, budget, fd_step, ftol,
                     xtol if last else max(xtol, 1e-6), gtol, verbose, halt)
        nfev += res.nfev
        njev += res.njev or 0
        x = res.x
        stages.append({"fraction": frac, "nfev": int(res.nfev), "cost": float(2 * res.cost)})
        if res.status == -2:  # ``stop`` said so: the remaining stages are skipped
            stopped = True
            stages[-1]["stopped"] = True
            break
    assert res is not None
    th, extra = to_theta(res.x[None])
    theta = th[0]
    fsc = extra.get("force_scales")
    # d theta / d x at the optimum, then the Jacobian in theta (and nuisance) units
    dth = np.where(is_log, theta, scale)
    if fit_force_scale:
        dth = np.concatenate([dth, fsc[0]])
    if fit_force_shift:
        dth = np.concatenate([dth, np.ones(n_sh)])
    if fit_force_spread:
        dth = np.concatenate([dth, np.ones(n_sp)])
    if fit_initial:
        dth = np.concatenate([dth, ic_scale])
    if n_kk:
        dth = np.concatenate([dth, np.ones(n_kk)])
    # covariance in the well-scaled x variables, then to theta: cov = D cov_x D
    # (inverting J^T J in theta units would mix 1e7 and 1e0 scales and lose the small ones)
    r = res.fun
    dof = max(1, r.size - n_x)
    s2 = float(r @ r) / dof
    cov_gn = (s2 * _pinv_sym(res.jac.T @ res.jac) * np.outer(dth, dth))[:len(free), :len(free)]
    if uncertainty == "bootstrap":
        # two bootstraps of the linearised fit (nuisance columns included, so they are
        # profiled out), the wider per parameter: (1) moving blocks of (J, r) rows, a
        # sandwich covariance that holds for correlated and misfit residuals; (2)
        # parametric: force-sensor noise in the pulse propagated through the simulation
        # and the chain, plus measurement noise with the residuals' own spectrum
        series = series_of([rr.target.shape for rr in full.records])
        cov_x, block = bootstrap_covariance(res.jac, r, series, n_boot=n_boot, seed=0)
        E = noise_replicates(full, th, extra, r, series, n_rep=max(16, n_boot // 6))
        xp = perturbation_solutions(res.jac, E)
        cov_p = np.cov(xp, rowvar=False).reshape(n_x, n_x)
        cov = _wider((cov_x * np.outer(dth, dth))[:len(free), :len(free)],
                     (cov_p * np.outer(dth, dth))[:len(free), :len(free)])
    elif uncertainty == "gauss-newton":
        cov, block = cov_gn, 1
    else:
        raise ValueError(f"uncertainty must be 'bootstrap' or 'gauss-newton', got {uncertainty!r}")
    # never narrower than the simulator's own accuracy: on noise-free records the
    # statistical spread vanishes and RK4 vs the data's integrator differ by ~1e-7
    floor = NUMERICAL_REL_STD * np.abs(theta)
    cov = cov + np.diag(floor ** 2)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    std_gn = np.sqrt(np.clip(np.diag(cov_gn), 0, None))
    ci = np.stack([theta - Z95 * std, theta + Z95 * std], axis=1)
    with np.errstate(all="ignore"):
        ratio = np.where(std_gn > 0, std / std_gn, 1.0)
    return RefineResult(theta=theta, std=std, ci95=ci, cov=cov, cost=float(r @ r), nfev=nfev,
                        success=bool(res.success), message=str(res.message), njev=njev,
                        substeps=[rr.substeps for rr in full.records],
                        time_s=time.perf_counter() - t_start,
                        ci_inflation=float(np.sqrt(np.mean(ratio ** 2))), names=free,
                        force_scale=None if fsc is None else fsc[0], stages=stages,
                        force_shift=(None if "force_shifts" not in extra
                                     else extra["force_shifts"][0]),
                        force_spread=(None if "force_spreads" not in extra
                                      else extra["force_spreads"][0]),
                        force_kick=(None if "force_kicks" not in extra
                                    else extra["force_kicks"][0]),
                        std_gauss_newton=std_gn, uncertainty=uncertainty, block_length=block,
                        stopped=stopped, jac=res.jac, residuals=r, dtheta_dx=dth)


def _wider(c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """The covariance with the larger variance per parameter (correlations from it too)."""
    pick = np.diag(c1) >= np.diag(c2)
    s = np.sqrt(np.clip(np.where(pick, np.diag(c1), np.diag(c2)), 0, None))
    corr1 = c1 / np.sqrt(np.clip(np.outer(np.diag(c1), np.diag(c1)), 1e-300, None))
    corr2 = c2 / np.sqrt(np.clip(np.outer(np.diag(c2), np.diag(c2)), 1e-300, None))
    corr = np.where(np.outer(pick, pick), corr1, np.where(np.outer(~pick, ~pick), corr2,
                                                          0.5 * (corr1 + corr2)))
    return corr * np.outer(s, s)


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


def _horizons(prob: OutputErrorProblem, horizons: Sequence[float] | str | None,
              to_theta: Any, x0: np.ndarray, n_x: int) -> list[float]:
    if horizons is None:
        return [1.0]
    if isinstance(horizons, str):
        if horizons != "auto":
            raise ValueError(f"horizons must be 'auto', None or fractions, got {horizons!r}")
        th, extra = to_theta(x0[None])
        cost0 = float(np.sum(prob.residuals(th, **extra) ** 2))
        if np.isfinite(cost0) and cost0 < HORIZON_SKIP_COST:
            return [1.0]
        return _auto_horizons(prob, min_samples=8 * n_x)
    fr = sorted(float(f) for f in horizons)
    if not fr or not all(0 < f <= 1 for f in fr):
        raise ValueError(f"horizons must be fractions in (0, 1], got {horizons}")
    return fr if fr[-1] == 1.0 else fr + [1.0]


def _auto_horizons(prob: OutputErrorProblem, first_cycles: float = 2.5,
                   growth: float = 1.6, min_samples: int = 0) -> list[float]:
    """Fractions of the records holding 2.5, 4, 6.4, ... oscillation cycles of the measured
    signal (hysteresis zero crossings at 10 % of the peak, averaged over DOFs; the longest
    record decides).  Starting at a couple of cycles matters: a start 10 % off in a
    power-law exponent changes the nonlinear force 2.5x, and only the first cycles are
    then still in phase (LO-NO: a first horizon of 5 cycles already ends in a wrong
    minimum, 2.5 cycles does not).  Each horizon keeps at least ``min_samples`` samples
    after the signal's onset, so that every parameter has data to act on."""
    counts = []
    for r in prob.records:
        c = np.zeros(len(r.target))
        for k in range(r.target.shape[1]):
            c += _crossings(r.target[:, k]) / r.target.shape[1]
        counts.append(c)
    fractions: list[float] = []
    need = 2 * first_cycles
    while True:
        f = max(min(1.0, (max(int(np.searchsorted(c, need)),
                              int(np.searchsorted(c, 0.5)) + min_samples) + 1) / len(c))
                for c in counts)
        if f >= 0.75:
            break
        if not fractions or f >= fractions[-1] * 1.25:
            fractions.append(f)
        need *= growth
    return fractions + [1.0]


def _crossings(x: np.ndarray, level: float = 0.1) -> np.ndarray:
    """Cumulative count of zero crossings with hysteresis +-level*max|x| (noise-proof)."""
    thr = level * float(np.max(np.abs(x)))
    s = np.where(x > thr, 1, np.where(x < -thr, -1, 0))
    idx = np.flatnonzero(s)
    out = np.zeros(len(x))
    if idx.size < 2:
        return out
    flips = idx[1:][s[idx[1:]] != s[idx[:-1]]]
    out[flips] = 1
    return np.cumsum(out)


def _stage_stop(stop: Callable[[int, bool, int, float, OutputErrorProblem], bool],
                stage: int, last: bool, prob: OutputErrorProblem) -> Callable[[Any], None]:
    """``least_squares``' callback for one stage of ``refine`` (scipy stops the solver
    when it raises StopIteration; the argument must be named ``intermediate_result``)."""
    def halt(intermediate_result: Any) -> None:
        if stop(stage, last, int(intermediate_result.nit),
                2.0 * float(intermediate_result.cost), prob):
            raise StopIteration
    return halt


def _solve(prob: OutputErrorProblem, to_theta: Any, x0: np.ndarray, lower: np.ndarray,
           upper: np.ndarray, max_nfev: int, fd_step: float, ftol: float, xtol: float,
           gtol: float, verbose: int, callback: Callable[[Any], None] | None = None) -> Any:
    n = x0.size

    def evaluate(X: np.ndarray) -> np.ndarray:
        th, extra = to_theta(X)
        return prob.residuals(th, **extra)

    # the trust-region method asks for the Jacobian at the point whose residuals it just
    # had: those are reused as the Jacobian's base row (each set of a batch is simulated
    # and processed on its own, so the row is the same bit for bit)
    last: dict[str, np.ndarray] = {}

    def fun(x: np.ndarray) -> np.ndarray:
        r = evaluate(x[None])[0]
        last["x"], last["r"] = x.copy(), r.copy()
        return r

    def jac(x: np.ndarray) -> np.ndarray:
        h = np.full(n, fd_step)
        h = np.where(x + h > upper, -h, h)  # keep every probe feasible
        X = np.repeat(x[None], n + 1, axis=0)
        X[1:] += np.diag(h)
        if "x" in last and np.array_equal(last["x"], x):
            R = np.concatenate([last["r"][None], evaluate(X[1:])])
        else:
            R = evaluate(X)  # ONE batched simulation of the n+1 sets
        J = (R[1:] - R[0]).T / h
        J[~np.isfinite(J)] = 0.0
        return J

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise ValueError("refine: the simulation diverges at the start (non-finite residuals)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        kw = {} if callback is None else {"callback": callback}  # scipy >= 1.16
        return least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf",
                             x_scale=1.0, max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol,
                             verbose=verbose, **kw)


def _pinv_sym(A: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    tol = max(float(w.max()), 0.0) * A.shape[0] * np.finfo(float).eps
    inv = np.where(w > tol, 1.0 / np.where(w > tol, w, 1.0), 0.0)
    return (V * inv) @ V.T


__all__ = ["output_error", "force_profiled_output_error", "displacement_mse", "refine",
           "RefineResult", "OutputErrorProblem"]
