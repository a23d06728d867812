"""The speed-ups of docs/perf.md 8.3 compute the same numbers as the code they replace,
bit for bit: the compiled zero-phase filter against scipy's, a batch of staged forces
against staging each, the sampled-force correction on the pulse's rows against the whole
record, a single simulated set on one thread against the same set in a batch, a record
simulated in two segments against one run, and the bootstrap's block weights."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import Structure, simulate, stage_force
from siva_core._impl.bootstrap import block_weights, series_of  # the bootstrap's weights
from siva_core._impl.processing import filters  # the compiled filter and its reference
from siva_core._impl.processing.filtfilt_kernel import filtfilt_kernel
from siva_core._impl.pulse_kick import sampled_force_acceleration
from siva_core._impl.simulate import simulate_split  # a record in two segments

#: every kind of filter the chain runs (band-pass, band edge at Nyquist, notch, high-pass
#: of the integration, low-pass of the decimation / differentiation), at LO-NO's and the
#: cantilever's rates
FILTERS = [("band", (2.875, 132.0), 2048.0, 4), ("band", (0.0, 132.0), 2048.0, 4),
           ("band", (5.0, 990.0), 2048.0, 3), ("notch", (60.0, 30.0), 2048.0, 4),
           ("high", 2.875, 2048.0, 4), ("low", 0.8 * 2048.0 / 3 / 2, 2048.0, 4),
           ("low", 151.2, 1000.0, 4)]


@pytest.mark.skipif(filtfilt_kernel() is None, reason="numba missing: scipy's path is used")
@pytest.mark.parametrize("key", FILTERS)
def test_compiled_zero_phase_filter_equals_scipys_bit_for_bit(key: tuple) -> None:
    sos, zi = filters.design_sos(*key), filters.sos_zi(*key)
    rng = np.random.default_rng(7)
    big = rng.standard_normal((5, 3000, 2)) * 1e-3
    cases = [(rng.standard_normal(4001), 0), (big, -2), (big[..., 1], -1),  # strided DOF
             (big[:1, :, 0], -1), (big[:2, :, 0], 1), (rng.standard_normal((40, 3)), 0),
             (rng.standard_normal(6), 0)]
    for x, axis in cases:
        n = x.shape[axis]
        for padlen in {min(3 * (2 * len(sos) + 1), n - 1), 0}:
            want = filters.sosfiltfilt_scipy(sos, zi, x, axis, padlen)
            got = filters.sosfiltfilt(sos, zi, x, axis, padlen)
            assert got.shape == want.shape
            assert np.array_equal(got, want), (key, x.shape, axis, padlen)


@pytest.mark.parametrize("interp", ["moments", "linear", "cubic"])
def test_a_batch_of_forces_staged_as_each_alone(interp: str) -> None:
    """The replicates' forces differ in a pulse's few samples: the batch copies the first
    and recomputes only the intervals that differ."""
    rng = np.random.default_rng(2)
    T, n = 300, 2
    base = np.zeros((T, n))
    base[40:45, 1] = [30.0, 80.0, 100.0, 70.0, 20.0]
    F = np.repeat(base[None], 5, axis=0)
    F[1:, 40:45] += rng.standard_normal((4, 5, n))
    F[2] = rng.standard_normal((T, n))          # differs everywhere
    F[3, -1] += 1.0                             # only the last sample
    for m in (1, 3):
        want = np.stack([stage_force(f, m, interp) for f in F])
        assert np.array_equal(stage_force(F, m, interp), want)


def test_sampled_force_acceleration_on_the_pulse_rows_only() -> None:
    """The correction is computed where the force's reading differs from its samples; the
    result equals the whole-record formula (zero elsewhere)."""
    st = Structure.from_dict({
        "name": "two", "dofs": ["a", "b"], "mass": {"a": 1.5, "b": 2.0},
        "elements": [{"kind": "spring", "between": ["a", "ground"], "params": {"k": "k1"}},
                     {"kind": "spring", "between": ["a", "b"], "params": {"k": "k2"}}]})
    rng = np.random.default_rng(4)
    T, m, B = 200, 2, 3
    F = np.zeros((T, 2))
    F[50:54, 1] = [10.0, 40.0, 35.0, 5.0]
    staged = np.repeat(stage_force(F, m, "moments")[None], B, axis=0)
    staged[:, 2 * m * 50:2 * m * 53] += rng.standard_normal((B, 2 * m * 3, 2))  # a kick
    a = rng.standard_normal((B, T, 2))
    scale = np.array([1.0, 0.9, 1.1])
    gain = np.array([1 / 1.5, 1 / 2.0])
    want = a + np.broadcast_to((F - staged[:, ::2 * m, :]) * gain, a.shape) * scale[:, None, None]
    got = sampled_force_acceleration(st, a, F, staged, m, scale)
    assert np.array_equal(got, want)
    assert sampled_force_acceleration(st, a, np.zeros((T, 2)), np.zeros_like(staged), m,
                                      None) is a


def test_a_single_set_on_one_thread_equals_the_set_in_a_batch(lono_model: Structure) -> None:
    """A batch of one runs on the calling thread alone (numba's pool is not woken): the
    same kernel, the same numbers; the pool's thread count is restored."""
    numba = pytest.importorskip("numba")
    theta = np.array([3.84, 19273.0, 0.786, 1947.6, 2.76e7, 2.0])[None] * np.array([[1.0], [1.01]])
    t = np.arange(2000) / 2048.0
    F = np.zeros((len(t), 2))
    F[100:106, 1] = [50.0, 300.0, 530.0, 400.0, 120.0, 10.0]
    before = numba.get_num_threads()
    both = simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps=3,
                    backend="numba")
    alone = simulate(lono_model, theta[1:], t, np.zeros(2), np.zeros(2), F, substeps=3,
                     backend="numba")
    assert numba.get_num_threads() == before
    assert np.array_equal(alone.a[0], both.a[1]) and np.array_equal(alone.q[0], both.q[1])


def test_a_record_simulated_in_two_segments_equals_one_run(lono_model: Structure) -> None:
    """``simulate_split``: per-set force in the head (a kick at the pulse), the shared force
    after it; the second segment starts from the first's state: the same steps."""
    pytest.importorskip("numba")
    theta = np.array([3.84, 19273.0, 0.786, 1947.6, 2.76e7, 2.0])[None] * np.array(
        [[1.0], [1.02], [0.97]])
    t = np.arange(3000) / 2048.0
    F = np.zeros((len(t), 2))
    F[100:106, 1] = [50.0, 300.0, 530.0, 400.0, 120.0, 10.0]
    m = 3
    shared = stage_force(F, m, "moments")
    w = 108
    rng = np.random.default_rng(1)
    full = np.repeat(shared[None], 3, axis=0)
    full[:, 2 * m * 99:2 * m * 107] += rng.standard_normal((3, 2 * m * 8, 2))
    head = np.ascontiguousarray(full[:, :2 * m * w + 1])
    scale = np.array([1.0, 0.98, 1.03])
    one = simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), np.repeat(F[None], 3, 0),
                   substeps=m, backend="numba", force_scale=scale, staged_force=full)
    two = simulate_split(lono_model, theta, t, np.zeros(2), np.zeros(2), head, shared, m, scale)
    for x, y in zip((one.q, one.v, one.a), two):
        assert np.array_equal(x, y)


def test_block_weights_count_the_blocks_as_one_by_one() -> None:
    """The moving-block bootstrap's row weights from a running sum of block starts and
    ends: the numbers of the loop that added each block (integers, exact)."""
    import math

    def by_loop(series, L, rng):
        w = np.zeros(sum(s.T * s.width for s in series))
        for s in series:
            Lk = min(L, s.T)
            counts = np.zeros(s.T)
            for a in rng.integers(0, s.T - Lk + 1, size=math.ceil(s.T / Lk)):
                counts[a:a + Lk] += 1.0
            counts *= s.T / counts.sum()
            w[s.start:s.start + s.T * s.width] = np.repeat(counts, s.width)
        return w

    for shapes, L in [([(1000, 2)], 31), ([(50, 1), (7, 3)], 12), ([(3, 2)], 5)]:
        series = series_of(shapes)
        r1, r2 = np.random.default_rng(5), np.random.default_rng(5)
        for _ in range(20):
            assert np.array_equal(block_weights(series, L, r2), by_loop(series, L, r1))


def test_compiled_cumulative_simpson_equals_scipys_bit_for_bit() -> None:
    """The chain's integration (``cumulative_integral``, "simpson") by the compiled loop:
    scipy's h1/h2 sub-integrals summed in the same order."""
    from scipy import integrate

    from siva_core._impl.processing.calculus import cumulative_integral

    rng = np.random.default_rng(3)
    strided = rng.standard_normal((400, 5, 2))[:, :, 1]
    for x in (rng.standard_normal(3), rng.standard_normal(4), rng.standard_normal((5, 2)),
              1e-6 * rng.standard_normal((1001, 3, 2)), strided):
        for dt in (1 / 2048, 0.37):
            want = integrate.cumulative_simpson(x, dx=dt, axis=0, initial=0.0)
            assert np.array_equal(cumulative_integral(x, dt, "simpson"), want)
