"""Sets of effects (issue 16): a joint pair fit explains what neither effect explains
alone, the set rule prefers it only when both members are needed, an element fitted to
nothing does not show above the noise; and the scenario generator is seeded and draws
what its doc says."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from siva_core import EFFECTS, Processing, Structure
from siva_core._impl.diagnose import (Candidate, DiagnoseSettings, Location, augmented,
                                      synthetic_impacts, with_effect)
from siva_core._impl.diagnose.scoring import judge, validation_gap
from siva_core._impl.diagnose.pair_fit import fit_pair
from siva_core._impl.diagnose.set_members import contributions
from siva_core._impl.diagnose.set_rules import better
from siva_core._impl.diagnose.where import spectral_noise_floor
from siva_core._impl.diagnose.verdict import look_alike

ROOT = Path(__file__).resolve().parents[1]

TWO = {"name": "two", "dofs": ["x", "y"], "mass": {"x": 1.0, "y": 0.5},
       "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k1"}},
                    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c1"}},
                    {"kind": "spring", "between": ["x", "y"], "params": {"k": "k2"}},
                    {"kind": "damper", "between": ["x", "y"], "params": {"c": "c2"}}]}
NOMINAL = {"k1": 6000.0, "c1": 1.0, "k2": 3000.0, "c2": 0.5}
G = Location(0, -1, ("x", "ground"))
XY = Location(0, 1, ("x", "y"))
K3, FC = 2.0e7, 0.6


def _single(st: Structure, kind: str, loc: Location, value: float, train, val, proc, gap,
            blocks) -> Candidate:
    eff = EFFECTS[kind]
    aug, names = augmented(st, eff, loc, {eff.magnitude: abs(value)})
    c = Candidate(eff, loc, {}, fitted=True, structure=aug, names=names,
                  theta=aug.vector({**NOMINAL, names[eff.magnitude]: value}))
    c.coefficients = {eff.magnitude: value}
    judge(c, val, proc, gap, blocks)
    return c


def two_dof_records(effects, duration: float, seeds: tuple[int, int]):
    """The 2-DOF model, train (60 + 150 N) and validation (30 + 200 N) hits on y of it
    with ``effects`` [(kind, between, coefficients)], no processing, and the nominal
    validation gap with its blocks."""
    st = Structure.from_dict(TWO)
    gen = st
    for kind, between, coeffs in effects:
        gen = with_effect(gen, kind, between, coeffs)
    theta = gen.vector(NOMINAL)
    train, val = (synthetic_impacts(gen, theta, amps, dof="y", fs=1024.0, duration=duration,
                                    seed=seed)
                  for amps, seed in (([60.0, 150.0], seeds[0]), ([30.0, 200.0], seeds[1])))
    proc = Processing.none()
    gap, blocks = validation_gap(st, st.vector(NOMINAL), val, proc)
    return st, train, val, proc, gap, blocks


@pytest.fixture(scope="module")
def pair_case():
    st, train, val, proc, gap, blocks = two_dof_records(
        [("cubic_spring", ("x", "ground"), {"k3": K3}), ("coulomb", ("x", "y"), {"fc": FC})],
        2.0, (1, 2))
    noise = spectral_noise_floor(st, val, proc, st.vector(NOMINAL))
    return st, train, val, proc, gap, blocks, noise


@pytest.mark.slow
def test_joint_pair_explains_what_neither_single_does(pair_case):
    st, train, val, proc, gap, blocks, noise = pair_case
    settings = DiagnoseSettings()
    a = _single(st, "cubic_spring", G, K3, train, val, proc, gap, blocks)
    b = _single(st, "coulomb", XY, FC, train, val, proc, gap, blocks)
    assert a.closure < 0.95 and b.closure < 0.95  # each is only a part
    pair = fit_pair(a, b, st, train, val, proc, gap, blocks, settings)
    assert pair is not None and pair.closure > 0.95
    assert better(pair, a.gap_after, noise, settings) and better(pair, b.gap_after, noise,
                                                                  settings)
    assert [m.label() for m in pair.members] == [a.label(), b.label()]
    contrib = contributions(pair, val, proc)
    assert len(contrib) == 2 and min(contrib) > settings.contribution_noise * noise


@pytest.mark.slow
def test_element_fitted_to_nothing_does_not_show_above_noise(pair_case):
    st, train, val, proc, gap, blocks, noise = pair_case
    tiny = _single(st, "cubic_spring", G, K3 * 1e-4, train, val,
                   proc, gap, blocks)
    (x,) = contributions(tiny, val, proc)
    assert x < DiagnoseSettings().contribution_noise * noise


def test_look_alike_groups():
    assert look_alike("quadratic_damper", "coulomb") and look_alike("cubic_spring", "clearance")
    assert look_alike("damper", "cubic_damper")
    assert not look_alike("coulomb", "cubic_spring") and not look_alike("quadratic_spring",
                                                                         "coulomb")
    # branch lookalike-qspring: a quadratic spring mimics a cubic one over the measured
    # amplitudes (fresh seeds 17975, 17839): one spring group
    assert look_alike("quadratic_spring", "cubic_spring")


def test_scenarios_are_seeded_and_within_their_ranges():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenarios

    a, b = scenarios.draw(7), scenarios.draw(7)
    assert scenarios.describe(a) == scenarios.describe(b)
    assert np.array_equal(a.val[0].channels[next(iter(a.val[0].channels))],
                          b.val[0].channels[next(iter(b.val[0].channels))])
    for s in (a, scenarios.draw(8), scenarios.draw(9)):  # 9: two effects diverging together
        assert 1 <= s.info["dofs"] <= 4
        assert len(s.train) == 2 and 1 <= len(s.val) <= 2
        assert len(s.effects) <= 2 and all(v >= 1.0 for v in s.visibility)
        assert s.info["fs"] >= 5 * max(s.info["modes_hz"]) - 1
        assert len(s.train[0].time) <= 8192
        assert s.category in ("null", "single", "two", "three")


def _gap(g: float) -> Candidate:
    c = Candidate(EFFECTS["coulomb"], G, {})
    c.gap_after = g
    return c


def test_a_set_at_the_noise_level_needs_one_noise_floor_per_member():
    s = DiagnoseSettings()  # step_min 0.25, noise_factor 2, kind_check_noise 3
    # seed 13006's numbers in noise units: the damper alone 3.1, with the gain 1.6
    assert better(_gap(1.6), 3.1, 1.0, s)
    # not at the noise level (3.5 > 3): the whole margin (2 x) applies to a 1.5 gain
    assert not better(_gap(3.5), 5.0, 1.0, s)
    # at the noise level, but removing less than the floor, or less than step_min
    assert not better(_gap(1.0), 1.8, 1.0, s)
    assert not better(_gap(2.9), 3.8, 1.0, s)  # 0.9: below the floor and step_min
    assert not better(_gap(2.0), 2.4, 0.1, s)  # 0.4 < 0.25 x 2.4


def test_later_structural_fits_paired_with_a_sensor_fault():
    from siva_core._impl.diagnose.grow import worth_pairing

    s = DiagnoseSettings()
    cands = []
    for cost, kind in [(0.0075, "clearance"), (0.0081, "quadratic_spring"),
                       (0.0095, "cubic_spring"), (0.006, "coulomb"), (0.007, "spring")]:
        c = Candidate(EFFECTS[kind], G, {}, fitted=True)
        c.train_cost = cost
        cands.append(c)
    got = worth_pairing(cands, 0.01036, s)  # the stage started at 0.01036 (seed 13010)
    # below (1 - step_min / 2) x 0.01036 = 0.00907, best first, at most pair_members
    assert [c.effect.kind for c in got] == ["coulomb", "spring", "clearance"]


def test_a_sensor_value_is_refitted_with_the_structural_model():
    """The delay fitted without the structural effect is biased; re-fitted with the right
    model (here the generating one) it returns to the truth (joint_sensor's doc)."""
    from siva_core._impl.diagnose.joint_sensor import retune_sensor
    from siva_core._impl.diagnose.sensor_faults import CHANNEL_DELAY, corrected

    st = Structure.from_dict(TWO)
    gen = with_effect(st, "cubic_spring", ("x", "ground"), {"k3": K3})
    theta = gen.vector(NOMINAL)
    fs, delay = 512.0, 2.0 / 512.0
    clean = synthetic_impacts(gen, theta, [60.0, 150.0], dof="y", fs=fs, duration=1.5,
                              seed=3)
    # the faulty records: channel x lags by two samples (corrected() with -delay undoes
    # a lead, i.e. makes the lag)
    train = corrected(clean, CHANNEL_DELAY, "acc_x", -delay)
    c = Candidate(CHANNEL_DELAY, Location(0, -1, ("acc_x", "sensor")), {})
    c.coefficients = {"delay": delay - 0.8 / fs}  # biased by 0.8 samples
    out = retune_sensor(c, gen, theta, train, Processing.none(), 10)
    assert out is not None
    new, th, cost, _ = out
    assert abs(new.coefficients["delay"] - delay) < 0.25 / fs
    assert c.coefficients["delay"] == pytest.approx(delay - 0.8 / fs)  # a copy, not c


def test_scenario_effects_are_bounded_on_every_record():
    """Seeds whose effects dominated a train record before the bounds (13002: coulomb
    fc 52 N against 2.6-9.1 N hits; 13007: a 1890 N s/m damper; 13008: fc 25 N)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenario_bounds as bounds
    import scenarios

    for seed in (13002, 13007, 13008, 13012):
        s = scenarios.draw(seed)
        assert len(s.info["bounds"]) == len(s.effects)
        for (kind, _, coeffs), b in zip(s.effects, s.info["bounds"]):
            assert b["dominance"] <= bounds.DOMINANCE
            assert b["train_visibility"] >= bounds.TRAIN_VISIBLE
            if kind == "coulomb":
                assert coeffs["fc"] <= bounds.FRICTION_SHARE * b["elastic_small"] * 1.01
            if kind == "damper":
                assert coeffs["c"] < 1890.0


def test_bounds_refuse_a_locking_friction_and_an_overdamping_damper():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenario_bounds as bounds

    st = Structure.from_dict(TWO)
    small = lambda c: [0.1]  # noqa: E731 - the response hardly changes
    no_damping = lambda c: 0.01  # noqa: E731
    assert bounds.excess("coulomb", ("x", "ground"), {"fc": 5.0}, small, 10.0,
                         no_damping) > 1.0  # fc above 0.3 x the 10 N elastic force
    assert bounds.excess("coulomb", ("x", "ground"), {"fc": 2.0}, small, 10.0,
                         no_damping) <= 1.0
    zeta = bounds.max_damping(st, NOMINAL, "damper", ("y", "ground"), {"c": 500.0}, 1.0)
    assert zeta > bounds.ZETA_MAX  # y (0.5 kg) on ~55 rad/s: critical near 55 N s/m
    assert bounds.max_damping(st, NOMINAL, "damper", ("y", "ground"), {"c": 1.0},
                              1.0) < bounds.ZETA_MAX


def test_a_sensor_fault_is_judged_on_the_gap_above_the_noise():
    """A force gain that brings the validation records to 1.5 x the floor closes only
    0.44 of a gap 2.8 x the floor (fresh seed 15032's numbers): named on the gap above
    the noise, when its interval excludes gain 1; not when the interval holds 1, not
    when it removes less than half the excess, never for a structural candidate."""
    from siva_core._impl.diagnose.sensor_faults import FORCE_GAIN
    from siva_core._impl.diagnose.verdict import decide, sensor_above_noise

    s = DiagnoseSettings()
    floor, gap = 0.00262, 0.00726

    def fault(gap_after: float, interval: tuple[float, float]) -> Candidate:
        c = Candidate(FORCE_GAIN, Location(0, -1, ("force_x", "sensor")), {}, fitted=True)
        c.gap_after, c.closure = gap_after, 1 - gap_after / gap
        c.coefficients, c.intervals = {"gain": 0.912}, {"gain": interval}
        c.per_record = [{"record": "v", "gap_before": gap, "gap_after": gap_after,
                         "closure": 1 - gap_after / gap}]
        return c

    right = fault(0.00408, (0.90, 0.925))
    assert right.closure < s.closure_min  # refused before: closes 0.44 of the whole gap
    assert sensor_above_noise(right, gap, floor, s)
    v, rule = decide([right], gap, floor, s)
    assert v is right and rule["checks"]["closure"] and rule["checks"]["above_noise"]
    assert not sensor_above_noise(fault(0.00408, (0.97, 1.02)), gap, floor, s)
    assert not sensor_above_noise(fault(0.0055, (0.90, 0.925)), gap, floor, s)  # 0.38
    assert decide([right], gap, gap / 1.9, s)[0] is None  # gap < 2 x floor: the noise
    struct = _gap(0.00408)
    struct.closure = 1 - 0.00408 / gap
    assert not sensor_above_noise(struct, gap, floor, s)


#: seeds whose drawn effect the bounds used to drop and that now need a re-draw (seed 0:
#: a cubic damper the 1 N train hits cannot show within the bounds on the 10 N record;
#: 15001: a quadratic spring, dropped in the fresh batch)
KEPT_SEEDS = (0, 10, 15001)


def test_the_generator_keeps_the_drawn_mix():
    """Seeds whose effects the bounds used to drop (listed with the re-draws they now
    need): every drawn structural effect is kept, each within the bounds, and the draw
    stays deterministic."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import scenario_bounds as bounds
    import scenarios

    for seed in KEPT_SEEDS:
        s = scenarios.draw(seed)
        assert len(s.effects) == s.info["drawn"]["structural"] <= scenarios.MAX_STRUCTURAL
        assert s.info["redraws"] and not s.info["dropped"]
        assert len({frozenset(b) for _, b, _ in s.effects}) == len(s.effects)
        for b in s.info["bounds"]:
            assert b["dominance"] <= bounds.DOMINANCE
            assert b["train_visibility"] >= bounds.TRAIN_VISIBLE
        assert all(v >= 1.0 for v in s.visibility)
    again = scenarios.draw(KEPT_SEEDS[0])
    assert scenarios.describe(again) == scenarios.describe(scenarios.draw(KEPT_SEEDS[0]))
