"""Frequency views of a response, as the paper's figures show them (Figs. 2, 4, 7, 9-11).

* :func:`fourier_amplitude` - the single-sided Fourier amplitude spectrum (a sine of
  amplitude A gives a peak of height ~A at its frequency), so measured and simulated
  records of different lengths are comparable.
* :func:`cwt` - the continuous wavelet transform with a complex Morlet wavelet
  (pywavelets), returned as a magnitude normalised so its maximum is 1, the paper's
  convention ("normalized such that the maximum amplitude is 1").  A time-frequency view
  shows what a spectrum hides in a nonlinear decay: the frequency moving with amplitude.
* :func:`frequency_band` - a frequency range that holds the signal's energy, so the
  figures are not mostly empty up to Nyquist (the Duffing at 10 kHz lives below ~300 Hz).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

#: complex Morlet wavelet: bandwidth 1.5, centre frequency 1.0 (time/frequency balance
#: suited to decaying vibration records; a larger bandwidth sharpens frequency)
WAVELET = "cmor1.5-1.0"


def fourier_amplitude(x: np.ndarray, fs: float, *, detrend: bool = True
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum of ``x`` (1-D, or (T, ...) along axis 0).

    Returns (frequencies in Hz, amplitudes in the units of ``x``): 2 |X_k| / T, DC and
    Nyquist bins not doubled.  The mean is removed first when ``detrend`` (an offset
    would otherwise dominate a log-scaled plot).
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] < 2:
        raise ValueError("fourier_amplitude needs at least 2 samples")
    if not fs > 0:
        raise ValueError(f"sampling rate must be positive, got {fs}")
    if detrend:
        x = x - x.mean(axis=0)
    T = x.shape[0]
    X = np.fft.rfft(x, axis=0)
    amp = np.abs(X) / T
    amp[1:] *= 2.0
    if T % 2 == 0:
        amp[-1] /= 2.0  # the Nyquist bin has no mirror image
    return np.fft.rfftfreq(T, 1.0 / fs), amp


def frequency_band(x: np.ndarray, fs: float, *, energy: float = 0.995, margin: float = 1.5,
                   fmin_fraction: float = 0.1, include: Sequence[float] = ()) -> tuple[float, float]:
    """(fmin, fmax) in Hz covering ``energy`` of the spectral energy of ``x`` (any shape,
    time on axis 0), widened by ``margin`` and capped at Nyquist.  fmin is a fraction of the
    dominant frequency, floored at two cycles over the record (lower is not resolvable).

    ``include``: frequencies that must be inside the band (e.g. the model's natural
    frequencies): a displacement's energy sits in its lowest mode, so an energy criterion
    alone cuts a weak higher mode off the axis (the 37 N LO-NO record's 19.8 Hz mode)."""
    f, amp = fourier_amplitude(np.asarray(x, dtype=float).reshape(len(x), -1), fs)
    p = (amp ** 2).sum(axis=1)
    nyq = fs / 2.0
    lowest = 2.0 * fs / len(x)
    if not np.any(p[1:] > 0):
        return lowest, nyq
    c = np.cumsum(p[1:]) / p[1:].sum()
    f_hi = float(f[1:][min(int(np.searchsorted(c, energy)), len(c) - 1)])
    fmax = min(nyq, max(margin * f_hi, 4 * lowest))
    extra = [float(f) for f in include if f is not None and np.isfinite(f) and f > 0]
    if extra:
        fmax = min(nyq, max(fmax, 1.25 * max(extra)))
    f_peak = float(f[1:][int(np.argmax(p[1:]))])
    fmin = max(lowest, fmin_fraction * f_peak)
    if fmin >= fmax:
        fmin = lowest
    return fmin, fmax


def cwt(x: np.ndarray, fs: float, freqs: np.ndarray | None = None, *, n_freqs: int = 96,
        fmin: float | None = None, fmax: float | None = None, wavelet: str = WAVELET,
        normalise: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Continuous wavelet transform magnitude of a 1-D signal with a complex Morlet.

    Returns (frequencies in Hz, increasing; |W| of shape (n_freqs, T)), scaled so the
    maximum is 1 when ``normalise``.  Frequencies default to ``n_freqs`` log-spaced values
    over :func:`frequency_band`.  The FFT method keeps long records (10 kHz x 1 s) fast.
    """
    import pywt

    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"cwt expects a 1-D signal, got shape {x.shape}")
    if len(x) < 4:
        raise ValueError("cwt needs at least 4 samples")
    if freqs is None:
        lo, hi = frequency_band(x, fs)
        lo = fmin if fmin is not None else lo
        hi = fmax if fmax is not None else hi
        freqs = np.geomspace(lo, hi, n_freqs)
    freqs = np.sort(np.asarray(freqs, dtype=float))
    if np.any(freqs <= 0) or freqs[-1] > fs / 2 * (1 + 1e-9):
        raise ValueError(f"cwt frequencies must lie in (0, {fs / 2:g}] Hz")
    w = pywt.ContinuousWavelet(wavelet)
    scales = pywt.central_frequency(w) * fs / freqs
    coef, _ = pywt.cwt(x - x.mean(), scales, w, sampling_period=1.0 / fs, method="fft")
    mag = np.abs(coef)
    if normalise:
        peak = float(mag.max())
        if peak > 0:
            mag = mag / peak
    return freqs, mag


def dominant_frequency(x: np.ndarray, fs: float) -> float:
    """Frequency (Hz) of the largest Fourier amplitude of a 1-D signal: Hann window (less
    leakage), then parabolic interpolation of the log-amplitude around the peak bin, which
    is near exact for a Hann-windowed sine (sub-bin accuracy)."""
    x = np.asarray(x, dtype=float)
    x = (x - x.mean()) * np.hanning(len(x))
    f, amp = fourier_amplitude(x, fs, detrend=False)
    k = int(np.argmax(amp[1:])) + 1
    if 1 <= k < len(amp) - 1 and np.all(amp[k - 1:k + 2] > 0):
        a, b, c = np.log(amp[k - 1:k + 2])
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return float(f[k] + shift * (f[1] - f[0]))
    return float(f[k])


__all__ = ["fourier_amplitude", "frequency_band", "cwt", "dominant_frequency", "WAVELET"]
