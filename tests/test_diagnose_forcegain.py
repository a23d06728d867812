"""A gain beside a structural effect that the records pin outside the hammer pulse's
reading (issue 16, branch forcegain; fresh seed 17720, burned): its value and interval
outside the reading's range make it a fault, not the reading's nuisance; its step is judged
on the gap above the noise floor and confirmed by the held-out test."""
from __future__ import annotations

from types import SimpleNamespace

from siva_core import DiagnoseSettings
from siva_core._impl.diagnose.pulse_reading import gain_range, outside_reading
from siva_core._impl.diagnose.set_rules import better

from synthetic import half_sine_hit, unit_sdof


def _gain(value: float, interval: tuple[float, float] | None) -> SimpleNamespace:
    st, th = unit_sdof()
    return SimpleNamespace(category="sensor", structure=st, theta=th,
                           effect=SimpleNamespace(kind="force_gain", magnitude="gain"),
                           coefficients={"gain": value},
                           intervals={"gain": interval} if interval else {})


def test_a_gain_is_pinned_only_when_value_and_interval_leave_the_reading():
    """A 5-sample half-sine at 512 Hz, 10 Hz mode: the reading explains about +-1 %."""
    rec = half_sine_hit(5.0, 0.3)
    st, th = unit_sdof()
    low, high, _ = gain_range(st, th, [rec])
    assert 0.95 < low < 1.0 < high < 1.05
    assert outside_reading(_gain(0.953, (0.952, 0.954)), [rec]) == (low, high)
    assert outside_reading(_gain(1.2, None), [rec]) is not None
    # the value outside, its interval reaching into the band: not pinned
    assert outside_reading(_gain(low - 0.005, (low - 0.01, low + 0.001)), [rec]) is None
    assert outside_reading(_gain(1.0, (0.999, 1.001)), [rec]) is None


def test_a_pinned_gain_steps_on_the_gap_above_the_floor():
    """17720's numbers: the coulomb alone leaves 0.00909, with the gain 0.00746 (18 % of
    it, 26 % of its part above the floor 0.00291), held-out z 7.1."""
    s = DiagnoseSettings()
    big = SimpleNamespace(gap_after=0.00746)
    assert not better(big, 0.00909, 0.00291, s, lambda: 7.1)
    assert better(big, 0.00909, 0.00291, s, lambda: 7.1, above_floor=True)
    assert not better(big, 0.00909, 0.00291, s, lambda: 2.0, above_floor=True)
