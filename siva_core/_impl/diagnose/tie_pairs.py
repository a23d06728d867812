"""The first stage's tied leads paired with the later stages' effects (issue 16, branch
tiepair).

When no single closes the gap, the first stage keeps one lead tentatively
(``weak_lead.tentative_lead``) and the next stage looks for the rest on the model that
holds it.  With two real effects the first stage's singles often tie: each explains a
part, and a look-alike of the true first effect (a cubic spring for a coulomb) explains
about as much (last fresh batch: coulomb m2-ground closed 0.59, cubic spring m1-ground
0.57, with a quadratic damper m1-m2 missing; coulomb m1-m3 0.56 against cubic spring
m3-ground 0.46 with a second coulomb missing).  The tentative lead is then a coin toss;
when it is the wrong one, the second effect the next stage finds is paired only with
it, and the set search (``sets.choose_set``) pairs the first stage's members among
themselves -- the second effect, weak alone in the first stage, is not among them -- so
the right pair is never fitted and nothing is named.

Here each other tied lead is paired with the later stages' effects (their fits on the
tentative model give the starting values) and the pair is refitted jointly from the
nominal model (``pair_fit``).  Nothing is named from a tie: a pair is named only when
the set rule passes (each member needed on the held-out records, each above the noise),
and the member swap (``swap``) lists the laws the data cannot separate as rivals.

A lead is *tied* when the tentative one does not separate from it on the validation
records: its gap within the ``separation`` ratio (``verdict.decide``'s separation check)
or within ``noise_factor`` x the spectral floor of the tentative lead's (what
``tentative_lead`` calls a tie).  Bounded by ``tie_leads`` leads and ``tie_pair_fits``
fits (CPU: a pair fit takes 10-30 s on LO-NO).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .results import Candidate
from .set_rules import can_pair
from .settings import DiagnoseSettings


def tied_leads(ranking: Sequence[Candidate], lead: Candidate, noise: float | None,
               settings: DiagnoseSettings) -> list[Candidate]:
    """The fitted structural singles of the first stage that ``lead`` (the tentative
    first effect) does not separate from (module doc), best by validation gap first, at
    most ``tie_leads``; not ``lead`` itself, nor a law at its place of its kind."""
    if settings.tie_leads < 1 or lead.category != "structure" \
            or not np.isfinite(lead.gap_after):
        return []
    margin = settings.noise_factor * noise if noise is not None and noise > 0 else 0.0
    out = [c for c in ranking if c is not lead and c.key != lead.key
           and c.category == "structure" and c.fitted and not c.reading and not c.stopped
           and c.structure is not None and c.theta is not None
           and np.isfinite(c.gap_after) and np.isfinite(c.train_cost)
           and (lead.gap_after > settings.separation * c.gap_after
                or c.gap_after - lead.gap_after <= margin)]
    out.sort(key=lambda c: c.gap_after)
    return out[:settings.tie_leads]


def tie_pairs(leads: Sequence[Candidate], seconds: Sequence[Candidate],
              settings: DiagnoseSettings) -> list[tuple[Candidate, Candidate]]:
    """(tied lead, later effect) pairs to fit jointly: the later effect a sensor fault or
    a structural law the lead can be paired with (``set_rules.can_pair``); at most
    ``tie_pair_fits``, the best-ranked lead's first."""
    out = []
    for a in leads:
        for b in seconds:
            if b.key == a.key or not can_pair(a, b):
                continue
            if b.structure is None or b.theta is None or not b.fitted:
                continue
            out.append((a, b))
    return out[:settings.tie_pair_fits]
