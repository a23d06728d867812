"""Checks before any training: is this set of records usable by this model at all?

One place for what the command line (``siva identify``, ``siva diagnose``) and the service
(an upload: 422) refuse in well under a second, instead of failing a minute into training
(or, worse, training to a wrong answer).  Every message names the file and says what to do.

The checks (docs/formats.md, "Checks before training"):

- **force**: a model whose spec has a ``[forces]`` table needs that force column; a record
  without any force whose response rises from rest mid-record (a hit) lacks its force.
- **sampling**: with known natural frequencies (the spec's ``initial`` parameter values, or
  the current estimate in the service) the highest linear mode must lie below Nyquist with
  at least ``MIN_SAMPLES_PER_PERIOD`` samples per period; from the data alone, a hammer
  pulse must span ``MIN_PULSE_SAMPLES`` samples and the strong response content must stay
  below ``MAX_CONTENT_FRACTION`` x fs (an aliased record shows its folded modes there) —
  refused when the dominant resonance itself is unresolved, else a warning (friction and
  impacts also put strong content near Nyquist).
- **mixed rates**: every record of one fit (or one service system) has the same sampling
  rate, unless resampling is asked for (``--resample``: to the lowest rate).
- **clipping**: a response or force channel that sits at its extreme value for
  ``CLIP_RUN`` samples or more in a row (a flat top: the sensor or ADC saturated).
- **too short**: a record must span ``MIN_PERIODS`` periods of the lowest mode (known
  modes: the spec's ``initial`` values or the service's estimate).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import Mapping, Sequence

import numpy as np

from .impulse import detect_impulse
from .recording import Recording, RecordingError
from .structure import Structure

#: a mode needs this many samples per period to be simulated and integrated faithfully
MIN_SAMPLES_PER_PERIOD = 8
#: a hammer pulse spanning fewer samples is not resolved (its impulse is a guess)
MIN_PULSE_SAMPLES = 4
#: strong response content (>= 10 % of the spectral peak) above this fraction of fs:
#: aliased, or too few samples per period
MAX_CONTENT_FRACTION = 0.4
#: periods of the lowest mode a record must span
MIN_PERIODS = 3.0
#: samples in a row at a channel's extreme value that make a flat top (clipping)
CLIP_RUN = 4
#: relative difference of two sampling rates still taken as the same rate
RATE_RTOL = 1e-6


@dataclass(frozen=True)
class Problem:
    """One refused (or, with ``fatal=False``, doubtful) property of one file."""

    file: str
    check: str      # force | nyquist | samples_per_period | pulse | aliased | mixed_rates |
    #                 clipping | too_short
    message: str
    fatal: bool = True

    def __str__(self) -> str:
        return self.message


class PreflightError(RecordingError):
    """Records refused before training; ``problems`` lists each (message: all of them)."""

    def __init__(self, problems: Sequence[Problem]) -> None:
        self.problems = list(problems)
        super().__init__("; ".join(p.message for p in self.problems))


@dataclass
class Preflight:
    """What :func:`preflight` let through: the records (resampled when asked) and notes."""

    train: list[Recording]
    val: list[Recording]
    notes: list[str] = field(default_factory=list)
    warnings: list[Problem] = field(default_factory=list)


def nominal_theta(structure: Structure) -> np.ndarray | None:
    """The spec's ``initial`` value of every free parameter, or None when one is missing."""
    vals = [structure.parameters[p].initial for p in structure.free]
    if any(v is None for v in vals):
        return None
    return np.array(vals, dtype=float)


def mode_frequencies(structure: Structure, theta: np.ndarray | None) -> list[float]:
    """Linear natural frequencies [Hz] at ``theta`` (the spec's ``initial`` values when
    None); [] when neither is known or the linearised model has no oscillating mode."""
    theta = nominal_theta(structure) if theta is None else np.asarray(theta, dtype=float)
    if theta is None or not np.all(np.isfinite(theta)):
        return []
    try:
        freqs = structure.linear_modes(theta)["frequency_hz"]
    except (ValueError, np.linalg.LinAlgError, ZeroDivisionError):
        return []
    return sorted(f for f in freqs if np.isfinite(f) and f > 0)


def check_recording(structure: Structure, rec: Recording, *,
                    theta: np.ndarray | None = None) -> list[Problem]:
    """Every single-record check (force, sampling, clipping, length) on ``rec``."""
    out: list[Problem] = []
    out += _check_force(structure, rec)
    modes = mode_frequencies(structure, theta)
    out += _check_sampling(structure, rec, modes)
    out += _check_clipping(structure, rec)
    out += _check_length(structure, rec, modes)
    return out


def check_rates(recs: Sequence[Recording], existing: Mapping[str, float] | None = None,
                *, what: str = "this fit") -> list[Problem]:
    """Mixed sampling rates among ``recs`` (and the ``existing`` {file: fs} of a system)."""
    seen: list[tuple[str, float]] = list((existing or {}).items())
    seen += [(r.name, r.fs) for r in recs]
    if not seen:
        return []
    ref_name, ref = seen[0]
    out = []
    for name, fs in seen[1:]:
        if abs(fs - ref) > RATE_RTOL * ref:
            out.append(Problem(name, "mixed_rates",
                               f"{name}: sampled at {fs:.6g} Hz, but {ref_name} in {what} at "
                               f"{ref:.6g} Hz; one fit needs one rate: resample the records "
                               f"to one rate (siva identify/diagnose --resample does it), or "
                               f"check the file's time step (a wrong Delta_X/wf_increment)"))
    # report each offending file once
    unique: dict[str, Problem] = {}
    for p in out:
        unique.setdefault(p.file, p)
    return list(unique.values())


def preflight(structure: Structure, train: Sequence[Recording],
              val: Sequence[Recording] = (), *, theta: np.ndarray | None = None,
              resample: bool = False) -> Preflight:
    """Run every check on the records of one fit; raise :class:`PreflightError` listing
    all fatal problems, else return the records (resampled to the lowest rate when
    ``resample`` and the rates differ) with notes and non-fatal warnings."""
    train, val = list(train), list(val)
    notes: list[str] = []
    rate_problems = check_rates([*train, *val])
    if rate_problems and resample:
        target = min(r.fs for r in [*train, *val])
        train = [resample_to(r, target) for r in train]
        val = [resample_to(r, target) for r in val]
        notes.append(f"resampled {', '.join(p.file for p in rate_problems)} to "
                     f"{target:.6g} Hz (--resample)")
        rate_problems = []
    problems = list(rate_problems)
    for rec in [*train, *val]:
        problems += check_recording(structure, rec, theta=theta)
    fatal = [p for p in problems if p.fatal]
    if fatal:
        raise PreflightError(fatal)
    return Preflight(train, val, notes, [p for p in problems if not p.fatal])


def resample_to(rec: Recording, fs: float) -> Recording:
    """``rec`` at sampling rate ``fs`` (polyphase, anti-aliased; time rebuilt uniform)."""
    if abs(rec.fs - fs) <= RATE_RTOL * fs:
        return rec
    from scipy.signal import resample_poly

    ratio = Fraction(fs / rec.fs).limit_denominator(4096)
    up, down = ratio.numerator, ratio.denominator
    chans = {k: resample_poly(v, up, down) for k, v in rec.channels.items()}
    n = len(next(iter(chans.values())))
    true_fs = rec.fs * up / down
    t = rec.time[0] + np.arange(n) / true_fs
    meta = {**rec.meta, "resampled_from_hz": rec.fs}
    return Recording(t, chans, rec.name, meta)


# --------------------------------------------------------------------------- the checks
def _responses(structure: Structure, rec: Recording) -> list[tuple[str, np.ndarray]]:
    """Per DOF the most derivative response measured (acc, else vel, else disp)."""
    out = []
    for d in structure.dofs:
        for q in ("acc", "vel", "disp"):
            x = rec.get(q, d)
            if x is not None:
                out.append((f"{q}_{d}", x))
                break
    return out


def _check_force(structure: Structure, rec: Recording) -> list[Problem]:
    needed = [d for d in structure.force_gains if rec.get("force", d) is None]
    if needed:
        cols = ", ".join(f"force_{d}" for d in needed)
        return [Problem(rec.name, "force",
                        f"{rec.name}: the model drives DOF(s) {needed} by a measured force "
                        f"([forces] in the spec) but the file has no {cols} column; map the "
                        f"force channel (--map \"Hammer={cols.split(', ')[0]}\") or add it")]
    rise = _rise_from_rest(structure, rec)
    if rise is None:
        return []
    col, t_rise = rise
    if rec.has_force(structure.dofs):
        f = np.stack([rec.get("force", d) for d in structure.dofs
                      if rec.get("force", d) is not None], axis=-1)
        mag = np.max(np.abs(f - np.median(f, axis=0)), axis=-1)
        sigma = max(_white_sigma(f[:, k]) for k in range(f.shape[1]))
        if sigma > 0 and float(mag.max()) < 10 * sigma:
            return [Problem(rec.name, "force",
                            f"{rec.name}: {col} rises from rest at t = {t_rise:.4g} s but the "
                            f"force holds only noise (peak {float(mag.max()):.3g} N, "
                            f"{float(mag.max()) / sigma:.1f} x its noise level): the hit fell "
                            f"between samples at {rec.fs:.6g} Hz (record faster), or the "
                            f"mapped force channel is not the hammer")]
        return []
    forced = [f"force_{d}" for d in structure.dofs]
    return [Problem(rec.name, "force",
                    f"{rec.name}: {col} rises from rest at t = {t_rise:.4g} s, so something "
                    f"forced it, but the file has no force column ({' or '.join(forced)}); "
                    f"map the force channel (e.g. --map \"Hammer={forced[-1]}\"), or cut the "
                    f"record to start at the release if it is a free decay")]


def _white_sigma(x: np.ndarray) -> float:
    d = np.diff(np.asarray(x, dtype=float), 3)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(20.0))


def _rise_from_rest(structure: Structure, rec: Recording) -> tuple[str, float] | None:
    """(column, time) where a response that was at rest rises (a hit), else None: the
    samples before it first reaches 10 % of its peak are at least 3 and quiet (RMS below
    2 % of the peak).  A free decay starts moving at once, so it is not one."""
    for col, x in _responses(structure, rec):
        x = np.asarray(x, dtype=float)
        x = x - float(np.median(x[: max(3, len(x) // 100)]))
        peak = float(np.max(np.abs(x)))
        if not peak > 0:
            continue
        rise = int(np.flatnonzero(np.abs(x) > 0.1 * peak)[0])
        if rise >= 3 and float(np.sqrt(np.mean(x[:rise] ** 2))) < 0.02 * peak:
            return col, float(rec.time[rise])
    return None


def _check_sampling(structure: Structure, rec: Recording, modes: Sequence[float]
                    ) -> list[Problem]:
    fs = rec.fs
    out: list[Problem] = []
    if modes:
        top = max(modes)
        if top >= fs / 2:
            out.append(Problem(rec.name, "nyquist",
                               f"{rec.name}: sampled at {fs:.6g} Hz, Nyquist {fs / 2:.6g} Hz, "
                               f"below the model's highest mode {top:.4g} Hz: that mode is "
                               f"aliased; record at {MIN_SAMPLES_PER_PERIOD * top:.0f} Hz or "
                               f"more (or check the file's time step)"))
        elif fs / top < MIN_SAMPLES_PER_PERIOD:
            out.append(Problem(rec.name, "samples_per_period",
                               f"{rec.name}: {fs / top:.1f} samples per period of the model's "
                               f"highest mode {top:.4g} Hz at {fs:.6g} Hz; at least "
                               f"{MIN_SAMPLES_PER_PERIOD} needed: record at "
                               f"{MIN_SAMPLES_PER_PERIOD * top:.0f} Hz or more"))
    forces = [rec.get("force", d) for d in structure.dofs]
    forces = [f for f in forces if f is not None]
    if forces:
        imp = detect_impulse(np.stack(forces, axis=-1))
        if imp is not None:
            width = int(imp.end - imp.first) if imp.end > imp.first else 1
            if width < MIN_PULSE_SAMPLES:
                out.append(Problem(rec.name, "pulse",
                                   f"{rec.name}: the force pulse spans {width} sample(s) at "
                                   f"{fs:.6g} Hz; at least {MIN_PULSE_SAMPLES} are needed to "
                                   f"know its impulse: record faster (or check the file's "
                                   f"time step)"))
    content = _strong_content(rec, structure)
    if content is not None and content[1] > MAX_CONTENT_FRACTION * fs and not out:
        f_peak, f_hi = content
        # The dominant resonance resolved (>= MIN_SAMPLES_PER_PERIOD samples per period, or
        # the model's known modes are): strong content near Nyquist is then as likely an
        # unmodelled nonlinearity (friction's jumps, impacts) as a folded higher mode, so
        # it is reported, not refused.  An unresolved dominant peak is refused.
        resolved = f_peak * MIN_SAMPLES_PER_PERIOD <= fs or bool(modes)
        tail = ("kept: it may also be friction or impacts, which the diagnosis can name"
                if resolved else "record at "
                f"{MIN_SAMPLES_PER_PERIOD * f_hi:.0f} Hz or more (or check the file's time step)")
        out.append(Problem(rec.name, "aliased",
                           f"{rec.name}: strong response at {f_hi:.4g} Hz, "
                           f"{fs / f_hi:.1f} samples per period at {fs:.6g} Hz (Nyquist "
                           f"{fs / 2:.6g} Hz): the record may be aliased or too coarsely "
                           f"sampled; {tail}", fatal=not resolved))
    return out


def _spectrum(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    amp = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1.0 / fs)
    return f, amp


def _strong_content(rec: Recording, structure: Structure) -> tuple[float, float] | None:
    """(frequency of the spectrum's peak, highest frequency whose smoothed response
    amplitude reaches 10 % of that peak) [Hz], over the DOFs (None without a response)."""
    peak_amp, f_peak, top = 0.0, 0.0, None
    for _, x in _responses(structure, rec):
        if len(x) < 16:
            continue
        f, amp = _spectrum(x, rec.fs)
        amp[0] = 0.0
        k = max(1, len(amp) // 512)
        smooth = np.convolve(amp, np.ones(k) / k, mode="same")
        if not smooth.max() > 0:
            continue
        if smooth.max() > peak_amp:
            peak_amp, f_peak = float(smooth.max()), float(f[int(np.argmax(smooth))])
        strong = np.flatnonzero(smooth >= 0.1 * smooth.max())
        fh = float(f[strong[-1]])
        top = fh if top is None else max(top, fh)
    return None if top is None else (f_peak, top)


def _check_clipping(structure: Structure, rec: Recording) -> list[Problem]:
    out = []
    for col, x in rec.channels.items():
        x = np.asarray(x, dtype=float)
        span = float(x.max() - x.min())
        if not span > 0:
            continue
        for extreme, label in ((x.max(), "maximum"), (x.min(), "minimum")):
            if abs(extreme - np.median(x)) < 0.25 * span:
                continue  # not a peak of the signal (one-sided record)
            at = np.abs(x - extreme) <= 1e-9 * span
            run = _longest_run(at)
            if run >= CLIP_RUN:
                i = int(np.flatnonzero(at)[0])
                out.append(Problem(rec.name, "clipping",
                                   f"{rec.name}: column {col!r} is flat at its {label} "
                                   f"{extreme:.6g} for {run} samples in a row (from t = "
                                   f"{rec.time[i]:.4g} s): the sensor or ADC saturated; "
                                   f"repeat the test with a larger input range or a "
                                   f"smaller hit"))
                break
    return out


def _longest_run(mask: np.ndarray) -> int:
    if not mask.any():
        return 0
    padded = np.r_[False, mask, False].astype(np.int8)
    d = np.diff(padded)
    return int((np.flatnonzero(d == -1) - np.flatnonzero(d == 1)).max())


def _check_length(structure: Structure, rec: Recording, modes: Sequence[float]
                  ) -> list[Problem]:
    duration = float(rec.time[-1] - rec.time[0])
    if not modes:
        return []  # from the data alone a short record's main frequency is itself unsure
    low, source = min(modes), "the model's lowest mode"
    if low is None or not low > 0:
        return []
    periods = duration * low
    if periods < MIN_PERIODS:
        return [Problem(rec.name, "too_short",
                        f"{rec.name}: {duration:.4g} s is {periods:.2g} period(s) of "
                        f"{source} ({low:.4g} Hz); at least {MIN_PERIODS:g} needed: record "
                        f"for {MIN_PERIODS / low:.3g} s or more")]
    return []


__all__ = ["Problem", "PreflightError", "Preflight", "preflight", "check_recording",
           "check_rates", "resample_to", "mode_frequencies", "nominal_theta",
           "MIN_SAMPLES_PER_PERIOD", "MIN_PULSE_SAMPLES", "MIN_PERIODS", "CLIP_RUN"]
