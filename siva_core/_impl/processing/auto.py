"""The rule by which ``Processing.auto`` chooses a chain from the data (also in
docs/formats.md), for records never seen before."""
from __future__ import annotations

import warnings
from typing import Any, Iterable, Sequence

from ..impulse import detect_impulse
from ..recording import Recording
from .spectra import SpectrumSummary, analyse_spectra, decays
from .window import start_index


#: the Butterworth order of the chosen chain's filters
ORDER = 4
#: a stationary line is notched unless the zero-phase band edge already keeps at most
#: this share of its amplitude (``line_reach``)
LINE_LEAK = 0.01


def line_reach(order: int, leak: float | None = None) -> float:
    """How far past a band edge (a frequency ratio) a zero-phase Butterworth of ``order``
    still keeps more than ``leak`` (default ``LINE_LEAK``, read when called) of a line's
    amplitude: forward and backward, its gain there is 1 / (1 + x^(2 order)), so lines
    within that ratio of the edge are notched.  A leak of 0.5 gives 1: lines inside the
    band only, the rule before issue 16's fresh seed 18049."""
    leak = LINE_LEAK if leak is None else leak
    return float((1.0 / leak - 1.0) ** (1.0 / (2 * order)))


def auto_settings(recordings: Recording | Iterable[Recording], dofs: Sequence[str],
                  impact_threshold: float, cover: tuple[float, float] | None = None
                  ) -> tuple[dict[str, Any], SpectrumSummary] | None:
    """The settings of a chain chosen from the data and what the spectra said, or None
    when every record gives every state (nothing to derive: the chain's defaults).

    ``impact_threshold``: the chain's default, with which the start after an impact is
    found for the spectra.  ``cover`` = (lowest, highest) frequency [Hz] the band must
    keep, e.g. the linear modes of a model fitted in a first pass: the spectral peaks of
    strongly damped higher modes, or of a mode next to a mains line, can be missed, and a
    band that cuts a mode of the structure leaves its parameters unidentified (issue 16:
    modes at 49.5 and 82.7 Hz cut by a 48.8 Hz low-pass, nominal train cost 0.28 against
    0.025 with them); ``first`` becomes min(first, lowest), ``top`` max(top, highest).
    Rule:

    1. Every record gives disp, vel and acc for every DOF: nothing is done (the states
       are used as given, whole record, force as measured).
    2. Otherwise the measured spectra set the band.  For each DOF the most derivative
       quantity measured (acc, else vel, else disp) is analysed over the free response
       (after the force pulse when the force is impulsive): Welch PSD with ~0.25 Hz
       resolution (coarser for short records), noise floor N = median PSD (that of the
       upper half of the band when lower).
       *Stationary lines* (narrow peaks at a 50/60 Hz harmonic whose level stays within a
       factor 4 between the first and last third of a decaying record, or any such peak
       in a record that does not decay: mains hum) are noise; a lightly damped mode keeps
       its level too, so peaks elsewhere are never notched.  Every other local
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
         low-pass below them, which would cut the nonlinear harmonics above the hum;
         so do lines just outside it, within ``line_reach`` (1.78 for order 4) of an
         edge, where the band's own roll-off keeps more than 1 % of them.
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
    """
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    if not recs:
        raise ValueError("Processing.auto needs at least one recording")
    dofs = list(dofs)
    if all(rec.get(qty, d) is not None for rec in recs for d in dofs
           for qty in ("disp", "vel", "acc")):
        return None
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
    start = "impact" if impulsive else "start"
    summary = analyse_spectra(recs, dofs, [start_index(rec, dofs, start, impact_threshold)
                                       for rec in recs])
    fs_min = min(rec.fs for rec in recs)
    nyq = fs_min / 2
    duration = min(float(rec.time[-1] - rec.time[0]) for rec in recs)
    if summary.first_hz is None:
        warnings.warn("Processing.auto: no significant spectral peak found; "
                      "using a wide band", stacklevel=3)
        first, top = 40.0 / max(duration, 1e-9), 0.4 * nyq
    else:
        first, top = summary.first_hz, summary.top_hz or summary.first_hz
    if cover is not None:  # modes known to exist (e.g. a fitted model's): the band keeps them
        first = min(first, float(cover[0])) if cover[0] > 0 else first
        top = max(top, float(cover[1]))
    fh = min(max(summary.noise_hz or 0.0, first / 6.0, 4.0 / duration), first / 2.0)
    if fh > first / 2:
        warnings.warn(f"Processing.auto: record too short ({duration:.3g} s) for a "
                      f"high-pass well below the lowest peak ({first:.3g} Hz)",
                      stacklevel=3)
    fl = min(2.0 * max(top, first), 0.8 * nyq)
    # a line in a band edge's transition passes half-attenuated (issue 16, fresh seed
    # 18049: 50.1 Hz hum against a 49.6 Hz low-pass, 0.48 of it kept): notched too
    reach = line_reach(ORDER)
    lines = tuple(x for x in summary.lines_hz if fh / reach < x < fl * reach)
    k = int(fs_min // (4.0 * fl)) if fl > 0 else 1
    fh, fl = float(fh), float(fl)
    settings: dict[str, Any] = dict(
        bandpass=(fh, fl) if has_acc else None,
        highpass=fh if needs_int else None,
        lowpass_diff=fl if needs_diff else None,
        notch=tuple(float(x) for x in lines),
        decimate_to=float(fs_min / k) if k >= 2 else None,
        start=start,
        gate_force=impulsive,
        consistent=True,
        integrator="simpson",
        order=ORDER,
        # the low-pass rings for a few of its periods at the record's ends
        trim=float(min(4.0 / fl, 0.02 * duration)) if fl > 0 else 0.0,
    )
    if (needs_int and not any_force and summary.noise_hz is not None
            and summary.noise_hz < 4.0 / duration and all(decays(r, dofs) for r in recs)):
        # a clean free decay: integration constants from the decayed tail, no high-pass
        settings.update(bandpass=(0.0, fl) if has_acc else None, highpass=None,
                        drift="tail")
    return settings, summary
