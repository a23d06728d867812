"""``refine``: the output-error fit of a model's parameters (and per-record nuisances) from
a start, over growing horizons, with the uncertainty of the result."""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Sequence

import numpy as np

from ..output_error import OutputErrorProblem, _state_derived
from ..processing import Processing
from ..pulse_kick import KICK_BOUNDS, default_force_kick, kick_mask
from ..recording import Recording
from ..simulate import OMEGA_H
from .horizons import _horizons
from .result import RefineResult
from .scaling import _bound, _log_mask, _x_bounds
from .solver import _solve, _stage_stop
from .uncertainty import refined_uncertainty


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
    every DOF (``pulse_kick.force_kick_patterns``), i.e. the structure's state just after
    the pulse, which a pulse of few samples leaves undetermined (docs/perf.md 6.5).
    "auto": with ``fit_force_scale``, where ``pulse_kick.force_kick_applicable``.
    ``fit_initial``: also fit offsets of each record's initial displacement and velocity
    (nuisance parameters, scaled by the record's state RMS).  "auto": for records without
    force whose displacement or velocity is derived rather than measured (a free decay
    recorded by accelerometers: its starting state is only known through integration).
    ``stop``: called after every iteration as ``stop(stage, last, iteration, cost,
    problem)`` (the stage's index, whether it is the full-record stage, the iteration
    within it, the cost on that stage's records, that stage's problem); True ends the
    refinement there (``stopped``; the remaining stages are skipped).  A caller comparing
    fits cuts short one that cannot win; without ``stop`` nothing changes (the same
    iterations, bit for bit).
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
    r = res.fun
    cov, std, std_gn, ci, ratio, block = refined_uncertainty(
        full, res, th, extra, dth, theta, len(free), n_x, uncertainty, n_boot)
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
