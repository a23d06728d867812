"""Candidate fits (step 4): nominal + one effect by output error on the train records."""
from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np

from ..effects import Amplitudes
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .model_edit import augmented
from .nominal import _plausible
from .results import Candidate
from .early_stop import StopRule, cannot_win
from .settings import FAST, DiagnoseSettings


#: magnitudes of the coarse scan, as fractions of the effect's "typical" magnitude (the
#: one whose force equals the structure's inertial force at the largest amplitude seen):
#: an unmodelled effect is rarely larger, and below 1e-4 of it is invisible in the data
SCAN_FRACTIONS = tuple(float(x) for x in np.logspace(-4.0, -0.5, 8))


def _batches(c: Candidate, aug: Structure, names: dict[str, str], theta_nom: np.ndarray,
             structure: Structure, amp: Amplitudes, force_scale: float,
             fractions: Sequence[float] = SCAN_FRACTIONS) -> list[np.ndarray]:
    """Start sets of the coarse scan: for each shape of the effect's grid, the magnitude on
    a log grid (both signs when the coefficient is unsigned), nominal parameters at the
    nominal fit.  One batch per shape and sign (a batch takes the substeps of its stiffest
    set)."""
    eff = c.effect
    nominal_values = structure.as_dict(theta_nom)
    signs = (1.0,) if eff.magnitude in eff.positive else (1.0, -1.0)
    if c.admissible and c.estimate < 0 and len(signs) == 2:
        signs = (-1.0, 1.0)
    out = []
    for shape in eff.shape_grid(amp):
        typical = eff.typical_magnitude(amp, shape, force_scale)
        mags = [f * typical for f in fractions]
        for sign in signs:
            batch = []
            for m in mags:
                vals = dict(nominal_values)
                vals.update({names[k]: v for k, v in shape.items()})
                vals[names[eff.magnitude]] = sign * m
                batch.append(aug.vector(vals))
            out.append(np.stack(batch))
    return out


#: scan sets are simulated in groups whose stiffness at rest differs by less than this
#: factor (a batch takes the substeps of its stiffest set)
SCAN_GROUP_RATE = 4.0


def _rate_groups(aug: Structure, batch: np.ndarray) -> list[np.ndarray]:
    """Indices of ``batch`` in groups of similar stiffness: each set's fastest rate at
    rest (the tangent of every element there: a dry friction's smoothing, a damper's
    slope), bucketed by factors of ``SCAN_GROUP_RATE``.  A log-spaced magnitude scan
    spans 3.5 decades; simulated as one batch, its weakest sets ran at the substeps of
    the strongest (measured: a coulomb scan on LO-NO, 6-7 s of a 50 s diagnosis).  Each
    group still gets its own substeps from the usual pilot, so every set is simulated to
    the simulator's accuracy target."""
    from ..simulate.substeps import _max_rate

    n = aug.n_dof
    rest = np.zeros((1, 1, n))
    with np.errstate(all="ignore"):
        rates = np.array([_max_rate(aug, th[None], rest, rest) for th in batch])
    if not np.all(np.isfinite(rates)) or not np.all(rates > 0):
        return [np.arange(len(batch))]
    bucket = np.floor(np.log(rates / rates.min()) / math.log(SCAN_GROUP_RATE)).astype(int)
    return [np.flatnonzero(bucket == b) for b in np.unique(bucket)]


def _scan_residuals(aug: Structure, train: Sequence[Recording], proc: Processing,
                    batch: np.ndarray) -> np.ndarray | None:
    """Residuals of a scan batch, simulated in groups of similar stiffness
    (``_rate_groups``)."""
    groups = _rate_groups(aug, batch)
    if len(groups) == 1:
        return _group_residuals(aug, train, proc, batch)
    parts = [(idx, _group_residuals(aug, train, proc, batch[idx])) for idx in groups]
    n = next((R.shape[1] for _, R in parts if R is not None), 0)
    if n == 0:
        return None
    out = np.full((len(batch), n), np.nan)
    for idx, R in parts:
        if R is not None and R.shape[1] == n:
            out[idx] = R
    return out


def _group_residuals(aug: Structure, train: Sequence[Recording], proc: Processing,
                     batch: np.ndarray) -> np.ndarray | None:
    """Residuals of a batch of scan sets; when the batch fails or diverges as a whole (one
    unstable set can spoil a shared integration), each set alone."""
    from .outputs import _Outputs

    try:
        R = _Outputs(aug, train, proc, batch).residuals(batch)
        if np.all(np.isfinite(R)):
            return R
    except Exception:  # noqa: BLE001 - retried set by set below
        R = None
    rows = []
    for th in batch:
        try:
            rows.append(_Outputs(aug, train, proc, th[None]).residuals(th[None])[0])
        except Exception:  # noqa: BLE001 - this set is unusable
            rows.append(None)
    n = next((len(r) for r in rows if r is not None), 0)
    if n == 0:
        return None
    return np.stack([r if r is not None and len(r) == n else np.full(n, np.nan)
                     for r in rows])


def scan_candidate(c: Candidate, structure: Structure, theta_nom: np.ndarray,
                   train: Sequence[Recording], proc: Processing, amp: Amplitudes,
                   force_scale: float, jacobian: np.ndarray | None = None,
                   basis: np.ndarray | None = None) -> None:
    """Coarse 1-D scan of the candidate's magnitude (in log-magnitude, every shape of its
    grid) at the nominal parameters: the train cost of the best point and that point as a
    fit start (in place: ``scan_cost``, ``scan_theta``, ``structure``, ``names``).

    The screening score is a linearisation at zero magnitude: it can rank the true law below
    a look-alike, and its estimate can be far from the optimum when the effect is strong.
    The scan costs one batched simulation per shape and sign and brings every family's fit
    start within a factor ~3 of its optimum, so the local fit no longer stalls.

    With the nominal Jacobian (``jacobian``, ``basis`` from the screening) each point is
    costed after a linearised re-tune of the nominal parameters (the residual projected off
    their column space: the nominal fit has absorbed part of the effect, e.g. a missing
    damper into the existing dampers, so at fixed nominal parameters the true magnitude
    looks worse than none) and the start gets that Gauss-Newton step too."""

    eff = c.effect
    floor = eff.typical_magnitude(amp, c.shape, force_scale)
    scales = {**{k: max(abs(v), 1e-12) for k, v in c.shape.items()},
              eff.magnitude: max(abs(c.estimate), floor * 1e-3, 1e-300)}
    aug, names = augmented(structure, eff, c.loc, scales)
    c.structure, c.names = aug, names
    best, th0 = math.inf, None
    n_nom = theta_nom.size
    for batch in _batches(c, aug, names, theta_nom, structure, amp, force_scale):
        R = _scan_residuals(aug, train, proc, batch)
        if R is None:
            continue
        ok = np.all(np.isfinite(R), axis=1)
        if basis is not None and jacobian is not None and basis.shape[0] == R.shape[1]:
            Rp = R - (R @ basis) @ basis.T
        else:
            Rp = R
        costs = np.where(ok, np.sum(Rp ** 2, axis=1), math.inf)
        k = int(np.argmin(costs))
        if costs[k] < best:
            best, th0 = float(costs[k]), batch[k].copy()
            c.scan_raw = batch[k].copy()
            if jacobian is not None and Rp is not R:
                delta, *_ = np.linalg.lstsq(jacobian, -R[k], rcond=None)
                th0[:n_nom] += delta[:n_nom]  # nominal parameters come first in aug
    c.scan_cost, c.scan_theta = best, th0


def fit_candidate(c: Candidate, structure: Structure, theta_nom: np.ndarray,
                  train: Sequence[Recording], proc: Processing, amp: Amplitudes,
                  settings: DiagnoseSettings, force_scale: float,
                  nominal_cost: float = math.inf, leader_cost: float = math.inf,
                  leader: Candidate | None = None, base_cost: float = math.nan) -> None:
    """Fit nominal + candidate by output error on the train records (in place).

    Starts: the nominal fit with the new magnitude at a few multiples of the score test's
    estimate, and the joint equation-error solution when there is one; each start is
    costed, the best is refined (growing horizons: a new element shifts the phase late in
    long records, where the landscape has local minima).  The magnitude scan's best point
    (``scan_candidate``) is the start when there is no other, and a second start when the
    first fit stalls (train cost above ``settings.stalled`` x the nominal one): measured,
    a scan start taken whenever it costs least led refine to a worse basin (quadratic
    damper c2 = 2.2 instead of 3.96), so it is a fallback, not a rival.

    ``leader_cost``: the best train cost fitted so far in this stage (``leader``: the
    structural candidate with the best one); a fit that cannot come near it is cut short
    (``cannot_win``; ``c.stopped``); ``base_cost``: the stage's starting train cost when
    the stage builds on an earlier effect (``early_stop.gain_limit``)."""
    from ..refine import output_error, refine

    t0 = time.perf_counter()
    eff = c.effect
    if c.structure is None or not c.names:
        floor = eff.typical_magnitude(amp, c.shape, force_scale)
        ref_mag = c.estimate if c.estimate != 0 else \
            (c.ee_start[1][eff.magnitude] if c.ee_start else floor)
        scales = {**{k: max(abs(v), 1e-12) for k, v in (c.shape or c.ee_shape).items()},
                  eff.magnitude: max(abs(ref_mag), floor * 1e-3, 1e-300)}
        c.structure, c.names = augmented(structure, eff, c.loc, scales)
    aug, names = c.structure, c.names
    floor = eff.typical_magnitude(amp, c.shape, force_scale)
    fs = min(r.fs for r in train)
    scan_starts = [np.asarray(t, float) for t in (c.scan_theta, c.scan_raw)
                   if t is not None and _plausible(aug, np.asarray(t, float), fs)]
    groups: list[np.ndarray] = []
    if c.admissible and c.estimate != 0:
        nominal_values = structure.as_dict(theta_nom)
        batch = []
        for m in eff.starts(c.estimate, floor):
            vals = dict(nominal_values)
            vals.update({names[k]: v for k, v in c.shape.items()})
            vals[names[eff.magnitude]] = m
            batch.append(aug.vector(vals))
        groups.append(np.stack(batch))
    if c.ee_start is not None:
        nominal_ee, coeffs_ee = c.ee_start
        th_ee = aug.vector({**nominal_ee, **{names[k]: v for k, v in coeffs_ee.items()}})
        if _plausible(aug, th_ee, min(r.fs for r in train)):
            groups.append(th_ee[None])
    if not groups and scan_starts:
        groups.append(np.stack(scan_starts))
        scan_starts = []
    if not groups:
        raise ValueError("no admissible start (negative magnitude for a signed effect)")
    best_cost, th0 = math.inf, None
    for batch in groups:  # separately: a batch takes the substeps of its stiffest set
        try:
            costs = output_error(aug, batch, list(train), proc)
        except Exception:  # noqa: BLE001 - a start that cannot be simulated is skipped
            continue
        k = int(np.argmin(costs))
        if costs[k] < best_cost:
            best_cost, th0 = float(costs[k]), batch[k]
    if th0 is None:
        raise ValueError("every start diverges")
    stop = cannot_win(leader_cost, settings, leader, train, proc, base_cost)
    res = refine(aug, th0, list(train), proc, max_nfev=settings.fit_nfev,
                 uncertainty=FAST, stop=stop)
    c_ref = float(output_error(aug, res.theta[None], list(train), proc)[0])
    j = aug.free.index(names[eff.magnitude])
    scan_starts = [t for t in scan_starts if not _near(t[j], res.theta[j])]
    if scan_starts and not c_ref <= settings.stalled * nominal_cost:
        # stalled: the local fit from the score-test starts barely beat the nominal model
        # (a strong effect: the linearisation at the nominal fit points the wrong way);
        # start again from the magnitude scan and keep the better fit
        try:
            costs = output_error(aug, np.stack(scan_starts), list(train), proc)
            k = int(np.argmin(costs))
            res2 = refine(aug, scan_starts[k], list(train), proc,
                          max_nfev=settings.fit_nfev, uncertainty=FAST, stop=stop)
            c2 = float(output_error(aug, res2.theta[None], list(train), proc)[0])
            if c2 < c_ref:
                res, c_ref = res2, c2
                c.note = "fit restarted from the magnitude scan"
        except Exception:  # noqa: BLE001 - the first fit stands
            pass
    theta, cost = (res.theta, c_ref) if c_ref <= best_cost else (th0, best_cost)
    c.theta = theta
    vals = aug.as_dict(theta)
    c.coefficients = {k: vals[p] for k, p in names.items()}
    c.parameters = {p: vals[p] for p in structure.free}
    c.intervals = _intervals(res, aug, names) if c_ref <= best_cost else {}
    c.train_cost = cost
    c.fitted = True
    c.stopped = bool(res.stopped)
    if c.stopped:
        c.note = ((c.note + "; ") if c.note else "") + (
            f"fit stopped early: train cost {cost:.3g} > {settings.stop_ratio:g} x the "
            f"leader's {leader_cost:.3g}" if not np.isfinite(base_cost) else
            f"fit stopped early: train cost {cost:.3g}, less than 1/{settings.stop_ratio:g} "
            f"of the leader's gain from {base_cost:.3g} to {leader_cost:.3g}")
    c.fit_time_s = time.perf_counter() - t0


def continue_fit(c: Candidate, train: Sequence[Recording], proc: Processing,
                 nfev: int, stop: StopRule | None = None) -> None:
    """More evaluations for a finalist of the first, cheaper round of fits: refine from
    its fit on the full records (no horizons: it is in its basin already); kept when the
    train cost improves.  ``stop``: ``cannot_win`` against the leader (a finalist kept
    as the leader's rival of another kind may sit far above it)."""
    from ..refine import output_error, refine

    if c.structure is None or c.theta is None or nfev <= 0:
        return
    t0 = time.perf_counter()
    recs = list(c.correct(train))
    res = refine(c.structure, c.theta, recs, proc, max_nfev=nfev, horizons=None,
                 uncertainty=FAST, stop=stop)
    cost = float(output_error(c.structure, res.theta[None], recs, proc)[0])
    if res.stopped:
        c.stopped = True
        c.note = ((c.note + "; ") if c.note else "") + "second round stopped early"
    if cost < c.train_cost:
        c.theta, c.train_cost = res.theta, cost
        vals = c.structure.as_dict(res.theta)
        if c.category == "structure" and c.names:
            c.coefficients = {k: vals[p] for k, p in c.names.items()}
            c.intervals = _intervals(res, c.structure, c.names)
            c.parameters = {p: v for p, v in vals.items() if p not in c.names.values()}
        else:
            c.parameters = vals
    c.fit_time_s += time.perf_counter() - t0


def bootstrap_intervals(c: Candidate, train: Sequence[Recording], proc: Processing) -> None:
    """The named effect's 95 % intervals with refine's bootstrap (the fits inside the
    diagnosis use Gauss-Newton only, see ``settings.FAST``): a refine started at the fit's
    optimum on the full records, a few evaluations, its theta not taken (the verdict stays
    the one the validation records judged)."""
    from ..refine import refine

    if c.category != "structure" or c.structure is None or c.theta is None or not c.names:
        return
    res = refine(c.structure, c.theta, list(c.correct(train)), proc, max_nfev=5,
                 horizons=None)
    c.intervals = _intervals(res, c.structure, c.names)


def _near(a: float, b: float, factor: float = 3.0) -> bool:
    """Same sign and within ``factor`` of each other (a restart from there is no news)."""
    return a * b > 0 and max(abs(a), abs(b)) <= factor * min(abs(a), abs(b))


def _intervals(res: Any, aug: Structure, names: dict[str, str]
               ) -> dict[str, tuple[float, float]]:
    """95 % intervals of the new coefficients: refine's Gauss-Newton std inflated by its
    residual-correlation factor (filtered, decimated records have correlated residuals)."""
    out: dict[str, tuple[float, float]] = {}
    rnames = list(getattr(res, "names", []) or aug.free)
    for k, p in names.items():
        if p not in rnames:
            continue
        j = rnames.index(p)
        half = 1.96 * float(res.std[j]) * float(getattr(res, "ci_inflation", 1.0) or 1.0)
        if np.isfinite(half):
            out[k] = (float(res.theta[j] - half), float(res.theta[j] + half))
    return out
