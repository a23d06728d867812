"""The chain's zero-phase filters and their ledgers.

Every filter is a Butterworth (or notch) run forward and backward as second-order
sections.  Designs and their initial conditions are memoised: refine and diagnose run the
same few filters thousands of times on short records.  A *ledger* counts the filters one
signal went through; ``consistent`` processing tops every signal up to the union of all
ledgers (the chain's total filter), so that the equation of motion still holds.
"""
from __future__ import annotations

import functools
from collections import Counter
from typing import Any, Iterable

import numpy as np
from scipy import signal

from .filtfilt_kernel import sosfiltfilt_batched

# A filter in the ledger: ("band", lo, hi) | ("high", fc) | ("low", fc) | ("notch", f0, q)
FilterKey = tuple


@functools.lru_cache(maxsize=512)
def design_sos(kind: str, cut: float | tuple[float, float], fs: float,
               order: int) -> np.ndarray:
    """Second-order sections of one of the chain's filters.  Memoised: designing a
    Butterworth costs more than running it on a short record, and refine/diagnose run the
    same few filters thousands of times.  The returned array is shared: do not modify it
    (scipy's filters only read it, but refuse a read-only buffer)."""
    nyq = fs / 2
    if kind == "band":
        lo, hi = cut
        if lo <= 0:
            sos = signal.butter(order, min(hi, 0.95 * nyq), btype="lowpass", fs=fs,
                                output="sos")
        elif hi >= 0.95 * nyq:
            sos = signal.butter(order, lo, btype="highpass", fs=fs, output="sos")
        else:
            sos = signal.butter(order, [lo, hi], btype="bandpass", fs=fs, output="sos")
    elif kind == "high":
        sos = signal.butter(order, cut, btype="highpass", fs=fs, output="sos")
    elif kind == "notch":
        f0, q = cut
        b, a = signal.iirnotch(f0, q, fs=fs)
        sos = signal.tf2sos(b, a)
    else:
        sos = signal.butter(order, min(cut, 0.95 * nyq), btype="lowpass", fs=fs, output="sos")
    return sos


@functools.lru_cache(maxsize=512)
def sos_zi(kind: str, cut: float | tuple[float, float], fs: float, order: int) -> np.ndarray:
    """``sosfilt_zi`` of a chain filter, memoised (scipy's ``sosfiltfilt`` recomputes it on
    every call: a linear solve per section that cost as much as filtering a short record)."""
    return signal.sosfilt_zi(design_sos(kind, cut, fs, order))


def sosfiltfilt(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, axis: int,
                padlen: int) -> np.ndarray:
    """``scipy.signal.sosfiltfilt(sos, x, axis, padtype="odd", padlen)`` with a precomputed
    ``zi`` (the same operations in the same order: bit-identical results), by the compiled
    kernel of ``filtfilt_kernel`` for float arrays (all signals of a batch in one pass),
    else by scipy's ``sosfilt``."""
    axis = axis % x.ndim
    n = x.shape[axis]
    if n <= padlen:
        raise ValueError(f"The length of the input vector x must be greater than padlen, "
                         f"which is {padlen}.")
    if x.dtype == np.float64 and x.size:
        y = sosfiltfilt_batched(sos, zi, x, axis, padlen)
        if y is not None:
            return y
    return sosfiltfilt_scipy(sos, zi, x, axis, padlen)


def sosfiltfilt_scipy(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, axis: int,
                      padlen: int) -> np.ndarray:
    """``sosfiltfilt`` by scipy's ``sosfilt`` (the fallback, and the reference the compiled
    kernel is tested against)."""
    axis = axis % x.ndim

    def sl(start: int | None = None, stop: int | None = None, step: int | None = None
           ) -> tuple[slice, ...]:
        idx = [slice(None)] * x.ndim
        idx[axis] = slice(start, stop, step)
        return tuple(idx)

    if padlen > 0:  # odd extension, as scipy.signal._arraytools.odd_ext
        left_end, right_end = x[sl(0, 1)], x[sl(-1, None)]
        ext = np.concatenate((2 * left_end - x[sl(padlen, 0, -1)], x,
                              2 * right_end - x[sl(-2, -(padlen + 2), -1)]), axis=axis)
    else:
        ext = x
    shape = [1] * x.ndim
    shape[axis] = 2
    z = zi.reshape([len(sos)] + shape)
    y, _ = signal.sosfilt(sos, ext, axis=axis, zi=z * ext[sl(0, 1)])
    y, _ = signal.sosfilt(sos, y[sl(None, None, -1)], axis=axis, zi=z * y[sl(-1, None)])
    y = y[sl(None, None, -1)]
    if padlen > 0:
        y = y[sl(padlen, -padlen)]
    return y


def zero_phase(x: np.ndarray, kind: str, cut: Any, fs: float, order: int,
               axis: int = 0) -> np.ndarray:
    """Zero-phase (forward-backward) second-order sections; short records still work."""
    key = (kind, tuple(cut) if isinstance(cut, (list, tuple)) else float(cut), float(fs),
           int(order))
    sos = design_sos(*key)
    n = np.shape(x)[axis]
    padlen = min(3 * (2 * len(sos) + 1), max(n - 1, 0))
    return sosfiltfilt(sos, sos_zi(*key), np.asarray(x, dtype=float), axis, padlen)


def apply_key(x: np.ndarray, key: FilterKey, fs: float, order: int, axis: int) -> np.ndarray:
    """Run the filter a ledger entry names."""
    kind = key[0]
    cut = key[1:] if kind in ("band", "notch") else key[1]
    return zero_phase(x, kind, cut, fs, order, axis)


def acc_keys(bandpass: tuple[float, float] | None, notch: Iterable[float], notch_q: float,
             fs: float) -> list[FilterKey]:
    """The filters of a measured acceleration: the band-pass, then the notches below
    Nyquist."""
    keys: list[FilterKey] = []
    if bandpass is not None:
        keys.append(("band", float(bandpass[0]), float(bandpass[1])))
    keys.extend(("notch", float(f0), float(notch_q)) for f0 in notch if 0 < f0 < fs / 2)
    return keys


def union(ledgers: Iterable[Counter]) -> Counter:
    """The total filter: every filter as often as the ledger that has it most."""
    target: Counter = Counter()
    for led in ledgers:
        target |= led
    return target


def top_up(x: np.ndarray, missing: Counter, fs: float, order: int, axis: int) -> np.ndarray:
    """``x`` through the filters its ledger lacks (in a fixed order)."""
    for key in sorted(missing, key=repr):
        for _ in range(missing[key]):
            x = apply_key(x, key, fs, order, axis)
    return x


def dof_ledgers(acc_keys: list[FilterKey], highpass: float | None, lowpass_diff: float | None,
                has_q: bool, has_v: bool, has_a: bool) -> tuple[Counter, Counter, Counter]:
    """(q, v, a) ledgers of one DOF: the filters each of its signals goes through,
    given which of them were measured (the rest is derived)."""
    high = [("high", float(highpass))] if highpass is not None else []
    low = [("low", float(lowpass_diff))] if lowpass_diff is not None else []
    la = lv = lq = Counter()
    if has_a:
        la = Counter(acc_keys)
    if not has_v:
        lv = la + Counter(high) if has_a else Counter(low)
    if not has_q:
        lq = lv + Counter(high)
    if not has_a:
        la = lv + Counter(low)
    return lq, lv, la
