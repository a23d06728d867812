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
