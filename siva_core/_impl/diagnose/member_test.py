"""Which members of a set need the held-out test to be *needed* (issue 16, branch
setmembers).

``set_rules.better`` accepts a member when the set without it leaves ``step_min`` more
of the gap and more than ``noise_factor`` x the spectral floor.  That margin is a share of
the whole noise energy, and the spectral floor (a median over the band) does not count
what every model of the records leaves alike: mains hum inside the band, the chain's
misfit.  Any one more free coefficient removes part of that, and a member that only
does so is *generic*: fresh seed 17790's third stage fitted a damper m3-ground, a coulomb
m1-m2, a clearance m1-ground, a cubic spring m1-m3 and a force gain 0.9945 (a gain the
pulse reading cannot tell from 1) -- each closed 0.45 of the gap 0.00425 that the true
pair left, and the set with the damper was named (the margins saw 0.0019 removed, 5 x
the spectral floor 0.00037).

Members that are *look-alikes of the rest of the set* are where that happens: a law of
the same role (dissipative or restoring) as another structural member -- it moves the
same modes' damping or stiffness as that member, and the joint fit shares the work
between them -- and a sensor gain beside a structural law (a gain scales what the law's
amplitude dependence also changes).  For those the margins are not enough: the
held-out test (``set_test.gain_z``: the gain over the noise's error on the validation
records, which hum and misfit inflate) must show it too, ``test_z``, and a gain's 95 %
interval must exclude 1 (a gain that may be 1 is no fault).  Members of another role than
every other member keep the margin rule alone.
"""
from __future__ import annotations

import math
from typing import Sequence

from .nominal import DISSIPATIVE
from .results import Candidate

GAINS = frozenset({"accelerometer_gain", "force_gain"})


def _role(m: Candidate) -> bool:
    return m.effect.kind in DISSIPATIVE


def look_alike_member(members: Sequence[Candidate], k: int) -> bool:
    """Whether member ``k`` shares its role with another structural member, or is a
    sensor gain beside a structural member (module doc)."""
    m = members[k]
    others = [o for j, o in enumerate(members) if j != k and o.category == "structure"]
    if m.category == "sensor":
        return m.effect.kind in GAINS and bool(others)
    return any(_role(o) == _role(m) for o in others)


def gain_may_be_one(m: Candidate) -> bool:
    """A sensor gain whose 95 % interval holds 1 (no interval: judged by the test)."""
    if m.effect.kind not in GAINS:
        return False
    iv = (m.intervals or {}).get(m.effect.magnitude)
    return iv is not None and all(map(math.isfinite, iv)) and iv[0] <= 1.0 <= iv[1]


def held_out_shows(members: Sequence[Candidate], k: int, z: float, test_z: float
                   ) -> bool:
    """Member ``k`` passes the extra condition: not a look-alike member, or its held-out
    statistic ``z`` against the set without it reaches ``test_z`` and, for a gain, its
    interval excludes 1.  An unknown ``z`` (no fit without it: the set without it is the
    nominal model, whose gap the margins already compare with) leaves the margins alone
    to judge (fresh seed 17790: the true pair had no fit of the damper m1-m3 alone)."""
    if not look_alike_member(members, k):
        return True
    return bool(z >= test_z or math.isnan(z)) and not gain_may_be_one(members[k])


def _group(m: Candidate) -> str:
    """A member's role for the separation of set members: dissipative, restoring, a
    gain (accelerometer and force gain: one fault on one DOF), or its sensor kind."""
    if m.category == "structure":
        return "dissipative" if _role(m) else "restoring"
    return "gain" if m.effect.kind in GAINS else m.effect.kind


def unseparated(members: Sequence[Candidate], gap: float,
                sets: dict[frozenset, Candidate], separation: float
                ) -> list[tuple[int, Candidate]]:
    """The members of a set (gap ``gap``) that are not separated from an effect of
    another role in their place in the set: a fitted set of the same other members
    with ``x`` instead, ``x`` of another role (``_group``), whose gap the set does not
    beat by ``separation`` (the single verdict's check (c), for each member).  Why: the
    margins and the held-out test measure what a member removes, not that *its law*
    removes it; when a law of another role (or a sensor fault) removes as much, the gain
    is generic (fresh seed 17790: the true pair left 0.00425; with a damper m3-ground
    0.00236, with a channel delay acc_m3 0.00252, with a delay acc_m2 0.00262).
    Returns (index, the best such alternative set)."""
    keys = [m.key for m in members]
    out: list[tuple[int, Candidate]] = []
    for k, m in enumerate(members):
        rest = frozenset(keys[:k] + keys[k + 1:])
        best: Candidate | None = None
        for ks, o in sets.items():
            if len(ks) != len(keys) or not rest < ks or ks == frozenset(keys):
                continue
            x = next((y for y in getattr(o, "members", ()) if y.key not in rest), None)
            if x is None or _group(x) == _group(m) or not math.isfinite(o.gap_after):
                continue
            if best is None or o.gap_after < best.gap_after:
                best = o
        if best is not None and gap > separation * best.gap_after:
            out.append((k, best))
    return out
