"""The memo of what the chain derives from measured records (chain_cache): callers get
their own copies, a record changed in place is processed anew, and the memoised force of
``apply_simulated`` is the one ``apply`` computes."""
from __future__ import annotations

import numpy as np

from siva_core import Processing, Recording
from siva_core._impl import chain_cache


def _acc_force_only(rec: Recording) -> Recording:
    keep = {k: v.copy() for k, v in rec.channels.items() if k.startswith(("acc", "force"))}
    return Recording(rec.time.copy(), keep, rec.name)


CHAIN = dict(bandpass=(2.0, 60.0), highpass=2.0, notch=(45.0,), consistent=True, pad=0.5,
             decimate_to=200.0, gate_force=True, start="impact", order=4,
             integrator="simpson")


def test_apply_hands_out_copies_and_sees_in_place_edits(make_sdof) -> None:
    rec, _ = make_sdof(duration=3.0, t_hit=0.1)
    rec = _acc_force_only(rec)
    proc = Processing(**CHAIN)
    first = proc.apply(rec, ["x"])
    kept = first.q.copy()
    first.q[:] = 0.0  # the caller's copy: the memo must not change
    again = proc.apply(rec, ["x"])
    np.testing.assert_array_equal(again.q, kept)
    # a record modified in place is not served from the memo
    rec.channels["acc_x"] *= 2.0
    doubled = proc.apply(rec, ["x"])
    chain_cache.clear()
    fresh = proc.apply(rec, ["x"])
    for name in "tqvaf":
        np.testing.assert_array_equal(getattr(doubled, name), getattr(fresh, name))
    np.testing.assert_allclose(doubled.q, 2.0 * kept, rtol=1e-9, atol=1e-12 * abs(kept).max())
    # another chain on the same record is another entry
    other = Processing(**{**CHAIN, "highpass": 3.0}).apply(rec, ["x"])
    assert not np.array_equal(other.q, doubled.q)


def test_simulated_force_is_the_measured_chain_force(make_sdof) -> None:
    rec, _ = make_sdof(duration=3.0, t_hit=0.1)
    measured = _acc_force_only(rec)
    proc = Processing(**CHAIN)
    q, v, a = (rec.channels[f"{k}_x"][None, :, None] for k in ("disp", "vel", "acc"))
    chain_cache.clear()
    for _ in range(2):  # computed, then memoised
        ref = proc.apply(measured, ["x"])
        sim = proc.apply_simulated(measured, ["x"], q, v, a, need="a")
        np.testing.assert_array_equal(sim.f, ref.f)
        np.testing.assert_array_equal(sim.t, ref.t)
        assert sim.start_index == ref.start_index and sim.decimation == ref.decimation
        sim.f[:] = 0.0  # a caller's copy
    np.testing.assert_array_equal(proc.apply_simulated(measured, ["x"], q, v, a).f, ref.f)
