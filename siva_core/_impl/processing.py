"""Processing chain: from a Recording to full states (q, v, a, F) per DOF.

The paper's chain (Sec. 2.2, 3.2): zero-phase Butterworth band-pass of measured
accelerations, integration to velocity then displacement with a zero-phase high-pass
after each integration, decimation, and a start just after the impact.  Every step is
configurable and can be switched off.  What a recording gives is used as given; only what
is missing is derived (integration upward from acc, differentiation downward from disp).

The chain biases what it produces (filters remove signal along with noise), so the final
estimate is refined by output error through the *same* chain (see ``refine``): use
:meth:`Processing.filter_like` to pass simulated signals through it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy import signal

from .recording import Recording


@dataclass
class States:
    """Processed states of one record, arrays of shape (T, n_dof)."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    f: np.ndarray
    name: str = "record"
    has_force: bool = False
    start_index: int = 0  # index into the raw recording of the first kept sample
    decimation: int = 1

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class Processing:
    """Settings of the processing chain (``None`` switches a step off).

    bandpass: (low, high) Hz for a zero-phase Butterworth of order ``order`` on measured
        accelerations (the paper: 4-50 Hz, 3rd order).
    highpass: Hz, zero-phase high-pass after each integration (the paper: 3 Hz).
    lowpass_diff: Hz, zero-phase low-pass before differentiating displacement/velocity.
    decimate_to: target sampling rate in Hz (the paper: 256 Hz), zero-phase anti-aliasing.
    start: "impact" keeps the record from just after the force pulse ends (free response,
        the paper's LO-NO choice); "start" keeps it whole; a float is a time in seconds.
    trim: seconds cut at both ends after filtering (filter edge transients).
    """

    bandpass: tuple[float, float] | None = None
    highpass: float | None = None
    lowpass_diff: float | None = None
    decimate_to: float | None = None
    start: str | float = "start"
    trim: float = 0.0
    order: int = 3
    impact_threshold: float = 0.02  # fraction of |F|max below which the pulse has ended

    @classmethod
    def paper(cls, **kw) -> "Processing":
        """The paper's LO-NO chain: band-pass 4-50 Hz, high-pass 3 Hz, 256 Hz, after impact."""
        base = dict(bandpass=(4.0, 50.0), highpass=3.0, decimate_to=256.0, start="impact",
                    trim=0.0)
        base.update(kw)
        return cls(**base)

    @classmethod
    def none(cls) -> "Processing":
        return cls()

    # ------------------------------------------------------------------ filters
    def _sos(self, kind: str, cut, fs: float):
        nyq = fs / 2
        if kind == "band":
            lo, hi = cut
            hi = min(hi, 0.95 * nyq)
            return signal.butter(self.order, [lo, hi], btype="bandpass", fs=fs, output="sos")
        if kind == "high":
            return signal.butter(self.order, cut, btype="highpass", fs=fs, output="sos")
        return signal.butter(self.order, min(cut, 0.95 * nyq), btype="lowpass", fs=fs, output="sos")

    def _filt(self, x: np.ndarray, kind: str, cut, fs: float) -> np.ndarray:
        return signal.sosfiltfilt(self._sos(kind, cut, fs), x, axis=0)

    def filter_acc(self, a: np.ndarray, fs: float) -> np.ndarray:
        """The chain's treatment of a measured acceleration (band-pass when set)."""
        return a if self.bandpass is None else self._filt(a, "band", self.bandpass, fs)

    def integrate(self, x: np.ndarray, fs: float, x0: np.ndarray | None = None) -> np.ndarray:
        """Trapezoidal integral, then the zero-phase high-pass when set."""
        dt = 1.0 / fs
        y = np.concatenate([np.zeros((1,) + x.shape[1:]),
                            np.cumsum(0.5 * (x[1:] + x[:-1]) * dt, axis=0)])
        if x0 is not None:
            y = y + x0
        if self.highpass is not None:
            y = self._filt(y, "high", self.highpass, fs)
        return y

    def differentiate(self, x: np.ndarray, fs: float) -> np.ndarray:
        """Central-difference derivative after the optional zero-phase low-pass."""
        if self.lowpass_diff is not None:
            x = self._filt(x, "low", self.lowpass_diff, fs)
        return np.gradient(x, 1.0 / fs, axis=0)

    # ------------------------------------------------------------------ chain
    def derive(self, rec: Recording, dofs: Sequence[str]) -> tuple[np.ndarray, ...]:
        """Full-rate (q, v, a, F) arrays, each (T, n_dof), before decimation/start."""
        fs = rec.fs
        T = len(rec)
        n = len(dofs)
        q = np.zeros((T, n))
        v = np.zeros((T, n))
        a = np.zeros((T, n))
        for k, d in enumerate(dofs):
            dq, dv, da = rec.get("disp", d), rec.get("vel", d), rec.get("acc", d)
            if da is not None:
                a[:, k] = self.filter_acc(da, fs)
            if dv is not None:
                v[:, k] = dv
            elif da is not None:
                v[:, k] = self.integrate(a[:, k], fs)
            elif dq is not None:
                v[:, k] = self.differentiate(dq, fs)
            if dq is not None:
                q[:, k] = dq
            else:
                q[:, k] = self.integrate(v[:, k], fs)
            if da is None:
                a[:, k] = self.differentiate(v[:, k], fs)
        f = rec.stack("force", dofs, fill=0.0)
        return q, v, a, f

    def start_index(self, rec: Recording, dofs: Sequence[str]) -> int:
        if self.start == "start":
            return 0
        if isinstance(self.start, (int, float)):
            return int(np.searchsorted(rec.time, rec.time[0] + float(self.start)))
        f = rec.stack("force", dofs, fill=0.0)
        mag = np.abs(f).max(axis=1)
        if mag.max() <= 0:
            return 0
        peak = int(np.argmax(mag))
        after = np.flatnonzero(mag[peak:] < self.impact_threshold * mag[peak])
        return peak + (int(after[0]) if after.size else 0)

    def decimation(self, fs: float) -> int:
        if self.decimate_to is None or self.decimate_to >= fs:
            return 1
        return max(1, int(round(fs / self.decimate_to)))

    def apply(self, rec: Recording, dofs: Sequence[str]) -> States:
        """Run the chain on one recording."""
        q, v, a, f = self.derive(rec, dofs)
        fs = rec.fs
        k = self.decimation(fs)
        if k > 1:
            # zero-phase anti-aliasing low-pass at 0.8 x the new Nyquist, then keep every k-th
            cut = 0.8 * fs / k / 2
            q, v, a = (self._filt(x, "low", cut, fs) for x in (q, v, a))
        i0 = self.start_index(rec, dofs)
        i0 += int(round(self.trim * fs))
        i1 = len(rec) - int(round(self.trim * fs))
        sl = slice(i0, i1, k)
        return States(rec.time[sl].copy(), q[sl].copy(), v[sl].copy(), a[sl].copy(),
                      f[sl].copy(), rec.name, rec.has_force(dofs), i0, k)

    def with_(self, **kw) -> "Processing":
        return replace(self, **kw)
