"""The chain's zero-phase filter (and its cumulative integral) as one compiled pass over
many signals at once.

``filters.sosfiltfilt`` (scipy's ``sosfiltfilt`` with memoised initial conditions) spent
most of its time outside the recurrence: scipy copies the signals into rows, builds the
odd extension, filters forward, reverses, copies again, filters backward, reverses, and
its compiled loop runs one signal at a time, each sample waiting for the previous one.
Here the signals of a batch (parameter sets x DOFs) lie side by side, time-major, and
every step of the recurrence is done for all of them before the next: the same
operations, in the same order, on each signal as scipy's ``_sosfilt`` (no fast-math, so
no fused or reassociated arithmetic) -- bit-identical results (``tests/test_fast_paths.py``
compares them on every filter of the chain) -- with the copies gone and the signals'
independent chains overlapping in the CPU.  LO-NO's identify spent 2.1 s of CPU in the
filters, docs/perf.md 8.3.
"""
from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=1)
def _numba():
    """numba, imported at the first filter call (not with the chain: ``siva --help`` and
    record handling stay light), or None when it is missing (scipy's path stays)."""
    try:
        import numba
    except ImportError:
        return None
    return numba


def _filtfilt_time_major(sos: np.ndarray, zi: np.ndarray, x: np.ndarray,
                         padlen: int) -> np.ndarray:
    """(n, S) zero-phase filtered ``x`` (n, S) (time-major, S independent signals): the
    odd extension by ``padlen`` samples, the sections forward from ``zi`` times the first
    extended sample, backward from ``zi`` times the last forward output, extension cut."""
    n, S = x.shape
    ns = sos.shape[0]
    m = n + 2 * padlen
    y = np.empty((m, S))
    if S < _SIDE_BY_SIDE:
        for j in range(S):
            _one_signal(sos, zi, x, padlen, j, y)
        return y[padlen:padlen + n]
    for i in range(padlen):  # 2 x[0] - x[padlen - i], as scipy's odd_ext
        for j in range(S):
            y[i, j] = 2.0 * x[0, j] - x[padlen - i, j]
    for k in range(n):
        for j in range(S):
            y[padlen + k, j] = x[k, j]
    for i in range(padlen):  # 2 x[-1] - x[-2 - i]
        for j in range(S):
            y[padlen + n + i, j] = 2.0 * x[n - 1, j] - x[n - 2 - i, j]
    z0 = np.empty((ns, S))
    z1 = np.empty((ns, S))
    cur = np.empty(S)
    for d in range(2):  # forward from the first sample, then backward from the last
        first = 0 if d == 0 else m - 1
        for s in range(ns):
            for j in range(S):
                z0[s, j] = zi[s, 0] * y[first, j]
                z1[s, j] = zi[s, 1] * y[first, j]
        for k in range(m):  # scipy's _sosfilt per signal (backward: the reversed signal)
            t = k if d == 0 else m - 1 - k
            for j in range(S):
                cur[j] = y[t, j]
            for s in range(ns):
                b0 = sos[s, 0]
                b1 = sos[s, 1]
                b2 = sos[s, 2]
                a1 = sos[s, 4]
                a2 = sos[s, 5]
                for j in range(S):
                    xn = b0 * cur[j] + z0[s, j]
                    z0[s, j] = b1 * cur[j] - a1 * xn + z1[s, j]
                    z1[s, j] = b2 * cur[j] - a2 * xn
                    cur[j] = xn
            for j in range(S):
                y[t, j] = cur[j]
    return y[padlen:padlen + n]


#: fewer signals than this are filtered one after the other (``_one_signal``): side by
#: side, the loops over so few signals cost more than they overlap
_SIDE_BY_SIDE = 3


def _one_signal(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, padlen: int, j: int,
                y: np.ndarray) -> None:
    """Column ``j`` of ``_filtfilt_time_major`` alone, its state in scalars' reach: the
    same operations as the side-by-side loops (and scipy's) for one signal."""
    n = x.shape[0]
    ns = sos.shape[0]
    m = n + 2 * padlen
    for i in range(padlen):
        y[i, j] = 2.0 * x[0, j] - x[padlen - i, j]
    for k in range(n):
        y[padlen + k, j] = x[k, j]
    for i in range(padlen):
        y[padlen + n + i, j] = 2.0 * x[n - 1, j] - x[n - 2 - i, j]
    z0 = np.empty(ns)
    z1 = np.empty(ns)
    for d in range(2):  # forward, then backward, as above
        first = 0 if d == 0 else m - 1
        for s in range(ns):
            z0[s] = zi[s, 0] * y[first, j]
            z1[s] = zi[s, 1] * y[first, j]
        for k in range(m):
            t = k if d == 0 else m - 1 - k
            cur = y[t, j]
            for s in range(ns):
                xn = sos[s, 0] * cur + z0[s]
                z0[s] = sos[s, 1] * cur - sos[s, 4] * xn + z1[s]
                z1[s] = sos[s, 2] * cur - sos[s, 5] * xn
                cur = xn
            y[t, j] = cur

_compiled = None
_simpson = None


def filtfilt_kernel():
    """The compiled ``_filtfilt_time_major`` (None without numba)."""
    global _compiled, _one_signal
    if _compiled is None:
        nb = _numba()
        if nb is None:
            return None
        _one_signal = nb.njit(cache=True, nogil=True)(_one_signal)
        _compiled = nb.njit(cache=True, nogil=True)(_filtfilt_time_major)
    return _compiled


def sosfiltfilt_batched(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, axis: int,
                        padlen: int) -> np.ndarray | None:
    """``filters.sosfiltfilt`` of float ``x`` along ``axis`` by the compiled kernel, every
    other axis a batch of signals; None when numba is missing (the caller falls back)."""
    kernel = filtfilt_kernel()
    if kernel is None:
        return None
    xt = np.moveaxis(x, axis, 0)
    shape = xt.shape
    flat = np.ascontiguousarray(xt.reshape(shape[0], -1), dtype=np.float64)
    y = kernel(np.ascontiguousarray(sos, dtype=np.float64),
               np.ascontiguousarray(zi, dtype=np.float64), flat, int(padlen))
    return np.moveaxis(y.reshape(shape), 0, axis)


def _cumulative_simpson_rows(y: np.ndarray, dx: float) -> np.ndarray:
    """(n, S) scipy's ``cumulative_simpson(y, dx=dx, axis=0, initial=0)`` of ``y`` (n >= 3,
    S signals side by side), written out: the first of each pair of intervals by Simpson's
    h1 formula, the second (and the last) by h2, summed one after the other."""
    n, S = y.shape
    out = np.empty((n, S))
    acc = np.zeros(S)
    d3 = dx / 3
    for j in range(S):
        out[0, j] = 0.0
    for i in range(n - 1):
        h1 = i % 2 == 0 and i < n - 2
        for j in range(S):
            if h1:  # h1 over [i, i + 1] from y[i], y[i+1], y[i+2]
                sub = d3 * (5 * y[i, j] / 4 + 2 * y[i + 1, j] - y[i + 2, j] / 4)
            else:  # h2 over [i, i + 1] from y[i+1], y[i], y[i-1]
                sub = d3 * (5 * y[i + 1, j] / 4 + 2 * y[i, j] - y[i - 1, j] / 4)
            acc[j] = acc[j] + sub if i > 0 else sub
            out[i + 1, j] = acc[j] + 0.0  # scipy adds the initial 0 to the running sum
    return out


def cumulative_simpson_batched(x: np.ndarray, dx: float) -> np.ndarray | None:
    """scipy's ``cumulative_simpson(x, dx=dx, axis=0, initial=0.0)`` of float ``x`` (at
    least 3 samples along axis 0) by the compiled loop, bit for bit; None without numba.
    Why: the chain integrates every simulated acceleration twice for a displacement metric
    (Approach III over 100 candidates), and scipy's version builds five temporaries."""
    global _simpson
    if _simpson is None:
        nb = _numba()
        if nb is None:
            return None
        _simpson = nb.njit(cache=True, nogil=True)(_cumulative_simpson_rows)
    flat = np.ascontiguousarray(x.reshape(x.shape[0], -1), dtype=np.float64)
    return _simpson(flat, float(dx)).reshape(x.shape)
