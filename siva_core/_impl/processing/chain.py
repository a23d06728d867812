"""``Processing``: the chain's settings, its presets and its run on a recording.

The steps it runs live in the sibling modules (filters, integration and differentiation,
derivation with ledgers, the kept window, the automatic choice); this class holds the
settings and puts them together: ``apply`` on a measured record, ``apply_simulated`` on a
simulation of it (exactly the same chain, sample for sample).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar, Iterable, Sequence

import numpy as np

from ..chain_cache import memoised, record_digest
from ..recording import Recording
from .auto import auto_settings
from .calculus import TAIL_FRACTION, central_difference, cumulative_integral
from .derive import derive_arrays, force_full_rate, signal_ledgers
from .filters import acc_keys, apply_key, union, zero_phase
from .spectra import SpectrumSummary
from .states import States, copy_states
from .window import decimation_factor, gated_force, start_index


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

        The rule (also in docs/formats.md) is :func:`.auto.auto_settings`'s: every state
        given, nothing is done; otherwise the measured spectra set a consistent band-pass,
        notches for stationary lines, the integration high-pass, the decimation and the
        start after an impact.

        ``cover`` = (lowest, highest) frequency the band must keep (see ``auto_settings``).
        ``overrides`` replace any chosen setting.  The analysis is kept in ``summary``.
        """
        chosen = auto_settings(recordings, dofs, cls.impact_threshold, cover)
        if chosen is None:
            return cls(**overrides)
        settings, summary = chosen
        settings.update(overrides)
        out = cls(**settings)
        out.summary = summary
        return out

    # ------------------------------------------------------------------ filters
    def _filt(self, x: np.ndarray, kind: str, cut: Any, fs: float, axis: int = 0) -> np.ndarray:
        """Zero-phase (forward-backward) second-order sections; short records still work."""
        return zero_phase(x, kind, cut, fs, self.order, axis)

    def filter_acc(self, a: np.ndarray, fs: float, axis: int = 0) -> np.ndarray:
        """The chain's treatment of a measured acceleration (band-pass and notches)."""
        for key in acc_keys(self.bandpass, self.notch, self.notch_q, fs):
            a = apply_key(a, key, fs, self.order, axis)
        return a

    def integrate(self, x: np.ndarray, fs: float, x0: np.ndarray | None = None,
                  axis: int = 0) -> np.ndarray:
        """Cumulative integral from 0 (``integrator``), then the zero-phase high-pass."""
        x = np.moveaxis(np.asarray(x, dtype=float), axis, 0)
        dt = 1.0 / fs
        y = cumulative_integral(x, dt, self.integrator)
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
    def _measured_force(self, rec: Recording, dofs: Sequence[str]) -> tuple[np.ndarray, int]:
        """(the kept force samples as ``apply`` returns them, start index) of a measured
        record, memoised: ``apply_simulated`` needs them on every call, and they depend
        on nothing simulated."""
        forces = [k for k in rec.channels if k.startswith("force_")]
        key = ("measured_force", repr(self), tuple(dofs), record_digest(rec, forces))

        def compute() -> tuple[np.ndarray, int]:
            fs = rec.fs
            present = lambda qty, d: rec.get(qty, d) is not None
            ledgers = [led for d in dofs for led in signal_ledgers(
                self, fs, present("disp", d), present("vel", d), present("acc", d))]
            f = force_full_rate(self, self.force(rec, dofs), fs, union(ledgers))
            f, sl, i0 = self._finish_force(rec, dofs, f)
            return f[sl].copy(), i0

        f, i0 = memoised(key, compute)
        return f.copy(), i0

    def force(self, rec: Recording, dofs: Sequence[str]) -> np.ndarray:
        """(T, n_dof) force as the chain uses it, before filtering: the record's force
        columns (0 where a DOF has none), gated to its pulse(s) when ``gate_force``
        (``impact_threshold`` of the peak, widened by ``gate_margin`` s; see ``impulse``).
        The simulator is driven by this force, so that what is simulated is what the chain
        reports."""
        return gated_force(rec, dofs, self.gate_force, self.impact_threshold, self.gate_margin)

    def derive(self, rec: Recording, dofs: Sequence[str]) -> tuple[np.ndarray, ...]:
        """Full-rate (q, v, a, F) arrays, each (T, n_dof), before decimation/start."""
        return derive_arrays(self, rec.fs, dofs, rec.get, self.force(rec, dofs))

    def start_index(self, rec: Recording, dofs: Sequence[str]) -> int:
        """Index of the first kept sample: 0, a time, or just after the force pulse."""
        return start_index(rec, dofs, self.start, self.impact_threshold)

    def decimation(self, fs: float) -> int:
        """Integer decimation factor reaching ``decimate_to`` (1 when off or above fs)."""
        return decimation_factor(fs, self.decimate_to)

    def _finish(self, rec: Recording, dofs: Sequence[str], q: np.ndarray, v: np.ndarray,
                a: np.ndarray, f: np.ndarray | None, need: str = "qva") -> States:
        """Decimate (zero-phase anti-aliasing) and cut to the kept window (only the
        ``need``ed of q, v, a: the others stay NaN, see ``derive.derive_arrays``; ``f=None``:
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

        return copy_states(memoised(key, compute))

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

        qq, vv, aa, _ = derive_arrays(self, measured.fs, dofs, given, None, need)
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
