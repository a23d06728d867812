"""The one impulse detector: its threshold rule, and every user asking it the same question."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import (Processing, Recording, Structure, detect_impulse, gate_force,
                       initial_state_and_force)

FS = 1000.0
#: the documented rule (docs/formats.md): in the pulse above 2 % of the peak |F|; impulsive
#: when in the pulse on fewer than 10 % of the samples
PULSE_THRESHOLD = 0.02
MAX_PULSE_FRACTION = 0.10


def hammer(n: int = 2000, hits: tuple[tuple[int, float], ...] = ((200, 100.0),),
           width: int = 8, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """(n,) half-sine pulses of ``width`` samples starting at the given samples."""
    f = np.zeros(n)
    for start, peak in hits:
        f[start:start + width + 1] += peak * np.sin(np.pi * np.arange(width + 1) / width)
    return f + noise * np.random.default_rng(seed).standard_normal(n)


def test_rule_threshold_and_fraction() -> None:
    f = hammer()
    pulse = detect_impulse(f)
    assert pulse is not None
    above = np.flatnonzero(np.abs(f) > PULSE_THRESHOLD * np.abs(f).max())
    assert (pulse.first, pulse.last) == (above[0], above[-1]) == (201, 207)
    assert pulse.peak == 204 and pulse.end == 208  # first sample after the peak back below 2 %
    assert pulse.window(2) == (199, 210)
    # a continuous excitation is not impulsive: in its "pulse" on >= 10 % of the samples
    t = np.arange(2000) / FS
    assert detect_impulse(np.sin(2 * np.pi * 7.3 * t)) is None
    # the 10 % boundary itself: a flat force on exactly 10 % of the record is not impulsive
    flat = np.zeros(1000)
    flat[:int(MAX_PULSE_FRACTION * 1000)] = 1.0
    assert detect_impulse(flat) is None
    flat[int(MAX_PULSE_FRACTION * 1000) - 1] = 0.0
    assert detect_impulse(flat) is not None
    assert detect_impulse(None) is None and detect_impulse(np.zeros(100)) is None


def test_noise_below_threshold_is_not_pulse_but_gates_drop_it() -> None:
    f = hammer(noise=0.2)  # 0.2 % of the 100 N peak, as the reference rigs
    pulse = detect_impulse(f)
    assert pulse is not None and 199 <= pulse.first and pulse.last <= 209
    g = gate_force(f[:, None])[:, 0]
    lo, hi = pulse.window(2)
    assert np.all(g[:lo] == 0) and np.all(g[hi:] == 0)
    np.testing.assert_array_equal(g[lo:hi], f[lo:hi])
    # columns: the largest |F| over the DOFs decides
    two = np.stack([f, 0.5 * f], axis=1)
    assert detect_impulse(two).window() == pulse.window()


def test_multi_hit_gate_keeps_each_hit() -> None:
    f = hammer(hits=((200, 100.0), (900, 60.0)), noise=0.1)
    pulse = detect_impulse(f)
    assert pulse.peak == 204 and pulse.end == 208 and 900 <= pulse.last <= 908
    gate = pulse.gate(1)
    assert gate[500] == 0.0 and gate[204] == 1.0 and gate[904] == 1.0


def test_processing_and_simulation_use_the_same_pulse() -> None:
    """auto's "impulsive", the chain's start and gate, and the simulator's rest start all
    come from detect_impulse: one record, one answer."""
    structure = Structure.from_dict({
        "name": "sdof", "dofs": ["x"], "mass": {"x": 1.0}, "elements": [
            {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
            {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}}]})
    n = 4000
    t = np.arange(n) / FS
    f = hammer(n, noise=0.05)
    wn = 2 * np.pi * 12.0
    resp = np.where(t > 0.2, np.exp(-2.0 * (t - 0.2)) * np.sin(wn * (t - 0.2)), 0.0)
    rec = Recording(t, {"acc_x": resp, "force_x": f}, "hit")
    pulse = detect_impulse(f)
    auto = Processing.auto(rec, ["x"])
    assert auto.gate_force and auto.start == "impact"
    assert Processing(start="impact").start_index(rec, ["x"]) == pulse.end
    gated = Processing(gate_force=True).force(rec, ["x"])[:, 0]
    np.testing.assert_array_equal(gated != 0, pulse.gate() != 0)
    q0, v0, force = initial_state_and_force(structure, rec, Processing())
    assert np.all(q0 == 0) and np.all(v0 == 0)  # pre-triggered: starts at rest
    lo, hi = pulse.window(2)
    assert np.all(force[:lo] == 0) and np.all(force[hi:] == 0)


@pytest.mark.parametrize("threshold", [0.01, 0.05])
def test_threshold_is_a_parameter(threshold: float) -> None:
    f = hammer(width=40)
    pulse = detect_impulse(f, threshold)
    mag = np.abs(f)
    assert mag[pulse.first] > threshold * mag.max() >= mag[pulse.first - 1]
