"""The simulation kernel is serial and re-entrant (branch speed6): no ``prange`` (numba's
parallel lowering made every per-signature compile ~2.3x longer), and calls from several
threads at once (the diagnosis' workers, no lock any more) give the numbers of one call
after another, bit for bit."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from siva_core import Structure, simulate
from siva_core._impl.simulate import compiled_kernel  # which kernel runs is private


def test_the_kernel_is_compiled_without_parallel_lowering(lono_model: Structure) -> None:
    pytest.importorskip("numba")
    kernel = compiled_kernel(lono_model)
    assert not kernel.targetoptions.get("parallel"), kernel.targetoptions
    assert "prange" not in kernel.py_func.__code__.co_names


def test_threads_simulating_at_once_equal_one_after_another(lono_model: Structure) -> None:
    pytest.importorskip("numba")
    base = np.array([3.84, 19273.0, 0.786, 1947.6, 2.76e7, 2.0])
    thetas = [base[None] * np.linspace(0.9, 1.1, 5)[:, None] * (1 + 0.01 * k) for k in range(6)]
    t = np.arange(3000) / 2048.0
    F = np.zeros((len(t), 2))
    F[100:106, 1] = [50.0, 300.0, 530.0, 400.0, 120.0, 10.0]

    def run(theta: np.ndarray) -> np.ndarray:
        return simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps=3,
                        backend="numba").a

    alone = [run(th) for th in thetas]
    with ThreadPoolExecutor(max_workers=3) as pool:
        together = list(pool.map(run, thetas))
    for a, b in zip(alone, together):
        assert np.array_equal(a, b)
    # and a set is the same alone as inside its batch
    assert np.array_equal(run(thetas[2][3:4])[0], alone[2][3])


def test_a_lone_batch_split_over_threads_equals_one_call(lono_model: Structure,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A lone caller's batch runs as chunks on several threads (the kernel being serial);
    every set is computed by the same code, so the split changes no bit."""
    pytest.importorskip("numba")
    from siva_core._impl.simulate import numba_kernel

    base = np.array([3.84, 19273.0, 0.786, 1947.6, 2.76e7, 2.0])
    theta = base[None] * np.linspace(0.8, 1.2, 11)[:, None]
    t = np.arange(2000) / 2048.0
    F = np.zeros((len(t), 2))
    F[100:104, 0] = [80.0, 250.0, 160.0, 20.0]

    def run() -> np.ndarray:
        return simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps=2,
                        backend="numba").a

    chunks: list[tuple[int, int]] = []
    original = numba_kernel._run_chunked

    def spy(run_chunk, B: int) -> None:
        original(lambda a, b: (chunks.append((a, b)), run_chunk(a, b))[1], B)

    monkeypatch.setattr(numba_kernel, "_thread_count", lambda: 1)
    one = run()
    monkeypatch.setattr(numba_kernel, "_thread_count", lambda: 3)
    monkeypatch.setattr(numba_kernel, "_run_chunked", spy)
    split = run()
    assert sorted(chunks) == [(0, 4), (4, 7), (7, 11)]
    assert np.array_equal(one, split)
