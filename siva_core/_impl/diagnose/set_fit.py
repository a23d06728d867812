"""A jointly fitted set of effects (issue 16): the result type of the set search and the
joint re-fit every set shares (best of several starts, then one refine)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .early_stop import StopRule, cannot_win
from .fitting import _intervals
from .outputs import Progress, _Outputs
from .results import Candidate
from .scoring import judge
from .settings import FAST, DiagnoseSettings


@dataclass
class SetFit(Candidate):
    """A jointly fitted set: ``members`` (the effects, structural last-added carrying the
    model), ``sensor`` the sensor member whose correction applies to the records."""

    members: list[Candidate] = field(default_factory=list)
    sensor: Candidate | None = None
    member_intervals: list[dict[str, tuple[float, float]]] = field(default_factory=list)

    def correct(self, records: Sequence[Recording]) -> list[Recording]:
        return self.sensor.correct(records) if self.sensor is not None else list(records)

    def label(self) -> str:
        return " + ".join(m.label() for m in self.members)


def member_coefficients(s: Candidate) -> list[dict[str, float]]:
    """Each structural member's coefficients in the set's joint fit (by its parameter
    names: the first member's names survive in the augmented model)."""
    if not isinstance(s, SetFit) or s.structure is None or s.theta is None:
        return [dict(s.coefficients)]
    vals = s.structure.as_dict(s.theta)
    out = []
    for m in s.members:
        if m.category == "sensor":
            out.append(dict(m.coefficients))
        else:
            out.append({k: vals[p] for k, p in m.names.items() if p in vals})
    return out


def contributions(s: Candidate, val: Sequence[Recording], proc: Processing) -> list[float]:
    """Each structural member's own contribution to the simulated validation outputs, in
    the gap's units (NMSE): the squared output change when its magnitude is set to zero,
    the rest of the fit held.  Sensor members: the change of the records their
    correction makes, the same way (nominal outputs held)."""
    if s.structure is None or s.theta is None:
        return []
    members = s.members if isinstance(s, SetFit) else [s]
    outs = _Outputs(s.structure, s.correct(val), proc, s.theta)
    r0 = outs.residuals(s.theta)[0]
    result = []
    for m in members:
        if m.category == "sensor":
            raw = _Outputs(s.structure, val, proc, s.theta).residuals(s.theta)[0]
            result.append(float((raw - r0) @ (raw - r0)) if raw.shape == r0.shape
                          else math.inf)
            continue
        names = m.names if isinstance(s, SetFit) else s.names
        p = names.get(m.effect.magnitude)
        if p is None or p not in s.structure.free:
            result.append(math.inf)
            continue
        th = np.array(s.theta, float)
        th[s.structure.free.index(p)] = 0.0
        r1 = outs.residuals(th)[0]
        d = r1 - r0
        result.append(float(d @ d) if np.all(np.isfinite(d)) else math.inf)
    return result


def _refit(aug: Structure, starts: Sequence[np.ndarray], train: Sequence[Recording],
           proc: Processing, nfev: int, stop: StopRule | None = None
           ) -> tuple[np.ndarray, float, object]:
    """The best start by train cost, refined jointly; the start stands when the refine
    does not lower its cost.  ``stop``: ``early_stop.cannot_win`` against the best set
    (``set_stop``); the result's ``stopped`` says it fired."""
    from ..refine import output_error, refine

    costs = output_error(aug, np.stack(list(starts)), list(train), proc)
    k = int(np.nanargmin(costs))
    res = refine(aug, starts[k], list(train), proc, max_nfev=nfev, horizons=None,
                 uncertainty=FAST, stop=stop)
    cost = float(output_error(aug, res.theta[None], list(train), proc)[0])
    if not cost <= costs[k]:
        return starts[k], float(costs[k]), res
    return res.theta, cost, res


def finish_set(out: SetFit, cost: float, res: object, val: Sequence[Recording],
               proc: Processing, gap_before: float, before_blocks: np.ndarray,
               progress: Progress | None = None) -> SetFit:
    """A joint fit's result as a judged set: its train cost, the last structural member's
    coefficients and intervals, every member's intervals, and its validation gap."""
    out.train_cost = cost
    vals = out.structure.as_dict(out.theta)
    out.coefficients = {k: vals[p] for k, p in out.names.items()}
    out.intervals = _intervals(res, out.structure, out.names)
    out.member_intervals = [_intervals(res, out.structure, m.names)
                            if m.category == "structure" else dict(m.intervals)
                            for m in out.members]
    judge(out, val, proc, gap_before, before_blocks, progress)
    return out


def mark_stopped(out: SetFit, stopped: bool, cost: float, against: float,
                 settings: DiagnoseSettings) -> None:
    """``out.stopped`` and, when it was, the note saying against what."""
    out.stopped = stopped
    if stopped:
        out.note = (f"joint fit stopped early: train cost {cost:.3g} > "
                    f"{settings.stop_ratio:g} x the best set's {against:.3g}")


def set_stop(reference: float, settings: DiagnoseSettings, reachable: float = math.inf
             ) -> StopRule | None:
    """The early stop of a set's joint fit (speed, issue 16 must-show 3): ``cannot_win``
    against ``reference``, the best train cost of a set or single known before the set
    fits start (fixed, so the result does not depend on the workers).  A joint fit still
    ``stop_ratio`` x above it two iterations into its refine cannot be the chosen set:
    sets are chosen by validation gap and must beat the best single (LO-NO two:0: the
    pairs without coulomb NO-ground ended 85-150 x above the greedy set, 13 s each on a
    friction model); a stopped set the validation records do not show losing is fitted
    in full (``refit_stopped``).

    Unlike a single's fit, a joint fit can start far from its optimum (one member's fit
    plus the other's coefficients count the shared part twice: coulomb NO-ground + coulomb
    LO-NO of two:0 started 150 x above the single and ended 45 x lower), so it is stopped
    only while it also descends slowly: the last iteration removed less than
    1 - ``SET_DESCENT`` of its cost -- and never when a member alone already fits within
    ``stop_ratio`` of the reference (``reachable``, the best member's train cost: the set's
    model holds each member's, so its optimum is at least that good; that pair above
    ended 4.6 x above the reference, not 150 x)."""
    rule = cannot_win(reference, settings)
    if rule is None or not reachable > settings.stop_ratio * reference:
        return None
    previous = [math.inf]

    def stop(stage: int, last: bool, iteration: int, cost: float, prob: object = None
             ) -> bool:
        before, previous[0] = previous[0], cost
        return bool(rule(stage, last, iteration, cost, prob) and cost > SET_DESCENT * before)
    return stop


#: a set's joint fit still halving its cost per iteration is never stopped (``set_stop``)
SET_DESCENT = 0.5


def refit_stopped(options: Sequence[SetFit], again: Callable[[SetFit], SetFit | None],
                  settings: DiagnoseSettings) -> list[SetFit]:
    """``options`` with every stopped set whose validation gap is within twice the
    separation margin of the best full fit's (as ``stage._stage``'s rescue) fitted again
    without the stop (``again(set)``: the new fit or None)."""
    best = min((o.gap_after for o in options if not o.stopped and np.isfinite(o.gap_after)),
               default=np.inf)
    out = []
    for o in options:
        if o.stopped and np.isfinite(o.gap_after) \
                and o.gap_after * settings.separation < 2.0 * best:
            o = again(o) or o
        out.append(o)
    return out
