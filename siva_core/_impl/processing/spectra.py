"""What the measured spectra say about a record: significant peaks, stationary lines
(hum, tones) and the noise-limited high-pass, read off Welch PSDs for ``Processing.auto``."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import signal

from ..recording import Recording
from .calculus import TAIL_FRACTION


@dataclass
class SpectrumSummary:
    """What :meth:`Processing.auto` read off the spectra (kept for reports and tests)."""

    peaks_hz: list[float]
    lines_hz: list[float]  # stationary narrow lines (hum, tones): treated as noise
    first_hz: float | None  # lowest significant peak within 20 dB of the strongest
    top_hz: float | None
    resolution_hz: float
    noise_hz: float | None = None  # high-pass at which integrated noise is 3 % of signal


def decays(rec: Recording, dofs: Sequence[str], ratio: float = 0.1) -> bool:
    """The response dies out within the record: tail RMS < ratio x head RMS on every DOF."""
    for d in dofs:
        x = next((rec.get(q, d) for q in ("acc", "vel", "disp") if rec.get(q, d) is not None))
        n = max(1, int(TAIL_FRACTION * len(x)))
        head, tail = np.sqrt(np.mean(x[:n] ** 2)), np.sqrt(np.mean(x[-n:] ** 2))
        if not tail < ratio * head:
            return False
    return True


def analyse_spectra(recs: Sequence[Recording], dofs: Sequence[str], starts: Sequence[int],
                    noise_tol: float = 0.03) -> SpectrumSummary:
    """Significant peaks, stationary lines and the noise-limited high-pass (see
    ``Processing.auto``); ``starts``: per record, the first sample analysed."""
    peaks: list[float] = []
    lines: list[float] = []
    top: float | None = None
    first: float | None = None
    noise_hz: float | None = None
    resolution = 0.0
    for rec, i0 in zip(recs, starts):
        fs = rec.fs
        for d in dofs:
            measured = [(qty, rec.get(qty, d)) for qty in ("acc", "vel", "disp")
                        if rec.get(qty, d) is not None]
            if not measured:
                continue
            qty, x = measured[0]
            x = np.asarray(x[i0:], float)
            n = len(x)
            if n < 32:
                continue
            nper = int(min(n, 2 ** math.ceil(math.log2(max(64.0, 4.0 * fs)))))
            freq, P = signal.welch(x, fs=fs, nperseg=nper, detrend="linear")
            df = float(freq[1] - freq[0])
            resolution = max(resolution, df)
            # noise floor: median PSD, or that of the upper half of the band when lower
            # (a broadband but noise-free response would otherwise pass for noise)
            floor = float(min(np.median(P[1:]), np.median(P[len(P) // 2:])))
            # 20 dB above the floor, and (noise-free data) within 60 dB of the strongest line
            # in acceleration terms: what the equation of motion sees
            p_int = {"acc": 2, "vel": 1, "disp": 0}[qty]
            to_acc = (2 * np.pi * np.maximum(freq, df)) ** (2 * (2 - p_int))
            thr = np.maximum(100.0 * floor, 1e-6 * float((P * to_acc).max()) / to_acc)
            rec_lines = stationary_lines(x, fs, nper, freq, P, thr)
            fmin = max(4 * df, 2.0 / (n / fs))  # below: the record's own mean/trend
            mask = freq >= fmin
            for f0 in rec_lines:
                mask &= np.abs(freq - f0) > 2.5 * df
            logp = np.log10(np.maximum(P, 1e-300))
            pk, _ = signal.find_peaks(np.where(mask & (P > thr), logp, logp.min()),
                                      prominence=0.6)
            peaks.extend(float(freq[p]) for p in pk)
            # the lowest peak that carries the response (within 20 dB of the strongest)
            strong = [float(freq[p]) for p in pk if P[p] >= 1e-2 * P[pk].max()]
            if strong:
                first = min(first or np.inf, strong[0])
            above = np.flatnonzero(mask & (P > thr))
            if above.size:
                top = max(top or 0.0, float(freq[above[-1]]))
            lines.extend(rec_lines)
            # p_int integrations turn this quantity into a displacement
            if p_int and strong:
                band = mask & (freq >= 0.5 * strong[0])
                w = (2 * np.pi * freq[band]) ** (2 * p_int)
                S = float(np.sum(np.maximum(P[band] - floor, 0.0) / w) * df)
                if S > 0 and floor > 0:
                    e = 2 * p_int - 1
                    fc = (floor / (e * (2 * np.pi) ** (2 * p_int) * noise_tol ** 2 * S)) ** (1 / e)
                    noise_hz = max(noise_hz or 0.0, float(fc))
    lines_merged: list[float] = []
    for f0 in sorted(lines):
        if not lines_merged or f0 - lines_merged[-1] > 2 * resolution:
            lines_merged.append(f0)
    peaks = sorted(set(peaks))
    return SpectrumSummary(peaks, lines_merged, first, top, resolution, noise_hz)


#: mains frequencies [Hz]: a stationary line is hum only at one of their harmonics
MAINS_HZ = (50.0, 60.0)


def _at_mains(f0: float, df: float) -> bool:
    """``f0`` within a bin (or 0.5 %) of a harmonic of 50 or 60 Hz."""
    for mains in MAINS_HZ:
        h = round(f0 / mains)
        if h >= 1 and abs(f0 - h * mains) <= max(1.5 * df, 0.005 * f0):
            return True
    return False


def stationary_lines(x: np.ndarray, fs: float, nper: int, freq: np.ndarray,
                     P: np.ndarray, thr: np.ndarray) -> list[float]:
    """Narrow peaks at a mains harmonic that do not decay while the record does: hum.

    Only mains harmonics: a lightly damped mode also keeps its level over a short
    decaying record (issue 16's null 19000: a 9.03 Hz mode with 0.2 % damping in 2.2 s
    passed the level test and got a notch, and the nominal fit of the notched records
    failed at a validation gap of 1.3).  A notch on a mode ruins the fit; a tone missed
    at another frequency only adds noise."""
    n = len(x)
    third = n // 3
    pk, _ = signal.find_peaks(np.where(P > thr, P, 0.0))
    if not pk.size:
        return []
    df = freq[1] - freq[0]
    # narrow: the level 2 bins away has dropped by 10 dB or more
    narrow = [p for p in pk if 2 <= p < len(P) - 2 and max(P[p - 2], P[p + 2]) < 0.1 * P[p]
              and _at_mains(float(freq[p]), df)]
    if not narrow:
        return []
    decaying = third >= 32 and np.std(x[-third:]) < 0.1 * np.std(x[:third])
    if not decaying:
        return [float(freq[p]) for p in narrow]
    seg = int(min(third, nper))
    f1, P1 = signal.welch(x[:third], fs=fs, nperseg=seg, detrend="linear")
    f3, P3 = signal.welch(x[-third:], fs=fs, nperseg=seg, detrend="linear")
    out: list[float] = []
    for p in narrow:
        k = int(np.argmin(np.abs(f1 - freq[p])))
        lo, hi = max(k - 1, 0), k + 2
        a, b = float(P1[lo:hi].max()), float(P3[lo:hi].max())
        if b > 0 and 0.25 < b / a < 4.0:
            out.append(float(freq[p]))
    return out
