"""A jointly fitted set of effects (issue 16): the result type of the set search and the
joint re-fit every set shares (best of several starts, then one refine)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .fitting import _intervals
from .outputs import Progress
from .results import Candidate
from .scoring import judge
from .settings import FAST


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


def _refit(aug: Structure, starts: Sequence[np.ndarray], train: Sequence[Recording],
           proc: Processing, nfev: int) -> tuple[np.ndarray, float, object]:
    """The best start by train cost, refined jointly; the start stands when the refine
    does not lower its cost."""
    from ..refine import output_error, refine

    costs = output_error(aug, np.stack(list(starts)), list(train), proc)
    k = int(np.nanargmin(costs))
    res = refine(aug, starts[k], list(train), proc, max_nfev=nfev, horizons=None,
                 uncertainty=FAST)
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
