"""Two effects when no single effect closes much (issue 16, branch nosingle).

With two effects acting at different amplitudes, each single fitted alone is judged on
validation records where the *missing* effect dominates: its validation closure mostly
measures how the missing effect extrapolates, and none closes ``step_min`` of the gap.
The pair search (``sets.choose_set``) takes its members by validation closure (and the
lead's partners), so the right pair was never formed (fresh seed 17677: a channel delay
acc_m1 + clearance m2-ground, gap 120 x the noise floor; the clearance made the
validation records 2.3 x worse alone but lowered the train cost 0.168 -> 0.132; the best
single, a delay on the other channel, closed 0.17; the clearance was never paired with
the acc_m1 delay.  Fresh seed 17681: a quadratic damper m1-m2 lowered the train cost
0.0070 -> 0.0020, 71 %, but closed -0.56 of a validation gap at 1/7 of the train
amplitudes where the coulomb m1-ground dominates; the next stage was built on a
quadratic spring closing 0.07 that lowered the train cost by 5 %).

In that case -- the gap at least ``faint_noise`` x the spectral noise floor, the best
single below ``step_min`` -- the train records, the same for every single and at no more
freedom, rank what a single explains:

- the tentative first effect is the structural single that lowers the stage's train
  cost most, when it removes at least ``step_min`` of it (``train_lead``); the
  validation leader is still paired with the later effects (``tie_pairs``);
- the structural singles that lower the train cost by ``step_min`` / 2 (one per kind and
  place, ``pair_members`` of them by train cost) are paired with each other and with the
  sensor faults that may join a structural effect (``grow.joiners``), at most
  ``weak_pair_fits`` more joint fits (``weak_pairs``).

Nothing is named from this: the set rule judges every pair (each member needed on the
held-out records, each above the noise, the set closing ``tentative_closure``).  A null
case's gap is near the noise and never triggers it.
"""
from __future__ import annotations

from itertools import combinations
from typing import Sequence

import numpy as np

from .results import Candidate
from .settings import DiagnoseSettings


def no_single_closes(ranking: Sequence[Candidate], gap_before: float, noise: float | None,
                     settings: DiagnoseSettings) -> bool:
    """No fitted single closes ``step_min`` of a gap at least ``faint_noise`` x the
    spectral noise floor (without a floor there is no scale to call the gap real)."""
    if noise is None or not noise > 0 or not np.isfinite(gap_before):
        return False
    best = max((c.closure for c in ranking if c.fitted and not c.reading
                and np.isfinite(c.closure)), default=-np.inf)
    return bool(gap_before >= settings.faint_noise * noise and best < settings.step_min)


def _explaining(ranking: Sequence[Candidate], train_cost: float, share: float
                ) -> list[Candidate]:
    """Structural singles lowering ``train_cost`` by at least ``share`` of it, best train
    cost first, one per kind and place."""
    fits = sorted((c for c in ranking if c.category == "structure" and c.fitted
                   and not c.reading and not c.stopped and c.structure is not None
                   and c.theta is not None and np.isfinite(c.train_cost)
                   and np.isfinite(c.gap_after)
                   and c.train_cost <= (1.0 - share) * train_cost),
                  key=lambda c: c.train_cost)
    return [c for k, c in enumerate(fits) if all(c.key != o.key for o in fits[:k])]


def train_lead(ranking: Sequence[Candidate], top: Candidate, train_cost: float,
               settings: DiagnoseSettings) -> Candidate | None:
    """The structural single with no more coefficients than ``top`` that removes the
    most of the stage's train cost -- at least ``step_min`` of it, and more than ``top``
    does -- or None (module doc)."""
    if top.category != "structure" or not np.isfinite(train_cost) or train_cost <= 0:
        return None
    n = len(top.effect.coefficients)
    fits = [c for c in _explaining(ranking, train_cost, settings.step_min)
            if len(c.effect.coefficients) <= n]
    if not fits or fits[0] is top or not fits[0].train_cost < top.train_cost:
        return None
    return fits[0]


def weak_pairs(ranking: Sequence[Candidate], faults: Sequence[Candidate], train_cost: float,
               settings: DiagnoseSettings) -> list[tuple[Candidate, Candidate]]:
    """The pairs of the module doc: each structural single explaining part of the train
    records with each joining sensor fault, then with each other (distinct places), at
    most ``weak_pair_fits``."""
    if settings.weak_pair_fits < 1 or not np.isfinite(train_cost) or train_cost <= 0:
        return []
    struct = _explaining(ranking, train_cost, settings.step_min / 2)[:settings.pair_members]
    out = [(s, f) for s in struct for f in faults if f.category == "sensor"]
    out += [(a, b) for a, b in combinations(struct, 2) if a.loc.between != b.loc.between]
    return out[:settings.weak_pair_fits]
