"""A weak lead's kind placed by fits (issue 16, branch lowclose).

The place check (``stage``: the leading kind fitted at every other place) runs only when
the leader closes ``step_min`` of the gap.  With two effects of one kind at two places
the single fits each explain part of the gap and none closes much: the screen's first
place is fitted, closes little, and the kind's other places -- where the truth is --
are never fitted, so the pair search has nothing right to pair (fresh seed 17506: two
coulombs m1-ground + m1-m2 on a 2-DOF chain; the screen ranked coulomb m2-ground 0.408,
m1-ground 0.383, m1-m2 0.319; only m2-ground was fitted, closing 0.18, and nothing was
named).

Here a weak lead whose fit still removes a real part of a gap many times the noise has
its kind fitted at the ``weak_places`` best-screened other places.  The bound keeps the
cost to a few single fits, and only on the cases that would otherwise name nothing; a
gap near the noise (a null) never triggers it.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .results import Candidate
from .screening import other_places
from .settings import DiagnoseSettings


def weak_lead(lead: Candidate | None, gap_before: float, noise: float | None,
              settings: DiagnoseSettings) -> bool:
    """``lead`` closes less than ``step_min`` of the gap (so the place check skips it),
    yet the gap is at least ``faint_noise`` x the spectral noise floor and the lead's fit
    removes more than ``noise_factor`` x the floor: a real part of a gap that is not
    noise -- one of several effects, or the right kind at the wrong place.  Without a
    noise floor there is no scale to call the gap real: False."""
    if lead is None or settings.weak_places < 1 or noise is None or not noise > 0 \
            or not np.isfinite(lead.gap_after) or lead.closure >= settings.step_min:
        return False
    removed = gap_before - lead.gap_after
    return bool(gap_before >= settings.faint_noise * noise
                and removed > settings.noise_factor * noise)


def weak_lead_places(cands: Sequence[Candidate], lead: Candidate,
                     chosen: Sequence[Candidate], settings: DiagnoseSettings
                     ) -> list[Candidate]:
    """The lead's kind at the ``weak_places`` best-screened places not fitted yet."""
    return other_places(cands, lead.effect.kind, chosen)[:settings.weak_places]


def tentative_lead(ranking: Sequence[Candidate], noise: float | None,
                   settings: DiagnoseSettings) -> Candidate:
    """The first effect kept tentatively for the next stage: the best by validation gap,
    or -- among the fitted structural singles with no more coefficients whose validation
    gap is within ``noise_factor`` x the noise floor of its (the held-out records cannot
    rank them: ``set_rules.better`` counts a gain only above that margin) -- the one with the
    lowest train cost.  With a second
    effect missing, a single's validation gap mostly measures how the missing effect
    extrapolates to the validation amplitudes, while the train cost, on the same records
    for all of them and at no more freedom, measures what it explains (fresh seed 17485:
    clearance m1-m3 left 0.0790 and the true cubic damper m1-ground 0.0811, 1.1 x the
    floor 0.0020 apart, but the damper lowered the train cost 0.083 -> 0.023 and the
    clearance to 0.079 only; the next stage was built on the clearance)."""
    top = ranking[0]
    if top.category != "structure" or noise is None or not noise > 0 \
            or not np.isfinite(top.gap_after):
        return top
    n = len(top.effect.coefficients)
    tied = [c for c in ranking if c.category == "structure" and c.fitted and not c.reading
            and not c.stopped and np.isfinite(c.gap_after) and np.isfinite(c.train_cost)
            and len(c.effect.coefficients) <= n
            and c.gap_after - top.gap_after <= settings.noise_factor * noise]
    best = min(tied, key=lambda c: c.train_cost, default=top)
    return best if best.train_cost < top.train_cost else top
