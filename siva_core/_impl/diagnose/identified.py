"""Is the validation gap the nominal model's own unidentified parameter?

A nominal model with a nonlinear element (a cubic spring, ...) fitted on small-amplitude
train records may leave that element's coefficient unidentified: the train records barely
move it, so its estimate is anywhere in a wide interval, and larger validation records then
show a gap that any flexible candidate "explains" (fresh seed 17517, a null: the nominal
cubic spring's k3 was unidentified by 8 and 16 N train hits; the 132 N validation hit left
a gap 52 x the noise floor that a clearance closed 0.97 of).  A gap is evidence for a
missing effect only when it survives every value of the nominal parameters the train
records allow: each free nonlinear coefficient is pinned at points of its 95 % interval
(from the train records alone), the other parameters refitted on the train records, and
the lowest validation gap of these refits is the gap a candidate must still close.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .nominal import nonlinear_params
from .outputs import Progress, _say
from .parallel import run_each, worker_count
from .scoring import validation_gap
from .settings import FAST, DiagnoseSettings


@dataclass
class PinnedGap:
    """The nominal model refitted with one coefficient pinned inside its interval."""

    param: str
    interval: tuple[float, float]
    value: float          # where it was pinned (the lowest validation gap)
    train_cost: float     # the refit's train cost
    gap: float            # its validation gap
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)  # every
    # nonlinear coefficient's 95 % interval from the train records

    def describe(self, estimate: float, gap_before: float) -> str:
        lo, hi = self.interval
        return (f"parameter {self.param} of the nominal model is not identified by the "
                f"train records (estimate {estimate:.3g}, 95 % interval [{lo:.3g}, "
                f"{hi:.3g}]): pinned at {self.value:.3g} within it and the rest refitted on "
                f"the train records (train cost {self.train_cost:.3g}), the validation gap "
                f"falls from {gap_before:.3g} to {self.gap:.3g}")


def pinned(structure: Structure, param: str, value: float) -> Structure:
    """``structure`` with ``param`` fixed at ``value`` (no longer free)."""
    info = structure.parameters[param]
    return replace(structure, parameters={**structure.parameters,
                                          param: replace(info, fixed=float(value))})


def _intervals(structure: Structure, theta: np.ndarray, train: Sequence[Recording],
               proc: Processing) -> tuple[dict[str, tuple[float, float]], float]:
    """95 % intervals of the free parameters from the train records (refine's bootstrap,
    which accounts for the correlated residuals of filtered records; a few evaluations
    from the nominal optimum, its theta not taken), and the rise of the train cost that
    the same 95 % level allows on one parameter's profile: 1.96^2 s^2 with s^2 = cost /
    (n - p), inflated by the median bootstrap / Gauss-Newton ratio squared (the residuals of
    filtered, decimated records are correlated: fewer independent samples than n)."""
    from ..refine import refine

    res = refine(structure, theta, list(train), proc, max_nfev=3, horizons=None)
    names = list(getattr(res, "names", []) or structure.free)
    out: dict[str, tuple[float, float]] = {}
    for j, p in enumerate(names):
        half = 1.96 * float(res.std[j])
        if np.isfinite(half):
            v = float(theta[structure.free.index(p)])
            out[p] = (v - half, v + half)
    n = res.residuals.size if getattr(res, "residuals", None) is not None else 0
    infl = _median_inflation(res)
    rise = 1.96 ** 2 * float(res.cost) / (n - len(names)) * infl ** 2 \
        if n > len(names) else 0.0
    return out, rise


def _median_inflation(res: Any) -> float:
    """The median of the per-parameter bootstrap / Gauss-Newton std ratios: the
    residuals' correlation is one property of the records, and refine's ``ci_inflation``
    (their RMS) lets one degenerate parameter make it astronomic (fresh seed 17866: 1.6e19
    on the plain nominal, so every pinned point passed whatever its train cost)."""
    std, gn = getattr(res, "std", None), getattr(res, "std_gauss_newton", None)
    if std is None or gn is None:
        return float(getattr(res, "ci_inflation", 1.0) or 1.0)
    std, gn = np.asarray(std, float), np.asarray(gn, float)
    ok = np.isfinite(std) & np.isfinite(gn) & (gn > 0)
    return float(np.median(std[ok] / gn[ok])) if ok.any() else 1.0


def _refit(structure: Structure, theta: np.ndarray, param: str, value: float,
           train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
           settings: DiagnoseSettings) -> tuple[float, float]:
    """(train cost, validation gap) of the nominal refitted on ``train`` with ``param``
    pinned at ``value``; infinite when it cannot be simulated."""
    from ..refine import output_error, refine

    st = pinned(structure, param, value)
    th0 = np.array([theta[k] for k, p in enumerate(structure.free) if p != param])
    try:
        res = refine(st, th0, list(train), proc, max_nfev=max(5, settings.nominal_nfev // 4),
                     uncertainty=FAST, horizons=None)
        cost = float(output_error(st, res.theta[None], list(train), proc)[0])
        gap = validation_gap(st, res.theta, val, proc)[0]
    except Exception:  # noqa: BLE001 - a pinned value that diverges is not admissible
        return math.inf, math.inf
    return cost, float(gap)


def _parabola_min(xs: Sequence[float], ys: Sequence[float]) -> float | None:
    """The minimum of the parabola through three points, None when it opens downward.
    Fitted in centred, scaled coordinates: an interval of +-6.5e13 (dev seed 25612, an
    unidentified knl) made the raw Vandermonde matrix fail its SVD and sank the run."""
    x = np.asarray(xs, float)
    mid, half = float(x.mean()), float(np.ptp(x)) / 2 or 1.0
    try:
        a, b, _ = np.polyfit((x - mid) / half, np.asarray(ys, float), 2)
    except (np.linalg.LinAlgError, ValueError):
        return None
    return float(mid - half * b / (2 * a)) if a > 0 else None


def lowest_pinned_gap(structure: Structure, theta: np.ndarray, train_cost: float,
                      gap_before: float, train: Sequence[Recording],
                      val: Sequence[Recording], proc: Processing,
                      settings: DiagnoseSettings, progress: Progress | None = None,
                      wider: dict[str, tuple[float, float]] | None = None
                      ) -> PinnedGap | None:
    """The nonlinear coefficient whose pinning (inside its train interval, the rest
    refitted on train) lowers the validation gap most, or None when none lowers it.

    The points: both ends of the interval, zero (the element absent) and the estimate's
    mirror (a cubic coefficient's sign is what small records see least: fresh seed 17517's
    nominal fit found the other sign at the same train cost), then the minimum of the
    parabola of validation gap against the pinned value through (low end, estimate, high
    end) when inside.  A point counts when its refit's train cost rises by less than the
    profile's 95 % threshold (``_intervals``): the train records cannot exclude it.

    ``wider``: intervals of the same coefficients from another fit of the same train
    records (the plain nominal's, for the nominal with a nuisance gain), each interval
    taken as the hull of both: refine's steps are relative to the value, so a coefficient
    a fit left near zero (fresh seed 17866: knl -15 N/m^3 where the nominal's is -2.3e6)
    gets a vanishing interval however unidentified it is."""
    params = [p for p in nonlinear_params(structure) if p in structure.free]
    if not params or not np.isfinite(gap_before):
        return None
    try:
        ints, tol = _intervals(structure, theta, train, proc)
    except Exception as exc:  # noqa: BLE001 - no interval, no check
        _say(progress, f"nominal identification: intervals failed ({exc})")
        return None
    for p, (lo, hi) in (wider or {}).items():
        if p in ints:
            ints[p] = (min(ints[p][0], lo), max(ints[p][1], hi))
    params = [p for p in params if p in ints]
    workers = worker_count(settings)

    def refit(pv: tuple[str, float]) -> tuple[float, float]:
        return _refit(structure, theta, pv[0], pv[1], train, val, proc, settings)

    # the fixed points of every parameter are independent refits: they run together on
    # the workers (the same values in the same order whatever the worker count); a dict
    # keeps each distinct value once (0 and -0.0 are one point)
    points = {p: list(dict.fromkeys((ints[p][0], ints[p][1], 0.0,
                                     -float(theta[structure.free.index(p)]))))
              for p in params}
    flat = [(p, v) for p in params for v in points[p]]
    tried_all: dict[str, dict[float, tuple[float, float]]] = {p: {} for p in params}
    for (p, v), out in zip(flat, run_each(refit, flat, workers)):
        tried_all[p][v] = out
    # then the parabola's minimum of each, which needs the ends' gaps
    extra: list[tuple[str, float]] = []
    for p in params:
        lo, hi = ints[p]
        est = float(theta[structure.free.index(p)])
        ys = [tried_all[p][lo][1], gap_before, tried_all[p][hi][1]]
        if all(np.isfinite(ys)):
            m = _parabola_min([lo, est, hi], ys)
            if m is not None and lo < m < hi:
                extra.append((p, m))
    for (p, v), out in zip(extra, run_each(refit, extra, workers)):
        tried_all[p][v] = out
    best: PinnedGap | None = None
    for p in params:
        lo, hi = ints[p]
        tried = tried_all[p]
        for v, (cost, gap) in tried.items():
            _say(progress, f"nominal identification: {p} pinned at {v:.4g} (interval "
                           f"[{lo:.4g}, {hi:.4g}]): train cost {cost:.4g} (nominal "
                           f"{train_cost:.4g} + at most {tol:.3g}), validation gap "
                           f"{gap:.4g}")
            if not (np.isfinite(gap) and cost <= train_cost + tol and gap < gap_before):
                continue
            if best is None or gap < best.gap:
                best = PinnedGap(p, (lo, hi), float(v), cost, gap, dict(ints))
    return best


def explained_by_nominal(pin: PinnedGap, named_gap: float, estimate: float,
                         gap_before: float, noise: float | None,
                         settings: DiagnoseSettings) -> dict[str, Any] | None:
    """The rule entry refusing the named effects when the pinned nominal explains the gap:
    the pinned nominal is within ``noise_factor`` x the noise floor *and* its pinning
    removes at least ``closure_min`` of what the named effects remove (a pinning that
    leaves a gap near the noise untouched explains nothing: lono:quadratic_spring:
    NO-ground:small, gap 0.000719 at 2.1 x the floor, pinned 0.000685), or the named
    set's gap is not below ``1 - closure_min`` of the pinned nominal's (the candidate must
    still close ``closure_min`` of what the nominal's own parameters cannot absorb) while
    the pinning removes at least ``step_min`` of what the named effects remove.  None
    when the named effects still beat the pinned nominal."""
    removed_by_named = gap_before - named_gap
    removed_by_pin = gap_before - pin.gap
    explains = removed_by_pin >= settings.closure_min * removed_by_named
    at_noise = (noise is not None and noise > 0 and pin.gap <= settings.noise_factor * noise
                and explains)
    closes = 1.0 - named_gap / pin.gap if pin.gap > 0 else 0.0
    # the pinned nominal is a new reference only when the pinning moves the gap: one
    # removing less than ``step_min`` of what the named effects remove leaves the verdict
    # judged against the nominal, by the rules that named it (fresh seed 17890: a true
    # 1.16 force gain on a gap 2.8 x the floor closing 0.48 of it, the pinning 0.0221 ->
    # 0.0219)
    moves = removed_by_pin >= settings.step_min * removed_by_named
    if not at_noise and (closes >= settings.closure_min or not moves):
        return None
    why = (f"within {settings.noise_factor:g} x the noise floor {noise:.3g}" if at_noise
           else f"and the named effects close only {closes:.2f} of that (less than "
                f"{settings.closure_min:.0%})")
    return {"param": pin.param, "interval": list(pin.interval), "pinned_at": pin.value,
            "pinned_train_cost": pin.train_cost, "pinned_gap": pin.gap,
            "named_closure_of_pinned": closes,
            "text": f"{pin.describe(estimate, gap_before)}, {why}: records at larger "
                    "amplitude are needed to identify it"}


def check_named(verdict: Any, verdicts: list[Any], structure: Structure, theta: np.ndarray,
                train_cost: float, gap_before: float, train: Sequence[Recording],
                val: Sequence[Recording], proc: Processing, noise: float | None,
                settings: DiagnoseSettings, rule: dict[str, Any],
                progress: Progress | None = None) -> tuple[Any, list[Any]]:
    """The named effects, or none when the nominal model's own unidentified nonlinear
    coefficient explains the validation gap (``explained_by_nominal``; the rule's reason
    says so).  Run only when something is named and the nominal has such a coefficient
    (the refits cost about one nominal fit).

    When the named set was fitted with a pulse-reading gain (a nuisance of the records,
    never named), the same check is made on the nominal *with that gain*: the reference
    a named effect must beat is the nominal with every nuisance the records carry (fresh
    seed 17866, a null: the gain alone, fitted at a value of the nominal's unidentified
    knl that the train records allow but the 5 x larger validation hit does not, left
    0.013; the gain fitted with a 0.06 N s/m damper landed nearer the truth's knl and
    left 0.0008, so the damper looked needed; the truth with the gain leaves 0.0005)."""
    if verdict is None or not verdicts or not nonlinear_params(structure):
        return verdict, verdicts
    closure = float(rule.get("combined_closure", verdict.closure))
    named_gap = gap_before * (1.0 - closure)
    references = [(None, structure, theta, train_cost, gap_before, train, val)]
    for g in getattr(verdict, "nuisances", None) or []:
        if g.structure is not None and g.theta is not None and np.isfinite(g.gap_after) \
                and np.isfinite(g.train_cost) and g.gap_after > named_gap:
            references.append((g, g.structure, g.theta, g.train_cost, g.gap_after,
                               g.correct(train), g.correct(val)))
    plain: dict[str, tuple[float, float]] = {}
    for g, st, th, cost, ref_gap, tr, va in references:
        pin = lowest_pinned_gap(st, th, cost, ref_gap, tr, va, proc, settings, progress,
                                wider=plain if g is not None else None)
        if pin is None:
            continue
        if g is None:
            plain = pin.intervals
        estimate = float(th[st.free.index(pin.param)])
        refused = explained_by_nominal(pin, named_gap, estimate, ref_gap, noise, settings)
        if refused is None:
            if g is None:
                rule["nominal_identification"] = {
                    "param": pin.param, "interval": list(pin.interval),
                    "pinned_gap": pin.gap, "named_closure_of_pinned":
                        1.0 - named_gap / pin.gap if pin.gap > 0 else None}
            continue
        refused["refused"] = [v.label() for v in verdicts]
        if g is not None:
            refused["with_nuisance"] = g.label()
            refused["text"] = (f"with {g.label()} (the hammer pulse's reading, a nuisance) "
                               f"in the nominal model, {refused['text']}")
        rule["nominal_identification"] = refused
        rule["reason"] = (f"{refused['text']}; {', '.join(refused['refused'])} (closing "
                          f"{closure:.2f} of the nominal gap) is not named")
        _say(progress, f"nominal identification: {rule['reason']}")
        return None, []
    return verdict, verdicts
