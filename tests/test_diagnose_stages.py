"""The diagnosis's stages after a first named effect (issue 16): when a further effect is
looked for, and how its stage is judged."""
from __future__ import annotations

from siva_core._impl.diagnose import DiagnoseSettings


def test_a_second_stage_runs_when_the_first_effect_leaves_more_than_the_noise():
    """Stopping after one effect needs a leftover below gap_min *and* within
    kind_check_noise x the noise floor (issue 16: a clearance left 0.0025, 4 x the noise,
    and the damper of the pair was never looked for); the old rule stopped on gap_min."""
    from siva_core import EFFECTS
    from siva_core._impl.diagnose import Candidate, Location
    from siva_core._impl.diagnose.stage_outcome import explained

    v = Candidate(EFFECTS["clearance"], Location(0, -1, ("m1", "ground")), {}, fitted=True,
                  gap_before=0.0177, gap_after=0.0025, closure=0.857)
    s = DiagnoseSettings()
    assert v.gap_after <= s.gap_min                      # the old rule stopped here
    assert not explained(v, s, noise=6e-4)              # 4 x the noise: look further
    assert explained(v, s, noise=1e-3)                  # 2.5 x the noise: explained
    assert explained(v, s, noise=None)
    v.gap_after = 0.006
    assert not explained(v, s, noise=1e-2)              # above gap_min


def test_a_later_stage_is_judged_against_the_noise_not_the_fixed_floor():
    """What a named effect leaves (0.0025, 4 x the noise floor) is below gap_min; a second
    effect closing 60 % of it is named at a later stage, not at the first (issue 16; at
    the first it closes 0.79 of the part above the floor, under faint_closure -- since
    branch absorbed a candidate closing 0.8 of that part passes at the first stage too)."""
    from siva_core import EFFECTS
    from siva_core._impl.diagnose import Candidate, Location
    from siva_core._impl.diagnose.verdict import decide

    c = Candidate(EFFECTS["damper"], Location(0, 2, ("m1", "m3")), {}, fitted=True,
                  gap_before=0.0025, gap_after=0.001, closure=0.6)
    c.per_record = [{"record": "r", "gap_before": 0.0025, "gap_after": 0.001,
                     "closure": 0.6}]
    first, rule = decide([c], 0.0025, 6e-4, DiagnoseSettings())
    assert first is None and not rule["checks"]["above_noise"]
    later, _ = decide([c], 0.0025, 6e-4, DiagnoseSettings(), later=True)
    assert later is c
    at_noise, _ = decide([c], 0.0025, 2e-3, DiagnoseSettings(), later=True)
    assert at_noise is None                              # below 2 x the noise floor


def test_a_later_stage_floor_is_the_spectral_one_when_lower():
    """Fresh seed 17898: after a coulomb (closure 0.74) a 1.1 force gain takes the gap
    0.0198 to 0.0131; its own train cost 0.0158 as the floor made the stage read "at the
    noise" (1.2 x); the spectral floor 0.0070 makes it 2.8 x and the gain is named.  The
    first stage keeps the train-cost floor."""
    from siva_core._impl.diagnose import Candidate, Location
    from siva_core._impl.diagnose.sensors import FORCE_GAIN
    from siva_core._impl.diagnose.verdict import decide, stage_floor

    g = Candidate(FORCE_GAIN, Location(1, -1, ("force_m2", "sensor")), {}, fitted=True,
                  gap_before=0.01976, gap_after=0.0131, closure=0.337, train_cost=0.01584)
    g.intervals = {g.effect.magnitude: (1.09, 1.11)}
    g.per_record = [{"record": "r", "gap_before": 0.01976, "gap_after": 0.0131,
                     "closure": 0.337}]
    assert stage_floor(0.0207, [g], 0.00703, later=False) == 0.01584
    later = stage_floor(0.0207, [g], 0.00703, later=True)
    assert later == 0.00703 and stage_floor(0.0207, [g], None, later=True) == 0.01584
    s = DiagnoseSettings()
    before, rule = decide([g], 0.01976, 0.01584, s, later=True, spectral=0.00703)
    assert before is None and not rule["checks"]["above_noise"]
    named, _ = decide([g], 0.01976, later, s, later=True, spectral=0.00703)
    assert named is g


def test_a_lead_removing_many_times_the_noise_is_kept_tentatively():
    """No single closes half of a gap many times the noise (fresh seed 17335: a cubic
    damper m1-m4 closed 0.20 of 0.0922, removing 75 x the floor 0.000247; the coulomb of
    the pair showed only from its model).  ``large_part`` keeps such a lead whatever its
    closure; a removal under ``faint_noise`` x the floor, a gap at the noise, no
    spectral floor, or a force gain the pulse reading explains is not kept."""
    from siva_core import EFFECTS
    from siva_core._impl.diagnose import Candidate, Location
    from siva_core._impl.diagnose.stage_outcome import large_part, partial_lead

    s = DiagnoseSettings()
    gap, noise = 0.09217, 0.0002468
    lead = Candidate(EFFECTS["cubic_damper"], Location(0, 3, ("m1", "m4")), {},
                     fitted=True, gap_before=gap, gap_after=0.07369, closure=0.200)
    rule = {"checks": {"above_noise": True, "closure": False, "separation": False,
                       "consistent": True}}
    assert not partial_lead(rule, [lead], s)                 # under step_min: refused before
    part = large_part([lead], gap, noise, s)
    assert part is not None and 74 < part["removed_x_floor"] < 76
    assert large_part([lead], gap, None, s) is None
    assert large_part([lead], gap, 0.0185 / 9, s) is None   # removes 9 x: not kept
    assert large_part([lead], gap, gap / 9, s) is None      # the gap itself 9 x the floor
    lead.reading = True
    assert large_part([lead], gap, noise, s) is None
