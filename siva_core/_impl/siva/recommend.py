"""SIVA's recommended value: Approach III's winner among the candidates, refined by the
output error through the processing chain (``recommend_best``, shared by ``Siva.fit`` and
the service)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .bounds import physical_candidates


@dataclass
class Recommendation:
    """What ``recommend_best`` found: the recommended ``theta`` (and its ``std``, None when
    the refinement was not run or not accepted), Approach III's winner, the output error of
    ``theta`` on the records (None without refinement) and a note for the user."""

    theta: np.ndarray
    std: np.ndarray | None
    note: str | None
    theta_III: np.ndarray
    output_error: float | None
    refined: bool
    refine_result: Any = None
    timing_s: dict[str, float] = field(default_factory=dict)

    def __iter__(self):  # ``theta, std, note = recommend_best(...)``
        return iter((self.theta, self.std, self.note))


def recommend_best(structure: Structure, candidates: Any, train: Sequence[Recording],
                   processing: Processing, *, refine: bool = True) -> Recommendation:
    """SIVA's recommended value from ensemble candidates (``Siva.fit`` and the service).

    Approach III: every candidate (rows of ``candidates``) is simulated on the raw training
    records in one batch and the one with the smallest displacement MSE wins.  Then
    ``best``: the output-error refinement (``refine.refine``) from that winner, through the
    same processing chain, kept only when it succeeded and does not raise the output error;
    otherwise ``best`` is the Approach III winner and ``std`` is None.

    Pure: reads its arguments, touches no trainer state or random generator.
    """
    from ..refine import displacement_mse, force_profiled_output_error, output_error
    from ..refine import refine as _refine
    from ..output_error import default_force_spread

    st = structure
    names = st.free
    train = list(train)
    cand = np.atleast_2d(np.asarray(candidates, dtype=float))
    if cand.size == 0 or not train:
        raise ValueError("recommend_best needs at least one candidate and one training record")
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    lo, hi = st.physical_bounds()
    moved = physical_candidates(cand, lo, hi, names)
    cand = moved.candidates
    mse = displacement_mse(st, cand, train, processing)
    theta_III = cand[int(np.nanargmin(mse))].copy() if np.isfinite(mse).any() else cand[-1].copy()
    timing["approach_III"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    best, best_std, note, oe, refined, res = theta_III.copy(), None, None, None, False, None
    if refine and not np.isfinite(mse).any():
        # nothing to refine from (e.g. Approach II's mean of a softening spring that runs
        # away): best stays the candidate, without interval, and says why
        note = "every candidate's simulation diverges on the training records: not refined"
    elif refine:
        # An impact's response scales with its impulse: with a force sensor and no
        # identified gain, one force multiplier per record is fitted as a nuisance
        # parameter so that sensor error is not absorbed by the structure's parameters.
        gains = [g for g in st.force_gains.values() if isinstance(g, str) and g in names]
        forced = all(r.has_force(st.dofs) for r in train)
        fit_scale = forced and not gains
        fit_spread = fit_scale and default_force_spread(st, theta_III, train)
        # The pulse's spread too when enabled (``output_error.FIT_FORCE_SPREAD_BY_DEFAULT``,
        # off: it fixed one structure and broke two, docs/perf.md 6.4) and identifiable.
        res = _refine(st, theta_III, train, processing, fit_force_scale=fit_scale,
                      fit_force_spread=fit_spread, bounds=(lo, hi))
        # judged by the cost the refinement minimised: with fitted force scales, start and
        # result each with their own (``force_profiled_output_error``)
        if fit_scale:
            c_ref = force_profiled_output_error(st, np.stack([theta_III, res.theta]), train,
                                                processing, fit_spread=fit_spread)
        else:
            c_ref = output_error(st, np.stack([theta_III, res.theta]), train, processing)
        if res.success and np.all(np.isfinite(res.theta)) and c_ref[1] <= c_ref[0]:
            # Gauss-Newton std, inflated for the correlation of filtered residuals
            best, best_std = res.theta, res.std  # block-bootstrap (sandwich) std
            oe, refined = float(c_ref[1]), True
            if res.force_scale is not None:
                note = ("best: fitted force scale per training record "
                        + ", ".join(f"{r.name}={f:.4f}"
                                    for r, f in zip(train, np.ravel(res.force_scale))))
        else:
            oe = float(c_ref[0])
            note = f"refinement did not improve on Approach III ({res.message})"
    timing["refine"] = time.perf_counter() - t0
    outside = [n for n, v, a, b in zip(names, best, lo, hi) if not a <= v <= b]
    if outside:  # cannot happen through the bounded refinement; a last guard all the same
        best = np.clip(best, lo, hi)
        note = ((note + "; ") if note else "") + (
            f"best: {', '.join(outside)} clipped to the physical bounds")
    if moved.names:
        note = ((note + "; ") if note else "") + (
            f"Approach III candidates with {', '.join(moved.names)} outside the physical "
            f"bounds (e.g. negative damping) were moved inside before choosing")
    return Recommendation(np.asarray(best, dtype=float), best_std, note, theta_III, oe, refined,
                          res, timing)


def rerefine(structure: Structure, best: np.ndarray, mean_II: np.ndarray,
             train: Sequence[Recording], val: Sequence[Recording],
             proc: Processing) -> Recommendation | None:
    """``recommend_best`` (fitted on the training records) from Approach II's mean, kept
    when it simulates training *and* validation records better than ``best``: the
    paper's Approach III selects "using identification data, validation data, or
    both": one training record can hold a wrong basin that the validation records
    expose (None otherwise)."""
    from ..refine import force_profiled_output_error, output_error

    # (Approach II's mean itself is not compared: its force scales were profiled out)
    recs = [*train, *val]
    if not np.all(np.isfinite(mean_II)):
        return None
    rec = recommend_best(structure, mean_II[None], train, proc)
    if not rec.refined:
        return None
    # with fitted force scales, each candidate is judged with its own per record (the
    # refinement's cost); plain output error would favour a basin that absorbs the
    # force's error
    scaled = rec.refine_result is not None and rec.refine_result.force_scale is not None
    judge = force_profiled_output_error if scaled else output_error
    kw = ({"fit_spread": rec.refine_result.force_spread is not None} if scaled else {})
    cost = judge(structure, np.stack([best, rec.theta]), recs, proc, **kw)
    return rec if np.isfinite(cost[1]) and cost[1] < 0.999 * cost[0] else None
