"""The rules that compare sets of effects (issue 16): which singles are worth pairing,
when a larger set beats a smaller one, and when a set's closure is relevant at all.
``sets.choose_set`` searches; these say what it may keep."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from .nominal import DISSIPATIVE
from .results import Candidate
from .settings import DiagnoseSettings


def can_pair(a: Candidate, b: Candidate) -> bool:
    """Whether two structural laws may be members of one set: at distinct places, or at
    one place with distinct roles (one dissipative, one restoring: a joint that both rubs
    and stiffens, a damper beside a missing spring).  Two laws of one role at one place are
    look-alikes, told apart by the kind check, not a pair (pair matrix row lono: damper
    NO-ground + spring NO-ground was never fitted: nothing but the damper was named, its
    set leaving 27 x the noise floor).  A sensor fault pairs with any structural law."""
    if a.category != "structure" or b.category != "structure":
        return True
    return a.loc.between != b.loc.between or (
        (a.effect.kind in DISSIPATIVE) != (b.effect.kind in DISSIPATIVE))


def pair_members(ranking: Sequence[Candidate], settings: DiagnoseSettings, n: int = 3
                 ) -> list[Candidate]:
    """The singles worth pairing: the ``n`` best structural fits by validation closure
    (distinct places first: the first stage's laws at one place are mostly look-alikes,
    told apart by the kind check; a law of the other role at a member's place is paired
    from the later stages' fits, ``can_pair``) that close at least a little, and the best
    sensor fault."""
    fitted = [c for c in ranking if c.fitted and np.isfinite(c.closure) and c.closure > 0.05
              and not c.reading]
    struct = [c for c in fitted if c.category == "structure"]
    out: list[Candidate] = []
    for c in struct:
        if all(c.loc.between != o.loc.between for o in out):
            out.append(c)
        if len(out) >= n:
            break
    sens = [c for c in fitted if c.category == "sensor"]
    return out + sens[:1]


def better(big: Candidate, small_gap: float, noise: float | None,
           settings: DiagnoseSettings, test: Callable[[], float] | None = None,
           above_floor: bool = False) -> bool:
    """A set with one more effect beats one whose gap is ``small_gap`` when the added
    effect removes at least ``step_min`` of it and more than ``noise_factor`` x the noise
    floor -- or more than the floor itself when the set brings the gap down to the noise
    level (within ``kind_check_noise`` x the floor: where the true model would be).  With
    the whole margin a second effect whose smaller set already sits near the noise could
    never be added (issue 16, seed 13006: a cubic damper left 0.0104 = 3.1 x the floor
    0.0034, the 16 % accelerometer gain with it 0.0053 = 1.6 x; the gain removed 0.0050,
    below 2 x the floor).

    A gain below those margins still counts when the held-out records show it: ``test``
    gives the gain over its noise error on the validation records (``set_test``), which
    must reach ``test_z``.  The floor margin compares the gain with the *whole* noise
    energy, which both sets share and which cancels in their difference; the test
    measures what does not cancel, on the records themselves.

    ``above_floor``: the step is a share of the smaller set's gap *above* the noise floor
    (what a right model can remove; ``verdict.closes_above_noise`` for a closure), for an
    added gain the records pin outside the pulse reading (``pulse_reading.
    outside_reading``): one number whose value is its evidence, confirmed on the held-out
    records by ``test`` (issue 16, fresh seed 17720: the force gain removed 0.0016 of the
    coulomb's 0.0091, 18 % of it and 26 % of its part above the floor 0.0029; z 7.1)."""
    if not np.isfinite(big.gap_after):
        return False
    gain = small_gap - big.gap_after
    ref = small_gap - noise if above_floor and noise is not None and small_gap > noise \
        else small_gap
    if gain < settings.step_min * ref:
        return False
    if noise is None:
        return True
    at_noise = big.gap_after <= settings.kind_check_noise * noise
    if gain > (1.0 if at_noise else settings.noise_factor) * noise:
        return True
    return bool(test is not None and test() >= settings.test_z)


def relevant(gap_before: float, closure: float, noise: float | None,
              settings: DiagnoseSettings) -> bool:
    """verdict.decide's relevance check (a), for a set's combined closure."""
    above = noise is None or gap_before > settings.noise_factor * noise
    visible = (gap_before > settings.gap_min or closure >= settings.faint_closure
               or (noise is not None and noise > 0
                   and gap_before >= settings.faint_noise * noise
                   and closure >= settings.closure_min))
    return bool(above and visible)
