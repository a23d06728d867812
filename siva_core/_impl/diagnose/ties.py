"""Ties on the validation records broken on all records (issue 16, branch place): the
right law named at a neighbouring place, or its look-alike named at the right place.

A single verdict is the candidate with the lowest validation gap.  On the chain3 matrix
that gap often cannot tell the places apart: for the quadratic damper m2-ground (small)
the fits at m3-ground and m2-ground left 0.000177 and 0.000279, the true model itself
0.000202, all below the spectral noise floor 0.00033, and m3-ground was named.  The
validation records differ from the train records in amplitude, so a fit at a wrong place
that happens to extrapolate well wins by a difference the noise makes.

Validation guards against a model that fits the train records better only because it
has more freedom.  Candidates with the *same number of coefficients* (the same law at
two places, or two one-coefficient look-alike laws) have the same freedom, so their fit
to *all* the records is a fair comparison (a likelihood ratio at equal dimension) and
it uses twice the data.  So when fitted singles of the verdict's category and
coefficient count leave a validation gap within ``swap_noise`` x the spectral floor of
the verdict's (``swap.py``'s margin: the data cannot separate them there), the verdict
and the ``tie_contenders`` best of them by train cost are each refitted on train +
validation records from their own fit (``fit_nfev``, stopped early as a candidate fit
against the best refit so far), and the lowest residual over all records is named --
with its own train-only fit, validation closure and checks (``verdict.decide`` on it
alone, and its contribution above the noise), else the verdict stands.  A contender
whose residual over all records is not ``test_z`` standard errors above the named one's
(``set_test.gain_z`` on all records) is listed as its rival: the data cannot separate
them.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .early_stop import cannot_win
from .budget import clock_of
from .parallel import run_each, worker_count
from .outputs import Progress, _say
from .results import Candidate
from .set_members import below_noise, contributions, floor_for
from .without_member import KnownFits
from .set_test import gain_z, residual
from .settings import FAST, DiagnoseSettings
from .verdict import decide, look_alike


def contenders(verdict: Candidate, ranking: Sequence[Candidate], noise: float | None,
               settings: DiagnoseSettings) -> list[Candidate]:
    """The fitted singles the validation records cannot separate from ``verdict`` (gap
    within ``swap_noise`` x the spectral floor of its gap; 1 - ``separation`` of it
    without a floor) with as many coefficients, the ``tie_contenders`` lowest by train
    cost.  Also those whose train fit beats the verdict's by the ``separation`` ratio
    (the margin a validation lead needs): with equal freedom the train records speak as
    loudly as the validation ones, and when the two disagree only all records decide
    (fresh seed 17365: quadratic damper m2-ground train 0.0019, val 0.0089; the cubic
    damper named, train 0.0099, val 0.0062)."""
    if noise is not None and noise > 0:
        margin = settings.swap_noise * noise
    else:
        margin = (1.0 - settings.separation) * verdict.gap_after
    n = len(verdict.effect.coefficients)
    out = [c for c in ranking if c is not verdict and c.key != verdict.key and c.fitted
           and c.category == verdict.category and c.structure is not None
           and c.theta is not None and not c.reading and not c.stopped
           and len(c.effect.coefficients) == n and np.isfinite(c.gap_after)
           and np.isfinite(c.train_cost) and (c.gap_after - verdict.gap_after <= margin
                                               or c.train_cost <= settings.separation
                                               * verdict.train_cost)]
    out.sort(key=lambda c: c.train_cost)
    return out[:settings.tie_contenders]


def tied_look_alikes(fitted: Sequence[Candidate], lead: Candidate, noise: float | None,
                     settings: DiagnoseSettings) -> list[str]:
    """The look-alike kinds fitted at ``lead``'s place whose validation gap is within
    ``swap_noise`` x the spectral floor of its gap (1 - ``separation`` of it without a
    floor), the ``place_lookalikes`` lowest by train cost: the validation records cannot
    separate their laws from the leader's there, so their places are decided by fits too
    (``stage._stage``'s place check; the lono matrix's cubic damper LO-NO, small: the
    linear damper NO-ground led with 0.916, quadratic 0.907 and cubic 0.831 there, and
    the linear damper had no other place to be fitted at)."""
    if settings.place_lookalikes < 1:
        return []
    if noise is not None and noise > 0:
        margin = settings.swap_noise * noise
    else:
        margin = (1.0 - settings.separation) * lead.gap_after
    out = [c for c in fitted if c.fitted and not c.stopped and c is not lead
           and c.loc.between == lead.loc.between and c.effect.kind != lead.effect.kind
           and c.category == "structure" and look_alike(lead.effect.kind, c.effect.kind)
           and np.isfinite(c.gap_after) and np.isfinite(c.train_cost)
           and c.gap_after - lead.gap_after <= margin]
    out.sort(key=lambda c: c.train_cost)
    return list(dict.fromkeys(c.effect.kind for c in out))[:settings.place_lookalikes]


def undecided_places(more: Sequence[Candidate], fitted: Sequence[Candidate],
                     lead: Candidate, noise: float | None, settings: DiagnoseSettings
                     ) -> list[Candidate]:
    """The look-alike candidates of ``more`` (a kind tied with ``lead`` at its place, to be
    fitted at other places) whose place the fits of the leader's own law there have not
    decided against: kept unless ``lead``'s kind was fitted at that place and its gap
    there, less the tie margin (``swap_noise`` x the spectral floor; 1 - ``separation``
    of the leader's gap without one), is still separated from the leader's (the
    verdict's ``separation`` test) and its train fit does not beat the leader's by that
    ratio (``contenders``' train rule: with equal freedom the train records count too).

    Why (speed, issue 16 must-show 3): look-alike laws are the laws that produce nearly
    the same force over the measured amplitudes -- that is what ties them at the
    leader's place -- so at another place the look-alike fits about as well as the
    leader's law fitted there, within the same tie margin.  A place where the leader's
    law is separated even after that margin is decided, and fitting the look-alike
    there cannot rival the leader (measured, fresh seed 17480, 4-DOF frame: the
    quadratic damper m2-ground led at 0.0303, floor 0.0085; at the 9 other places it left
    0.040-0.085, and the cubic damper fitted there was at most 0.005 below it, within
    the margin; 9 fits of ~11 s each).
    Places where the leader's law was not fitted, or came within the margin, are kept."""
    if noise is not None and noise > 0:
        margin = settings.swap_noise * noise
    else:
        margin = (1.0 - settings.separation) * lead.gap_after
    same = {c.loc.between: c for c in fitted
            if c.fitted and c.effect.kind == lead.effect.kind and c is not lead
            and c.category == "structure" and np.isfinite(c.gap_after)
            and np.isfinite(c.train_cost)}

    def decided(c: Candidate) -> bool:
        f = same.get(c.loc.between)
        return bool(f is not None
                    and lead.gap_after <= settings.separation * (f.gap_after - margin)
                    and f.train_cost > settings.separation * lead.train_cost)
    return [c for c in more if not decided(c)]


def _refit_all(c: Candidate, records: Sequence[Recording], proc: Processing,
               settings: DiagnoseSettings, best: float,
               seen: list[tuple[int, bool, int, float]] | None = None
               ) -> tuple[Candidate, float, tuple[np.ndarray, list[int]]] | None:
    """``c`` refitted on ``records`` from its fit (a copy: ``c`` keeps its train-only
    fit), its residual energy there and the residual (``set_test.residual``, kept for the
    block test); None when it cannot be fitted or was stopped.  ``seen``: the fit is not
    stopped but every (stage, last, iteration, cost) its stop rule would see is kept
    there (``_stopped_at``)."""
    from ..refine import refine

    recs = c.correct(records)

    def keep(stage: int, last: bool, it: int, cost: float, prob: Any = None) -> bool:
        assert seen is not None
        seen.append((stage, last, it, cost))
        return False
    stop = cannot_win(best, settings) if seen is None else keep
    try:
        res = refine(c.structure, c.theta, recs, proc, max_nfev=settings.fit_nfev,
                     horizons=None, uncertainty=FAST, stop=stop)
    except Exception:  # noqa: BLE001 - a contender that cannot be refitted is none
        return None
    if bool(getattr(res, "stopped", False)):
        return None
    out = replace(c, theta=np.asarray(res.theta, float))
    r = residual(out, records, proc)
    if r is None:
        return None
    return out, float(r[0] @ r[0]), r


Fit = tuple[Candidate, Candidate, float, tuple[np.ndarray, list[int]]]


def _stopped_at(seen: Sequence[tuple[int, bool, int, float]], best: float,
                settings: DiagnoseSettings) -> bool:
    """Whether ``cannot_win(best)`` would have stopped a fit whose stop rule saw ``seen``
    (the fit is deterministic: stopped at the first of them it returns True on)."""
    stop = cannot_win(best, settings)
    return stop is not None and any(stop(*x) for x in seen)


def _refit_each(cands: Sequence[Candidate], records: Sequence[Recording],
                proc: Processing, settings: DiagnoseSettings) -> list[Fit]:
    """(single, refit, residual energy on all records, residual) of each of ``cands``
    refitted on all records, each stopped early against the best refit before it.

    Speed (issue 16 must-show 3, branch lonospeed): with more than one worker the refits
    run together, unstopped, each keeping what its stop rule saw; the rule is then
    replayed in order against the best refit before it, and a refit it would have
    stopped is dropped.  The refits are deterministic, so the result is the one of the
    refits run one after the other (with one worker they are, as before)."""
    clock = clock_of(settings)
    out: list[Fit] = []
    best = math.inf
    if worker_count(settings) <= 1 or len(cands) <= 1:
        for c in cands:
            got = clock.run("tie", f"{c.label()} on all records",
                            lambda c=c, best=best: _refit_all(c, records, proc, settings,
                                                              best))
            if got is not None:
                out.append((c, *got))
                best = min(best, got[1])
        return out
    seen: list[list[tuple[int, bool, int, float]]] = [[] for _ in cands]

    def one(k: int) -> tuple[Candidate, float, tuple[np.ndarray, list[int]]] | None:
        c = cands[k]  # the first is refitted as before: nothing to stop it against
        return clock.run("tie", f"{c.label()} on all records",
                         lambda: _refit_all(c, records, proc, settings, math.inf,
                                            None if k == 0 else seen[k]))
    for c, got, saw in zip(cands, run_each(one, range(len(cands)), worker_count(settings)),
                           seen):
        if got is not None and not _stopped_at(saw, best, settings):
            out.append((c, *got))
            best = min(best, got[1])
    return out


def break_tie(verdict: Candidate | None, verdicts: list[Candidate],
              ranking: Sequence[Candidate], train: Sequence[Recording],
              val: Sequence[Recording], proc: Processing, gap_before: float,
              noise_floor: float | None, noise: float | None, settings: DiagnoseSettings,
              rule: dict[str, Any], progress: Progress | None = None,
              known: KnownFits | None = None
              ) -> tuple[Candidate | None, list[Candidate]]:
    """The single structural verdict, or the contender that fits all records best (module
    doc); ``rule["tie"]`` says what was compared.  A set, a sensor fault or no verdict is
    returned as it is."""
    if (verdict is None or len(verdicts) != 1 or verdicts[0] is not verdict
            or verdict.category != "structure" or settings.tie_contenders < 1
            or verdict.structure is None or verdict.theta is None):
        return verdict, verdicts
    rivals = contenders(verdict, ranking, noise, settings)
    if not rivals:
        return verdict, verdicts
    t0 = time.perf_counter()
    records = [*train, *val]
    # (single, refit, residual energy on all records, residual)
    fits = _refit_each([verdict, *rivals], records, proc, settings)
    entry: dict[str, Any] = {
        "compared": [{"candidate": c.label(), "gap": float(c.gap_after),
                      "train_cost": float(c.train_cost), "all_records": g}
                     for c, _, g, _ in fits]}
    rule["tie"] = entry
    if not fits:
        return verdict, verdicts
    fits.sort(key=lambda f: f[2])
    win, _, win_gap, _ = fits[0]
    new = verdict
    if win is not verdict:
        ok, _ = decide([win], gap_before, noise_floor, settings)
        contrib = contributions(win, val, proc, known)
        x = contrib[0] if contrib else math.inf
        if ok is not None and not below_noise(x, floor_for(win, noise), settings):
            new = win
            entry["named"] = {"from": verdict.label(), "to": win.label()}
            _say(progress, f"tie: {win.label()} fits all records best "
                           f"({win_gap:.4g} against {verdict.label()}'s "
                           + ", ".join(f"{g:.4g}" for c, _, g, _ in fits if c is verdict)
                           + ")")
        else:
            entry["refused"] = win.label()
    ref = next(f for f in fits if f[0] is new)
    z_of = {}
    tied = []
    for c, _, g, res in fits:
        if c is new:
            continue
        z = gain_z(res, ref[3], settings.test_blocks)
        z_of[c.label()] = round(float(z), 2) if np.isfinite(z) else None
        if not z >= settings.test_z:
            tied.append({"candidate": c.label(), "closure": float(c.closure),
                         "all_records": g})
    entry["z"] = z_of
    entry["seconds"] = time.perf_counter() - t0
    if new is not verdict:
        new.rivals = [r for r in new.rivals if r["candidate"] != verdict.label()]
        new.closure_added = float(new.closure)
        new.contribution = float(x)
        rule["combined_closure"] = float(new.closure)
        rule["reason"] = (f"{new.label()} fits all records best "
                          f"({ref[2]:.4g} against {verdict.label()}'s "
                          + ", ".join(f"{g:.4g}" for c, _, g, _ in fits if c is verdict)
                          + f"), with as many coefficients; the validation records alone "
                          f"do not decide (gaps {new.gap_after:.4g} and "
                          f"{verdict.gap_after:.4g}; train {new.train_cost:.4g} and "
                          f"{verdict.train_cost:.4g}; noise floor "
                          + (f"{noise:.3g})" if noise else "unknown)"))
    listed = {r["candidate"] for r in new.rivals}
    new.rivals = [*new.rivals, *(r for r in tied if r["candidate"] not in listed)]
    if tied:
        rule["reason"] = (f"{rule.get('reason') or 'all checks pass'}; the data cannot "
                          f"separate {new.label()} from "
                          + ", ".join(r["candidate"] for r in tied)
                          + f" (all records, z < {settings.test_z:g})")
    return new, [new]
