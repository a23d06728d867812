"""Early stop of candidate fits (speed): a fit that cannot come near the leader of its
stage is cut short (``refine``'s ``stop``), so the diagnosis spends its simulations on
the candidates that can name or block a verdict (docs/diagnosis.md step 3)."""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .results import Candidate
from .settings import DiagnoseSettings

StopRule = Callable[[int, bool, int, float, Any], bool]


class _HeadCosts:
    """The leader's train cost on the leading parts of the records a candidate's growing
    horizons fit (one short simulation per horizon, memoised)."""

    def __init__(self, leader: Candidate, train: Sequence[Recording], proc: Processing
                 ) -> None:
        self.leader, self.train, self.proc = leader, list(train), proc
        self.theta = np.array(leader.theta, dtype=float)  # the leader's fit, as it was
        self._full: Any = None
        self._cost: dict[tuple[int, ...], float] = {}

    def cost(self, prob: Any) -> float:
        from ..refine import OutputErrorProblem

        key = tuple(len(r.target) for r in prob.records)
        if key not in self._cost:
            try:
                if self._full is None:
                    self._full = OutputErrorProblem.build(
                        self.leader.structure, self.train, self.proc,
                        theta_ref=self.theta[None])
                head = self._full.head(list(key))
                self._cost[key] = float(head.cost(self.theta[None])[0])
            except Exception:  # noqa: BLE001 - no comparison on this horizon
                self._cost[key] = math.nan
        return self._cost[key]


#: the leaders' head costs, shared by every fit stopped against the same leader (speed:
#: a stage's fits after its leader all grow the same horizons, and each rebuilt the
#: leader's problem -- a full-length substep pilot -- and simulated its heads again)
_SHARED: list[tuple[tuple[Any, ...], _HeadCosts]] = []
_SHARED_MAX = 8


def head_costs(leader: Candidate, train: Sequence[Recording], proc: Processing
               ) -> _HeadCosts:
    """The ``_HeadCosts`` of ``leader`` at its current fit on ``train`` through ``proc``,
    shared while they are unchanged (the same objects and the same theta, bit for bit:
    the costs are then the same numbers)."""
    recs = list(train)
    theta = np.asarray(leader.theta, dtype=float)
    key = (id(leader.structure), theta.tobytes(), theta.shape, id(proc),
           tuple(id(r) for r in recs))
    for k, h in _SHARED:
        if (k == key and h.leader.structure is leader.structure and h.proc is proc
                and len(h.train) == len(recs)
                and all(a is b for a, b in zip(h.train, recs))):
            return h
    h = _HeadCosts(leader, recs, proc)
    _SHARED.append((key, h))
    del _SHARED[:-_SHARED_MAX]
    return h


def cannot_win(leader_cost: float, settings: DiagnoseSettings,
               leader: Candidate | None = None, train: Sequence[Recording] | None = None,
               proc: Processing | None = None, base_cost: float = math.nan
               ) -> StopRule | None:
    """``refine``'s ``stop`` for a candidate fitted after a leader of train cost
    ``leader_cost``: True once the fit has run ``settings.stop_after`` iterations of a
    stage and its cost there is still above ``settings.stop_ratio`` x the leader's on the
    same records -- on the full records its train cost; on a growing horizon (from the
    second on, with the structural ``leader`` and its ``train`` records given) the
    leader's cost on that leading part, which the candidate has just been fitted to and
    the leader not (the comparison favours the candidate).

    Why it is safe: the remaining iterations and horizons improve a fit by a small factor,
    not by the ``stop_ratio`` / (1/``separation``) = 7.5 x it would need to rival the
    leader (measured: the losers of the LO-NO cases sit 20-150 x above the leader).  None
    when there is no leader yet (or the rule is off).

    ``base_cost``: the train cost the fits start from, when it is the model of an earlier
    stage (``gain_limit``): on the full records a fit is also cut short once it has
    removed less than 1/``stop_ratio`` of what the leader removed from it."""
    limit = stop_limit(leader_cost, settings, base_cost)
    if not np.isfinite(limit):
        return None
    heads = (head_costs(leader, train, proc) if leader is not None and train is not None
             and proc is not None and leader.category == "structure"
             and leader.structure is not None and leader.theta is not None else None)

    def stop(stage: int, last: bool, iteration: int, cost: float, prob: Any = None) -> bool:
        if iteration < settings.stop_after:
            return False
        if last:
            return cost > limit
        if heads is None or prob is None or stage < 1:
            return False  # the first horizon (2.5 cycles) is never judged
        ref = heads.cost(prob)
        return bool(np.isfinite(ref) and ref > 0 and cost > settings.stop_ratio * ref)
    return stop


def stop_limit(leader_cost: float, settings: DiagnoseSettings,
               base_cost: float = math.nan) -> float:
    """The train cost on the full records above which a fit after a leader of train cost
    ``leader_cost`` is cut short (``cannot_win``'s last-stage test): ``stop_ratio`` x the
    leader's, or less than 1/``stop_ratio`` of the leader's gain from ``base_cost``; inf
    when there is no leader (or the rule is off)."""
    if not (np.isfinite(leader_cost) and leader_cost > 0
            and np.isfinite(settings.stop_ratio)):
        return math.inf
    return min(settings.stop_ratio * leader_cost,
               gain_limit(base_cost, leader_cost, settings.stop_ratio))


def gain_limit(base_cost: float, leader_cost: float, ratio: float) -> float:
    """The train cost above which a fit has removed less than 1/``ratio`` of what the
    leader removed from ``base_cost`` (inf when there is no base or the leader removed
    nothing).

    Why (speed, issue 16 must-show 3): after a first effect the stage's model already
    fits the train records closely and every candidate sits within a factor ~1.5 of the
    leader (LO-NO two:0 stage 2: 0.00045-0.00064 from 0.00064), so ``stop_ratio`` x the
    leader never fires while each fit simulates the stiff dry-friction model (12-20 RK4
    substeps per sample instead of 3).  A fit that has removed a tenth of the leader's
    share of the train cost two iterations into the full records is as far from a rival
    as a stage-1 fit 10 x above the leader (a coulomb at the wrong place beside the right
    one: fc -> 0, gain 0); a stopped fit the validation records do not show losing is
    fitted in full after all (``stage._stage``'s rescue)."""
    if not (np.isfinite(base_cost) and np.isfinite(ratio) and ratio > 0
            and base_cost > leader_cost):
        return math.inf
    return base_cost - (base_cost - leader_cost) / ratio
