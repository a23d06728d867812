"""Processing chain: from a Recording to full states (q, v, a, F) per DOF.

The paper's chain (Sec. 2.2, 3.2): zero-phase Butterworth band-pass of measured
accelerations, integration to velocity then displacement with a zero-phase high-pass
after each integration, decimation, and a start just after the impact.  Every step is
configurable and can be switched off.  What a recording gives is used as given; only what
is missing is derived (integration upward from acc, differentiation downward from disp).

The chain biases what it produces (filters remove signal along with noise, and the
paper's chain filters q, v, a and F differently, so M a = -f(q, v) + F no longer holds
even for a linear model).  Two remedies live here:

* ``consistent=True`` passes every signal (q, v, a of every DOF and the force) through the
  same total filter, so the equation of motion still holds exactly for the linear terms.
* :meth:`Processing.apply_simulated` / :func:`simulated_recording` pass a *simulated*
  response through exactly the same chain as a measured one, for output-error refinement.

:meth:`Processing.auto` picks a chain from the data (the rule is in its docstring and in
``docs/formats.md``); :meth:`Processing.paper` is the paper's chain, kept for comparison.
"""
from __future__ import annotations

import functools
import math
import warnings
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any, Callable, ClassVar, Iterable, Sequence

import numpy as np
from scipy import integrate, signal

from .chain_cache import memoised, record_digest
from .impulse import detect_impulse
from .recording import Recording

# A filter in the ledger: ("band", lo, hi) | ("high", fc) | ("low", fc) | ("notch", f0, q)
FilterKey = tuple


@dataclass
class States:
    """Processed states of one record, arrays of shape (T, n_dof).

    Arrays may carry extra leading axes (e.g. (B, T, n_dof) for a batch of simulations
    processed by :meth:`Processing.apply_simulated`); ``t`` is always (T,).
    """

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

    @property
    def fs(self) -> float:
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class SpectrumSummary:
    """What :meth:`Processing.auto` read off the spectra (kept for reports and tests)."""

    peaks_hz: list[float]
    lines_hz: list[float]  # stationary narrow lines (hum, tones): treated as noise
    first_hz: float | None  # lowest significant peak within 20 dB of the strongest
    top_hz: float | None
    resolution_hz: float
    noise_hz: float | None = None  # high-pass at which integrated noise is 3 % of signal


@dataclass
class Processing:
    """Settings of the processing chain (``None`` switches a step off).

    bandpass: (low, high) Hz for a zero-phase Butterworth of order ``order`` on measured
        accelerations (the paper: 4-50 Hz, 3rd order).
    highpass: Hz, zero-phase high-pass after each integration (the paper: 3 Hz).
    lowpass_diff: Hz, zero-phase low-pass before differentiating displacement/velocity.
    notch: frequencies [Hz] of stationary lines (mains hum) removed from measured signals
        by zero-phase notches of quality ``notch_q``.
    decimate_to: target sampling rate in Hz (the paper: 256 Hz), zero-phase anti-aliasing.
    start: "impact" keeps the record from just after the force pulse ends (free response,
        the paper's LO-NO choice); "start" keeps it whole; a float is a time in seconds.
    trim: seconds cut at both ends of the record after filtering (filter edge transients);
        a start after the impact that is later than ``trim`` is kept as it is.
    gate_force: zero the force outside its pulse(s) (|F| above ``impact_threshold`` of its
        peak, widened by ``gate_margin`` s): between hits a hammer applies no force, the
        channel only carries noise that would enter the equation of motion.  With
        ``start="impact"`` and no ``consistent``, the kept force is then exactly zero (the
        paper's F = 0 in training).
    consistent: give every signal, force included, the same total filter (each one is
        topped up with the filters the others received), so that the equation of motion
        holds for linear terms after processing.
    diff_accuracy: order of the central-difference stencil (2, 4 or 6); high orders keep
        the derivative's gain error small up to a good fraction of Nyquist.
    integrator: "trapezoid" (the paper's cumtrapz) or "simpson" (cumulative Simpson: about
        3x smaller error across a sharp impact pulse, whose error becomes velocity drift).
    drift: how integration constants are handled.  "highpass": the integral starts at 0
        and the high-pass (if set) removes the drift (the paper).  "tail": for a free
        decay that dies out within the record, the constant is chosen so that the integral
        has zero mean over the last ``TAIL_FRACTION`` of the record (where the structure is
        back at rest): this recovers an unknown initial velocity/displacement exactly,
        where a high-pass would remove it together with the response's slow content.
    pad: seconds of zeros added before and after the record for the derivation (the
        structure at rest).  Zero-phase filters ring *before* an impact as well as after;
        without room before the record's first sample that part is lost from the integral,
        and the filters no longer commute with integration (``consistent`` then fails).
        Only right when the record starts and ends at rest (impact tests).
    """

    bandpass: tuple[float, float] | None = None
    highpass: float | None = None
    lowpass_diff: float | None = None
    decimate_to: float | None = None
    start: str | float = "start"
    trim: float = 0.0
    order: int = 3
    impact_threshold: float = 0.02  # fraction of |F|max below which the pulse has ended
    notch: tuple[float, ...] = ()
    notch_q: float = 30.0
    gate_force: bool = False
    consistent: bool = False
    diff_accuracy: int = 6
    integrator: str = "trapezoid"
    pad: float = 0.0
    gate_margin: float = 0.0
    drift: str = "highpass"
    # what auto() read off the spectra: an attribute, not a setting (not in asdict/eq)
    summary: ClassVar[SpectrumSummary | None] = None

    # ------------------------------------------------------------------ presets
    @classmethod
    def paper(cls, **kw: Any) -> "Processing":
        """The paper's LO-NO chain: band-pass 4-50 Hz, high-pass 3 Hz, 256 Hz, after impact.

        The force is gated to its pulse, so training sees F = 0 after the impact as in the
        paper; nothing makes the filters consistent (that is the paper's bias).
        """
        base: dict[str, Any] = dict(bandpass=(4.0, 50.0), highpass=3.0, decimate_to=256.0,
                                    start="impact", trim=0.0, gate_force=True)
        base.update(kw)
        return cls(**base)

    @classmethod
    def none(cls) -> "Processing":
        return cls()

    @classmethod
    def auto(cls, recordings: Recording | Iterable[Recording], dofs: Sequence[str],
             cover: tuple[float, float] | None = None, **overrides: Any) -> "Processing":
        """A chain chosen from the data, for records never seen before.

        Rule (also in docs/formats.md):

        1. Every record gives disp, vel and acc for every DOF: nothing is done (the states
           are used as given, whole record, force as measured).
        2. Otherwise the measured spectra set the band.  For each DOF the most derivative
           quantity measured (acc, else vel, else disp) is analysed over the free response
           (after the force pulse when the force is impulsive): Welch PSD with ~0.25 Hz
           resolution (coarser for short records), noise floor N = median PSD (that of the
           upper half of the band when lower).
           *Stationary lines* (narrow peaks whose level stays within a factor 4 between the
           first and last third of a decaying record: mains hum, tones; in records that do
           not decay, narrow peaks at multiples of 50/60 Hz) are noise.  Every other local
           maximum 20 dB above N (and 6 dB above its surroundings) is a *significant peak*.
           - high-pass ``fh``: as low as the noise allows, within [f1/6, f1/2] where f1 is
             the lowest significant peak within 20 dB of the strongest one.  Integrating p
             times turns the white floor N into N/(2 pi f)^(2p); ``fh`` is where that
             integrated noise reaches 3 % of the RMS of the integrated signal:
             fh = (N / ((2p-1) (2 pi)^(2p) 0.03^2 S))^(1/(2p-1)),
             S = sum of (P - N)/(2 pi f)^(2p) df.  Lower is not better: a high-pass also
             removes the response's own slow content, which the nonlinear terms feel, and
             below 4 / record duration its transients at the record ends (it is zero-phase,
             so non-causal) spoil the double integral.
           - low-pass ``fl`` = 2 x the highest frequency still 20 dB above N and within
             60 dB of the strongest line in acceleration terms (harmonics included), at
             most 0.8 x Nyquist.
           - stationary lines in (fh, fl) get zero-phase notches (Q = 30) rather than a
             low-pass below them, which would cut the nonlinear harmonics above the hum.
           acc-only DOFs: band-pass (fh, fl), integrate twice (Simpson) with high-pass fh.
           Exception, a clean free decay (no force, the most derivative signal's RMS over
           the last 20 % below 0.1 x that over the first 20 %, and integrated noise
           negligible: fh from noise < 4 / duration): low-pass fl only and ``drift="tail"``
           (integration constants from the record's decayed tail), which keeps an unknown
           initial velocity that a high-pass would remove.
           disp-only DOFs: low-pass fl then 6th-order central differences.
        3. All signals, force included, get the same total filter (``consistent``), and an
           impulsive force (above 2 % of its peak for < 10 % of the record) is gated to
           its pulse; the record then starts just after the impact.
        4. Decimation by the largest integer factor keeping fs >= 4 fl (none below 2), and
           min(4 / fl, 2 % of the record) trimmed at both ends (filter edge transients).

        ``cover`` = (lowest, highest) frequency [Hz] the band must keep, e.g. the linear
        modes of a model fitted in a first pass: the spectral peaks of strongly damped
        higher modes, or of a mode next to a mains line, can be missed, and a band that
        cuts a mode of the structure leaves its parameters unidentified (issue 16:
        modes at 49.5 and 82.7 Hz cut by a 48.8 Hz low-pass, nominal train cost 0.28
        against 0.057 with them).  ``first`` becomes min(first, lowest) and ``top``
        max(top, highest).
        ``overrides`` replace any chosen setting.  The analysis is kept in ``summary``.
        """
        recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
        if not recs:
            raise ValueError("Processing.auto needs at least one recording")
        dofs = list(dofs)
        if all(rec.get(qty, d) is not None for rec in recs for d in dofs
               for qty in ("disp", "vel", "acc")):
            return cls(**overrides)
        needs_int = needs_diff = has_acc = False
        for rec in recs:
            for d in dofs:
                dq, dv, da = (rec.get(x, d) for x in ("disp", "vel", "acc"))
                if dq is None or (dv is None and da is not None):
                    needs_int = True
                if da is None:
                    needs_diff = True
                has_acc = has_acc or da is not None
        any_force = any(rec.has_force(dofs) for rec in recs)
        impulsive = any_force and all(detect_impulse(rec.stack("force", dofs, fill=0.0))
                                      is not None for rec in recs if rec.has_force(dofs))
        probe = cls(start="impact" if impulsive else "start")
        summary = _analyse_spectra(recs, dofs, probe)
        fs_min = min(rec.fs for rec in recs)
        nyq = fs_min / 2
        duration = min(float(rec.time[-1] - rec.time[0]) for rec in recs)
        if summary.first_hz is None:
            warnings.warn("Processing.auto: no significant spectral peak found; "
                          "using a wide band", stacklevel=2)
            first, top = 40.0 / max(duration, 1e-9), 0.4 * nyq
        else:
            first, top = summary.first_hz, summary.top_hz or summary.first_hz
        if cover is not None:
            first = min(first, float(cover[0])) if cover[0] > 0 else first
            top = max(top, float(cover[1]))
        fh = min(max(summary.noise_hz or 0.0, first / 6.0, 4.0 / duration), first / 2.0)
        if fh > first / 2:
            warnings.warn(f"Processing.auto: record too short ({duration:.3g} s) for a "
                          f"high-pass well below the lowest peak ({first:.3g} Hz)",
                          stacklevel=2)
        fl = min(2.0 * max(top, first), 0.8 * nyq)
        lines = tuple(x for x in summary.lines_hz if fh < x < fl)
        k = int(fs_min // (4.0 * fl)) if fl > 0 else 1
        fh, fl = float(fh), float(fl)
        settings: dict[str, Any] = dict(
            bandpass=(fh, fl) if has_acc else None,
            highpass=fh if needs_int else None,
            lowpass_diff=fl if needs_diff else None,
            notch=tuple(float(x) for x in lines),
            decimate_to=float(fs_min / k) if k >= 2 else None,
            start=probe.start,
            gate_force=impulsive,
            consistent=True,
            integrator="simpson",
            order=4,
            # the low-pass rings for a few of its periods at the record's ends
            trim=float(min(4.0 / fl, 0.02 * duration)) if fl > 0 else 0.0,
        )
        if (needs_int and not any_force and summary.noise_hz is not None
                and summary.noise_hz < 4.0 / duration and all(_decays(r, dofs) for r in recs)):
            # a clean free decay: integration constants from the decayed tail, no high-pass
            settings.update(bandpass=(0.0, fl) if has_acc else None, highpass=None,
                            drift="tail")
        settings.update(overrides)
        out = cls(**settings)
        out.summary = summary
        return out

    # ------------------------------------------------------------------ filters
    def _filt(self, x: np.ndarray, kind: str, cut: Any, fs: float, axis: int = 0) -> np.ndarray:
        """Zero-phase (forward-backward) second-order sections; short records still work."""
        key = (kind, tuple(cut) if isinstance(cut, (list, tuple)) else float(cut), float(fs),
               int(self.order))
        sos = _design_sos(*key)
        n = np.shape(x)[axis]
        padlen = min(3 * (2 * len(sos) + 1), max(n - 1, 0))
        return _sosfiltfilt(sos, _sos_zi(*key), np.asarray(x, dtype=float), axis, padlen)

    def _apply_key(self, x: np.ndarray, key: FilterKey, fs: float, axis: int) -> np.ndarray:
        kind = key[0]
        cut = key[1:] if kind in ("band", "notch") else key[1]
        return self._filt(x, kind, cut, fs, axis)

    def _acc_keys(self, fs: float) -> list[FilterKey]:
        keys: list[FilterKey] = []
        if self.bandpass is not None:
            keys.append(("band", float(self.bandpass[0]), float(self.bandpass[1])))
        keys.extend(("notch", float(f0), float(self.notch_q)) for f0 in self.notch
                    if 0 < f0 < fs / 2)
        return keys

    def filter_acc(self, a: np.ndarray, fs: float, axis: int = 0) -> np.ndarray:
        """The chain's treatment of a measured acceleration (band-pass and notches)."""
        for key in self._acc_keys(fs):
            a = self._apply_key(a, key, fs, axis)
        return a

    def integrate(self, x: np.ndarray, fs: float, x0: np.ndarray | None = None,
                  axis: int = 0) -> np.ndarray:
        """Cumulative integral from 0 (``integrator``), then the zero-phase high-pass."""
        x = np.moveaxis(np.asarray(x, dtype=float), axis, 0)
        dt = 1.0 / fs
        if self.integrator == "simpson" and x.shape[0] >= 3:
            y = integrate.cumulative_simpson(x, dx=dt, axis=0, initial=0.0)
        elif self.integrator in ("trapezoid", "simpson"):
            y = np.concatenate([np.zeros((1,) + x.shape[1:]),
                                np.cumsum(0.5 * (x[1:] + x[:-1]) * dt, axis=0)])
        else:
            raise ValueError(f"integrator must be 'trapezoid' or 'simpson', "
                             f"got {self.integrator!r}")
        if x0 is not None:
            y = y + x0
        if self.highpass is not None:
            y = self._filt(y, "high", self.highpass, fs)
        if self.drift == "tail":
            n_tail = max(1, int(TAIL_FRACTION * y.shape[0]))
            y = y - y[-n_tail:].mean(axis=0)
        elif self.drift != "highpass":
            raise ValueError(f"drift must be 'highpass' or 'tail', got {self.drift!r}")
        return np.moveaxis(y, 0, axis)

    def differentiate(self, x: np.ndarray, fs: float, axis: int = 0) -> np.ndarray:
        """Central-difference derivative (``diff_accuracy``) after the optional low-pass."""
        if self.lowpass_diff is not None:
            x = self._filt(x, "low", self.lowpass_diff, fs, axis)
        return central_difference(x, 1.0 / fs, axis=axis, accuracy=self.diff_accuracy)

    # ------------------------------------------------------------------ chain
    def _derive_arrays(self, fs: float, dofs: Sequence[str],
                       given: Callable[[str, str], np.ndarray | None],
                       force: np.ndarray | None, need: str = "qva") -> tuple[Any, ...]:
        """Core: per DOF derive what is missing; arrays have time on the last axis.

        Every derived signal records the filters it went through (its ledger); with
        ``consistent`` each signal is then topped up to the union of all ledgers.
        ``need``: which of q, v, a are wanted ("qva" = all).  The ledgers are worked out
        symbolically for every signal (they set the consistent total filter), but only
        the wanted signals and what they derive from are computed (an output-error
        residual on accelerations needs no integration); the others are returned as
        zero-strided NaN arrays.  Wanted signals are computed by exactly the same
        operations as with ``need="qva"`` (bit-identical).  ``force=None``: the force is
        not processed (returned as None; ``apply_simulated`` takes it from the memo).
        """
        npad = int(round(self.pad * fs))
        if self.drift == "tail":
            need = "qva"  # the tail constants couple v and q

        def padded(x: np.ndarray, axis: int) -> np.ndarray:
            """The structure at rest before and after the record: zeros, on every signal."""
            if npad <= 0:
                return x
            width = [(0, 0)] * x.ndim
            width[axis] = (npad, npad)
            return np.pad(x, width)

        def source(qty: str, d: str) -> np.ndarray | None:
            x = given(qty, d)
            return None if x is None else padded(np.asarray(x, float), -1)

        qs: list[np.ndarray | None] = []
        vs: list[np.ndarray | None] = []
        as_: list[np.ndarray | None] = []
        ledgers: list[Counter] = []
        for d in dofs:
            dq, dv, da = source("disp", d), source("vel", d), source("acc", d)
            if dq is None and dv is None and da is None:
                raise ValueError(f"DOF {d!r} has no disp, vel or acc")
            lq, lv, la = self._dof_ledgers(fs, dq is not None, dv is not None, da is not None)
            # what must be computed: the wanted signals and their sources
            want_q = "q" in need
            want_a = "a" in need
            want_v = ("v" in need or (want_q and dq is None)
                      or (want_a and da is None))
            need_fa = want_a or (want_v and dv is None and da is not None)
            a = v = q = None
            if da is not None and need_fa:
                a = self.filter_acc(np.asarray(da, float), fs, axis=-1)
            if want_v:
                if dv is not None:
                    v = np.asarray(dv, float)
                elif da is not None:
                    v = self.integrate(a, fs, axis=-1)
                else:
                    v = self.differentiate(np.asarray(dq, float), fs, axis=-1)
            if want_q:
                if dq is not None:
                    q = np.asarray(dq, float)
                else:
                    q = self.integrate(v, fs, axis=-1)
                    if self.drift == "tail" and dv is None and da is not None:
                        v, q = _joint_tail_constants(v, q, fs)
            if a is None and want_a:
                a = self.differentiate(v, fs, axis=-1)
            qs.append(q if want_q else None)
            vs.append(v if "v" in need else None)
            as_.append(a if want_a else None)
            ledgers.extend([lq, lv, la])
        if self.consistent:
            target = _union(ledgers)
            for k in range(len(dofs)):
                for lst, led in ((qs, ledgers[3 * k]), (vs, ledgers[3 * k + 1]),
                                 (as_, ledgers[3 * k + 2])):
                    if lst[k] is not None:
                        lst[k] = self._top_up(lst[k], target - led, fs, -1)
        f = None if force is None else self._force_full_rate(force, fs, _union(ledgers))
        computed = [x for x in qs + vs + as_ if x is not None]
        shape = np.broadcast_shapes(*(x.shape for x in computed))
        nan = np.broadcast_to(np.float64(np.nan), shape)
        q, v, a = (np.stack([np.broadcast_to(x, shape) if x is not None else nan
                             for x in lst], axis=-1)
                   if any(x is not None for x in lst)
                   else np.broadcast_to(np.float64(np.nan), shape + (len(dofs),))
                   for lst in (qs, vs, as_))
        if npad > 0:
            keep = slice(npad, q.shape[-2] - npad)
            q, v, a = q[..., keep, :], v[..., keep, :], a[..., keep, :]
        return q, v, a, f

    def _dof_ledgers(self, fs: float, has_q: bool, has_v: bool, has_a: bool
                     ) -> tuple[Counter, Counter, Counter]:
        """(q, v, a) ledgers of one DOF: the filters each of its signals goes through,
        given which of them were measured (the rest is derived)."""
        high = [("high", float(self.highpass))] if self.highpass is not None else []
        low = [("low", float(self.lowpass_diff))] if self.lowpass_diff is not None else []
        la = lv = lq = Counter()
        if has_a:
            la = Counter(self._acc_keys(fs))
        if not has_v:
            lv = la + Counter(high) if has_a else Counter(low)
        if not has_q:
            lq = lv + Counter(high)
        if not has_a:
            la = lv + Counter(low)
        return lq, lv, la

    def _force_full_rate(self, force: np.ndarray, fs: float, target: Counter) -> np.ndarray:
        """The force through the chain at the record's rate (padded, topped up to the
        total filter ``target`` when ``consistent``, unpadded)."""
        npad = int(round(self.pad * fs))
        f = np.asarray(force, float)
        if npad > 0:
            f = np.pad(f, [(npad, npad)] + [(0, 0)] * (f.ndim - 1))
        if self.consistent:
            f = self._top_up(f, target, fs, 0)
        if npad > 0:
            f = f[npad:f.shape[0] - npad]
        return f

    def _measured_force(self, rec: Recording, dofs: Sequence[str]) -> tuple[np.ndarray, int]:
        """(the kept force samples as ``apply`` returns them, start index) of a measured
        record, memoised: ``apply_simulated`` needs them on every call, and they depend
        on nothing simulated."""
        forces = [k for k in rec.channels if k.startswith("force_")]
        key = ("measured_force", repr(self), tuple(dofs), record_digest(rec, forces))

        def compute() -> tuple[np.ndarray, int]:
            fs = rec.fs
            present = lambda qty, d: rec.get(qty, d) is not None
            ledgers = [led for d in dofs for led in self._dof_ledgers(
                fs, present("disp", d), present("vel", d), present("acc", d))]
            f = self._force_full_rate(self.force(rec, dofs), fs, _union(ledgers))
            f, sl, i0 = self._finish_force(rec, dofs, f)
            return f[sl].copy(), i0

        f, i0 = memoised(key, compute)
        return f.copy(), i0

    def _top_up(self, x: np.ndarray, missing: Counter, fs: float, axis: int) -> np.ndarray:
        for key in sorted(missing, key=repr):
            for _ in range(missing[key]):
                x = self._apply_key(x, key, fs, axis)
        return x

    def force(self, rec: Recording, dofs: Sequence[str]) -> np.ndarray:
        """(T, n_dof) force as the chain uses it, before filtering: the record's force
        columns (0 where a DOF has none), gated to its pulse(s) when ``gate_force``
        (``impact_threshold`` of the peak, widened by ``gate_margin`` s; see ``impulse``).
        The simulator is driven by this force, so that what is simulated is what the chain
        reports."""
        f = rec.stack("force", dofs, fill=0.0)
        if self.gate_force:
            pulse = detect_impulse(f, self.impact_threshold, require_impulsive=False)
            if pulse is not None:
                f = f * pulse.gate(int(round(self.gate_margin * rec.fs)))[:, None]
        return f

    def derive(self, rec: Recording, dofs: Sequence[str]) -> tuple[np.ndarray, ...]:
        """Full-rate (q, v, a, F) arrays, each (T, n_dof), before decimation/start."""
        return self._derive_arrays(rec.fs, dofs, rec.get, self.force(rec, dofs))

    def start_index(self, rec: Recording, dofs: Sequence[str]) -> int:
        """Index of the first kept sample: 0, a time, or just after the force pulse."""
        if self.start == "start":
            return 0
        if isinstance(self.start, (int, float)):
            return int(np.searchsorted(rec.time, rec.time[0] + float(self.start)))
        if self.start != "impact":
            raise ValueError(f"start must be 'start', 'impact' or seconds, got {self.start!r}")
        pulse = detect_impulse(rec.stack("force", dofs, fill=0.0), self.impact_threshold,
                               require_impulsive=False)
        return 0 if pulse is None else pulse.end

    def decimation(self, fs: float) -> int:
        """Integer decimation factor reaching ``decimate_to`` (1 when off or above fs)."""
        if self.decimate_to is None or self.decimate_to >= fs:
            return 1
        return max(1, int(round(fs / self.decimate_to)))

    def _finish(self, rec: Recording, dofs: Sequence[str], q: np.ndarray, v: np.ndarray,
                a: np.ndarray, f: np.ndarray | None, need: str = "qva") -> States:
        """Decimate (zero-phase anti-aliasing) and cut to the kept window (only the
        ``need``ed of q, v, a: the others stay NaN, see ``_derive_arrays``; ``f=None``:
        the measured record's processed force, memoised)."""
        fs = rec.fs
        k = self.decimation(fs)
        if k > 1:
            # zero-phase anti-aliasing low-pass at 0.8 x the new Nyquist, then keep every k-th
            cut = 0.8 * fs / k / 2
            q, v, a = (self._filt(x, "low", cut, fs, axis=-2) if name in need else x
                       for name, x in (("q", q), ("v", v), ("a", a)))
        if f is None:  # apply_simulated: the measured record's, memoised
            f_kept, i0 = self._measured_force(rec, dofs)
            sl = slice(i0, len(rec) - int(round(self.trim * fs)), k)
        else:
            f, sl, i0 = self._finish_force(rec, dofs, f)
            f_kept = f[sl].copy()

        def cut(name: str, x: np.ndarray) -> np.ndarray:
            y = x[..., sl, :]
            return y.copy() if name in need else np.broadcast_to(np.float64(np.nan), y.shape)

        return States(rec.time[sl].copy(), cut("q", q), cut("v", v), cut("a", a), f_kept,
                      rec.name, rec.has_force(dofs), i0, k)

    def _finish_force(self, rec: Recording, dofs: Sequence[str], f: np.ndarray
                      ) -> tuple[np.ndarray, slice, int]:
        """The force decimated like the states (when ``consistent``), the kept window's
        slice and its start index (errors when nothing is left)."""
        fs = rec.fs
        k = self.decimation(fs)
        if k > 1 and self.consistent:
            f = self._filt(f, "low", 0.8 * fs / k / 2, fs, axis=0)
        edge = int(round(self.trim * fs))
        i0 = max(self.start_index(rec, dofs), edge)
        i1 = len(rec) - edge
        if i1 - i0 < 2 * k:
            raise ValueError(f"{rec.name}: nothing left after start/trim "
                             f"(start index {i0}, end {i1})")
        return f, slice(i0, i1, k), i0

    def apply(self, rec: Recording, dofs: Sequence[str]) -> States:
        """Run the chain on one recording (measured or simulated, see simulated_recording).

        Memoised on the record's samples and the chain's settings (``chain_cache``): the
        output-error problems of a fit or a diagnosis process the same measured records
        many times.  Each call returns its own copy."""
        key = ("apply", repr(self), tuple(dofs), record_digest(rec))

        def compute() -> States:
            q, v, a, f = self.derive(rec, dofs)
            return self._finish(rec, dofs, q, v, a, f)

        return _copy_states(memoised(key, compute))

    def apply_simulated(self, measured: Recording, dofs: Sequence[str], q: np.ndarray,
                        v: np.ndarray, a: np.ndarray, need: str = "qva") -> States:
        """Pass simulated states through exactly the chain ``measured`` goes through.

        ``q``, ``v``, ``a``: (..., T, n_dof) on the measured time grid (leading axes, e.g.
        a batch of parameter sets, are kept).  Only the quantities ``measured`` has per DOF
        are taken from the simulation; the force, start index and decimation come from the
        measured record, so the result lines up sample by sample with ``apply(measured)``.
        ``need``: the processed quantities wanted ("qva"; e.g. "a" for a residual on
        accelerations): the others are not derived and come back as NaN.
        """
        sim = {"disp": np.asarray(q, float), "vel": np.asarray(v, float),
               "acc": np.asarray(a, float)}
        T = len(measured)
        for name, x in sim.items():
            if x.shape[-2:] != (T, len(dofs)):
                raise ValueError(f"simulated {name} has shape {x.shape}, expected (..., {T}, "
                                 f"{len(dofs)}) on the measured time grid")
        index = {d: k for k, d in enumerate(dofs)}

        def given(qty: str, d: str) -> np.ndarray | None:
            if measured.get(qty, d) is None:
                return None
            return sim[qty][..., index[d]]

        qq, vv, aa, _ = self._derive_arrays(measured.fs, dofs, given, None, need)
        return self._finish(measured, dofs, qq, vv, aa, None, need)

    def with_(self, **kw: Any) -> "Processing":
        return replace(self, **kw)

    def describe(self) -> str:
        """One line saying what the chain does (for logs and reports)."""
        parts = []
        if self.bandpass:
            parts.append(f"band-pass {self.bandpass[0]:.3g}-{self.bandpass[1]:.3g} Hz")
        if self.notch:
            parts.append("notch " + ", ".join(f"{x:.4g}" for x in self.notch) + " Hz")
        if self.highpass:
            parts.append(f"integrate + high-pass {self.highpass:.3g} Hz")
        if self.lowpass_diff:
            parts.append(f"low-pass {self.lowpass_diff:.3g} Hz + differentiate")
        if self.decimate_to:
            parts.append(f"decimate to {self.decimate_to:.4g} Hz")
        if self.consistent:
            parts.append("consistent filtering")
        if self.gate_force:
            parts.append("force gated to its pulse")
        parts.append(f"from {self.start!r}" if not isinstance(self.start, (int, float))
                     else f"from t = {self.start:g} s")
        return "; ".join(parts) if parts else "none"


@functools.lru_cache(maxsize=512)
def _design_sos(kind: str, cut: float | tuple[float, float], fs: float,
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
def _sos_zi(kind: str, cut: float | tuple[float, float], fs: float, order: int) -> np.ndarray:
    """``sosfilt_zi`` of a chain filter, memoised (scipy's ``sosfiltfilt`` recomputes it on
    every call: a linear solve per section that cost as much as filtering a short record)."""
    return signal.sosfilt_zi(_design_sos(kind, cut, fs, order))


def _sosfiltfilt(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, axis: int,
                 padlen: int) -> np.ndarray:
    """``scipy.signal.sosfiltfilt(sos, x, axis, padtype="odd", padlen)`` with a precomputed
    ``zi`` (the same operations in the same order: bit-identical results)."""
    axis = axis % x.ndim
    n = x.shape[axis]
    if n <= padlen:
        raise ValueError(f"The length of the input vector x must be greater than padlen, "
                         f"which is {padlen}.")

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


def _union(ledgers: Iterable[Counter]) -> Counter:
    """The total filter: every filter as often as the ledger that has it most."""
    target: Counter = Counter()
    for led in ledgers:
        target |= led
    return target


def _copy_states(st: States) -> States:
    """A States whose arrays the caller may modify (the memo's stay as computed)."""
    cp = lambda x: x.copy() if isinstance(x, np.ndarray) else x
    return replace(st, t=cp(st.t), q=cp(st.q), v=cp(st.v), a=cp(st.a), f=cp(st.f))


def simulated_recording(measured: Recording, dofs: Sequence[str] | Any, q: np.ndarray,
                        v: np.ndarray, a: np.ndarray, *, name: str | None = None) -> Recording:
    """A Recording of simulated (T, n_dof) states with the channels ``measured`` has.

    ``dofs``: the DOF names, or anything with a ``dofs`` attribute (a Structure).

    The force channels are copied from ``measured`` (the simulation was driven by them), so
    ``proc.apply(simulated_recording(...))`` gives states processed exactly like
    ``proc.apply(measured)``: same derivations, filters, start and decimation.
    """
    dofs = list(getattr(dofs, "dofs", dofs))
    sim = {"disp": np.asarray(q, float), "vel": np.asarray(v, float),
           "acc": np.asarray(a, float)}
    for key, x in sim.items():
        if x.shape != (len(measured), len(dofs)):
            raise ValueError(f"simulated {key} has shape {x.shape}, expected "
                             f"({len(measured)}, {len(dofs)})")
    channels: dict[str, np.ndarray] = {}
    for key, x in measured.channels.items():
        qty, _, d = key.partition("_")
        if qty == "force":
            channels[key] = x.copy()
        elif qty in sim and d in dofs:
            channels[key] = sim[qty][:, dofs.index(d)].copy()
    return Recording(measured.time.copy(), channels, name or f"{measured.name} (simulated)",
                     {"simulated": True})


def central_difference(x: np.ndarray, dt: float, axis: int = 0,
                       accuracy: int = 6) -> np.ndarray:
    """Derivative by a central stencil of the given order; 2nd-order one-sided at edges."""
    x = np.asarray(x, dtype=float)
    out = np.gradient(x, dt, axis=axis, edge_order=2) if x.shape[axis] > 2 else \
        np.gradient(x, dt, axis=axis)
    stencils = {2: [1 / 2], 4: [2 / 3, -1 / 12], 6: [3 / 4, -3 / 20, 1 / 60]}
    if accuracy not in stencils:
        raise ValueError(f"diff_accuracy must be 2, 4 or 6, got {accuracy}")
    w = stencils[accuracy]
    m = len(w)
    n = x.shape[axis]
    if accuracy == 2 or n <= 2 * m:
        return out
    xm = np.moveaxis(x, axis, 0)
    om = np.moveaxis(out, axis, 0)
    inner = np.zeros_like(xm[m:n - m])
    for j, c in enumerate(w, start=1):
        inner += c * (xm[m + j:n - m + j] - xm[m - j:n - m - j])
    om[m:n - m] = inner / dt
    return np.moveaxis(om, 0, axis)


# ---------------------------------------------------------------------- helpers for auto
TAIL_FRACTION = 0.2


def _joint_tail_constants(v: np.ndarray, q: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement both integrated from acceleration (time on the last axis):
    choose the constants (q0, v0) so that q + q0 + v0 t has zero mean and no trend over the
    decayed tail.  A velocity offset left by a tail mean over partial cycles would otherwise
    become a displacement drift; fitting the drift pins v0 far more precisely."""
    n = q.shape[-1]
    m = max(2, int(TAIL_FRACTION * n))
    t = np.arange(n) / fs
    tt = t[-m:]
    A = np.stack([np.ones(m), tt - tt.mean()], axis=1)
    coef = np.linalg.lstsq(A, -np.moveaxis(q[..., -m:], -1, 0).reshape(m, -1), rcond=None)[0]
    v0 = coef[1].reshape(q.shape[:-1])[..., None]
    q0 = (coef[0] - coef[1] * tt.mean()).reshape(q.shape[:-1])[..., None]
    # v was already shifted by its own tail mean; the fit corrects what remains
    return v + v0, q + q0 + v0 * t


def _decays(rec: Recording, dofs: Sequence[str], ratio: float = 0.1) -> bool:
    """The response dies out within the record: tail RMS < ratio x head RMS on every DOF."""
    for d in dofs:
        x = next((rec.get(q, d) for q in ("acc", "vel", "disp") if rec.get(q, d) is not None))
        n = max(1, int(TAIL_FRACTION * len(x)))
        head, tail = np.sqrt(np.mean(x[:n] ** 2)), np.sqrt(np.mean(x[-n:] ** 2))
        if not tail < ratio * head:
            return False
    return True


def _analyse_spectra(recs: Sequence[Recording], dofs: Sequence[str],
                     probe: Processing, noise_tol: float = 0.03) -> SpectrumSummary:
    """Significant peaks, stationary lines and the noise-limited high-pass (see auto)."""
    peaks: list[float] = []
    lines: list[float] = []
    top: float | None = None
    first: float | None = None
    noise_hz: float | None = None
    resolution = 0.0
    for rec in recs:
        i0 = probe.start_index(rec, dofs)
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
            rec_lines = _stationary_lines(x, fs, nper, freq, P, thr)
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


def _stationary_lines(x: np.ndarray, fs: float, nper: int, freq: np.ndarray,
                      P: np.ndarray, thr: np.ndarray) -> list[float]:
    """Narrow peaks that do not decay while the record does (hum, tones): noise."""
    n = len(x)
    third = n // 3
    pk, _ = signal.find_peaks(np.where(P > thr, P, 0.0))
    if not pk.size:
        return []
    df = freq[1] - freq[0]
    # narrow: the level 2 bins away has dropped by 10 dB or more
    narrow = [p for p in pk if 2 <= p < len(P) - 2 and max(P[p - 2], P[p + 2]) < 0.1 * P[p]]
    if not narrow:
        return []
    decaying = third >= 32 and np.std(x[-third:]) < 0.1 * np.std(x[:third])
    out: list[float] = []
    if decaying:
        seg = int(min(third, nper))
        f1, P1 = signal.welch(x[:third], fs=fs, nperseg=seg, detrend="linear")
        f3, P3 = signal.welch(x[-third:], fs=fs, nperseg=seg, detrend="linear")
        for p in narrow:
            k = int(np.argmin(np.abs(f1 - freq[p])))
            lo, hi = max(k - 1, 0), k + 2
            a, b = float(P1[lo:hi].max()), float(P3[lo:hi].max())
            if b > 0 and 0.25 < b / a < 4.0:
                out.append(float(freq[p]))
    else:
        for p in narrow:
            f0 = float(freq[p])
            for mains in (50.0, 60.0):
                h = round(f0 / mains)
                if h >= 1 and abs(f0 - h * mains) <= max(1.5 * df, 0.005 * f0):
                    out.append(f0)
                    break
    return out
