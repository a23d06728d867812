"""The joint fit of a pair of fitted single candidates (issue 16's sets): two structural
effects in one model, or a structural effect on the records a sensor fault corrects."""
from __future__ import annotations

import math
import time
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .budget import clock_of
from .joint_sensor import force_scale_retune, retune_sensor
from .model_edit import augmented
from .outputs import Progress, _say
from .results import Candidate
from .set_rules import can_pair
from .set_fit import SetFit, _refit, finish_set, mark_stopped, set_stop
from .settings import DiagnoseSettings


def _fit_pair(a: Candidate, b: Candidate, structure: Structure, train: Sequence[Recording],
             val: Sequence[Recording], proc: Processing, gap_before: float,
             before_blocks: np.ndarray, settings: DiagnoseSettings,
             progress: Progress | None = None, against: float = math.inf,
             starts_a: Sequence[np.ndarray] = ()) -> SetFit | None:
    """The joint fit of two fitted single candidates (at most one a sensor fault), judged
    on the validation records; None when it cannot be built or simulated.  ``against``:
    the best train cost known (``set_fit.set_stop``); a fit stopped against it is marked
    ``stopped`` (its sensor value is not re-tuned).  ``starts_a``: more starts of ``a``'s
    model (a look-alike second lead's law-swap starts, ``grow.refit_from_lead``), each
    with ``b``'s coefficients."""
    t0 = time.perf_counter()
    stop = set_stop(against, settings, min(a.train_cost, b.train_cost))
    if a.category == "sensor" and b.category == "sensor":
        return None
    if a.category == "sensor":
        a, b = b, a
    try:
        if b.category == "sensor":  # structural a on the records b corrects
            recs = b.correct(train)
            aug, names = a.structure, dict(a.names)
            nom_b = dict(b.parameters or {})
            vals_a = aug.as_dict(a.theta)
            starts = [np.asarray(a.theta, float)]
            if nom_b:
                starts.append(aug.vector({**vals_a, **{p: v for p, v in nom_b.items()
                                                       if p in vals_a}}))
            theta, cost, res = _refit(aug, starts, recs, proc, settings.fit_nfev, stop)
            stopped = bool(getattr(res, "stopped", False))
            # the fault's value re-fitted with the structural model (joint_sensor's doc:
            # fitted with the nominal model alone it absorbs part of the other effect)
            again = None if stopped else retune_sensor(b, aug, theta, train, proc,
                                                       max(10, settings.fit_nfev // 2))
            if again is not None:
                b, theta, cost, res = again
            # a force gain found afresh with the structural model (force_scale_retune's
            # doc): the lower train cost wins
            fresh = None if stopped else force_scale_retune(
                b, aug, np.asarray(a.theta, float), train, proc,
                max(10, settings.fit_nfev // 2))
            if fresh is not None and fresh[2] < cost:
                b, theta, cost, res = fresh
            out = SetFit(a.effect, a.loc, dict(a.shape), structure=aug, names=names,
                         theta=theta, fitted=True, amplitudes=a.amplitudes,
                         members=[a, b], sensor=b)
        else:
            if not can_pair(a, b):
                return None
            scales = {k: max(abs(v), 1e-12) for k, v in b.coefficients.items()}
            aug, names = augmented(a.structure, b.effect, b.loc, scales)
            vals_a = a.structure.as_dict(a.theta)
            vals_b = b.structure.as_dict(b.theta)
            s1 = {**vals_a, **{names[k]: v for k, v in b.coefficients.items()}}
            s2 = {**s1, **{p: vals_b[p] for p in structure.free if p in vals_b}}
            starts = [aug.vector(s1), aug.vector(s2)]
            theta, cost, res = _refit(aug, starts, train, proc, settings.fit_nfev, stop)
            if starts_a:  # a look-alike second lead: from the lead's force in its law too
                mag = a.names[a.effect.magnitude]
                swap = []
                for t in starts_a:
                    va = a.structure.as_dict(t)
                    swap.append(aug.vector({**s1, **va}))
                    # the lead absorbed part of the other effect too: smaller magnitudes
                    # on the other member's nominal parameters
                    swap += [aug.vector({**s2, mag: va[mag] * f}) for f in (1.0, 0.3, 0.1)]
                th2, cost2, res2 = _refit(aug, swap, train, proc, settings.fit_nfev, stop)
                if cost2 < cost:
                    theta, cost, res = th2, cost2, res2
            stopped = bool(getattr(res, "stopped", False))
            out = SetFit(b.effect, b.loc, dict(b.shape), structure=aug, names=names,
                         theta=theta, fitted=True, amplitudes=b.amplitudes,
                         members=[a, b])
    except Exception as exc:  # noqa: BLE001 - a pair that cannot be fitted is not a set
        _say(progress, f"pair {a.label()} + {b.label()}: fit failed ({exc})")
        return None
    mark_stopped(out, stopped, cost, against, settings)
    finish_set(out, cost, res, val, proc, gap_before, before_blocks, progress)
    out.fit_time_s = time.perf_counter() - t0
    return out


def best_known(options: Sequence[Candidate], ranking: Sequence[Candidate]) -> float:
    """The best train cost of the sets fitted so far and of the structural singles (the
    reference of ``set_fit.set_stop``)."""
    costs = [o.train_cost for o in options if not o.stopped and np.isfinite(o.train_cost)]
    costs += [c.train_cost for c in ranking if c.category == "structure" and c.fitted
              and not c.stopped and np.isfinite(c.train_cost)]
    return min(costs, default=math.inf)


def fit_pair(a: Candidate, b: Candidate, structure: Structure, train: Sequence[Recording],
             val: Sequence[Recording], proc: Processing, gap_before: float,
             before_blocks: np.ndarray, settings: DiagnoseSettings,
             progress: Progress | None = None, against: float = math.inf,
             starts_a: Sequence[np.ndarray] = ()) -> SetFit | None:
    """``_fit_pair`` within the diagnosis's time budget (``budget``): None, as a pair
    that cannot be fitted, once a pair fit would run past it."""
    return clock_of(settings).run(
        "pair", f"{a.label()} + {b.label()}",
        lambda: _fit_pair(a, b, structure, train, val, proc, gap_before, before_blocks,
                          settings, progress, against, starts_a))
