"""Which set members need the held-out test (``member_test``, branch setmembers)."""
from __future__ import annotations

import math

from siva_core import EFFECTS
from siva_core._impl.diagnose import Candidate, Location
from siva_core._impl.diagnose.member_test import (gain_may_be_one, held_out_shows,
                                                   look_alike_member)
from siva_core._impl.diagnose.sensor_faults import ACC_GAIN, CHANNEL_DELAY


def _s(kind: str, a: str, b: str = "ground") -> Candidate:
    c = Candidate(EFFECTS[kind], Location(0, -1, (a, b)), {}, fitted=True)
    return c


def _gain(lo: float, hi: float) -> Candidate:
    c = Candidate(ACC_GAIN, Location(0, -1, ("acc_m3", "sensor")), {}, fitted=True)
    c.intervals = {ACC_GAIN.magnitude: (lo, hi)}
    return c


def test_same_role_members_need_the_test_other_roles_do_not():
    two_dampers = [_s("quadratic_damper", "m2"), _s("damper", "m1", "m3")]
    assert look_alike_member(two_dampers, 0) and look_alike_member(two_dampers, 1)
    mixed = [_s("coulomb", "m1"), _s("cubic_spring", "m1", "m2")]
    assert not look_alike_member(mixed, 0) and not look_alike_member(mixed, 1)
    # a member of another role than all others passes on the margins alone
    assert held_out_shows(mixed, 0, math.nan, 3.0)


def test_a_gain_beside_a_law_needs_the_test_and_an_interval_without_one():
    g = _gain(0.95, 1.02)
    members = [_s("quadratic_damper", "m1"), g]
    assert look_alike_member(members, 1) and not look_alike_member(members, 0)
    assert gain_may_be_one(g)
    assert not held_out_shows(members, 1, 10.0, 3.0)  # z large, interval holds 1
    members[1] = _gain(1.08, 1.12)
    assert held_out_shows(members, 1, 10.0, 3.0)
    assert not held_out_shows(members, 1, 2.0, 3.0)  # the test does not show it
    assert held_out_shows(members, 1, math.nan, 3.0)  # no fit without it: the margins


def test_a_delay_is_not_a_gain():
    d = Candidate(CHANNEL_DELAY, Location(0, -1, ("acc_m1", "sensor")), {}, fitted=True)
    assert not look_alike_member([_s("damper", "m1"), d], 1)


def _set(members, gap):
    from siva_core._impl.diagnose.set_fit import SetFit
    m0 = members[0]
    s = SetFit(m0.effect, m0.loc, {}, fitted=True, members=list(members))
    s.gap_after = gap
    return s


def test_a_member_matched_by_another_role_in_its_place_is_not_separated():
    from siva_core._impl.diagnose.member_test import unseparated
    qd, d13, d3 = _s("quadratic_damper", "m2"), _s("damper", "m1", "m3"), _s("damper", "m3")
    delay = Candidate(CHANNEL_DELAY, Location(0, -1, ("acc_m3", "sensor")), {}, fitted=True)
    spring = _s("cubic_spring", "m1", "m3")
    # fresh seed 17790's gaps: the third damper is matched by a channel delay
    big = _set([qd, d13, d3], 0.00236)
    sets = {frozenset(m.key for m in o.members): o for o in (
        big, _set([qd, d13, delay], 0.00252), _set([qd, d13], 0.00425))}
    out = unseparated(big.members, big.gap_after, sets, 0.75)
    assert [k for k, _ in out] == [2]
    # a set that beats every alternative of another role by the margin is separated
    pair = _set([qd, d13], 0.00425)
    sets[frozenset((qd.key, spring.key))] = _set([qd, spring], 0.0182)
    assert unseparated(pair.members, pair.gap_after, sets, 0.75) == []
    # a same-role alternative (a look-alike, for swap) does not count
    sets[frozenset((qd.key, d3.key))] = _set([qd, d3], 0.0045)
    assert unseparated(pair.members, pair.gap_after, sets, 0.75) == []
