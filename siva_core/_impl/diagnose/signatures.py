"""Amplitude-domain signatures: how damping and frequency depend on the vibration
amplitude, and how much even-harmonic content the response has.

Laws that act alike in a time trace differ here: per mode, the Hilbert envelope A(t) of the
mode-filtered decay gives the damping ratio zeta(A) = -dln A/dt / (2 pi f) and the
instantaneous frequency f(A) (the backbone).  Viscous damping keeps zeta constant,
velocity-squared damping makes it grow ~ A, a cubic (d^2 dv) damper ~ A^2, dry friction
~ 1/A; a hardening/softening spring bends the backbone up/down with A^2, a clearance only
above its gap.  Even harmonics (2f) come from asymmetric laws (quadratic spring, one-sided
stop).  Each is computed on the measured records, the nominal model and the best candidate,
all through the same processing chain, so their differences are evidence.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy import signal

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .outputs import _ATTR, _Outputs
from .results import Candidate

#: amplitude bins per mode (log-spaced between the 5th and 95th percentile of the envelope)
N_BINS = 6


def _mode_track(x: np.ndarray, fs: float, f0: float) -> tuple[np.ndarray, ...] | None:
    """Envelope, instantaneous frequency and damping ratio of ``x`` band-passed around f0."""
    lo, hi = 0.7 * f0, min(1.3 * f0, 0.45 * fs)
    if hi <= lo or len(x) < 64:
        return None
    sos = signal.butter(3, [lo, hi], btype="band", fs=fs, output="sos")
    y = signal.sosfiltfilt(sos, x)
    z = signal.hilbert(y)
    env = np.abs(z)
    phase = np.unwrap(np.angle(z))
    win = max(3, int(round(2 * fs / f0)) | 1)  # smooth over ~2 periods
    ker = np.ones(win) / win
    f_inst = np.convolve(np.gradient(phase) * fs / (2 * np.pi), ker, "same")
    lnA = np.convolve(np.log(np.maximum(env, 1e-300)), ker, "same")
    zeta = -np.gradient(lnA) * fs / (2 * np.pi * np.maximum(f_inst, 1e-9))
    edge = win  # filter and smoothing transients at both ends
    if len(x) - 2 * edge < 16:  # a mode too slow for the record: no track left
        return None
    sl = slice(edge, len(x) - edge)
    return env[sl], f_inst[sl], zeta[sl]


def _binned(tracks: Sequence[tuple[np.ndarray, ...]], edges: np.ndarray,
            f0: float) -> dict[str, list]:
    env = np.concatenate([t[0] for t in tracks])
    f = np.concatenate([t[1] for t in tracks])
    z = np.concatenate([t[2] for t in tracks])
    ok = np.abs(f - f0) < 0.3 * f0  # where the band holds the mode, not noise or a stop
    env, f, z = env[ok], f[ok], z[ok]
    out: dict[str, list] = {"amplitude": [], "frequency_hz": [], "damping_ratio": []}
    for a, b in zip(edges[:-1], edges[1:]):
        m = (env >= a) & (env < b)
        if m.sum() < 8:
            continue
        out["amplitude"].append(float(math.sqrt(a * b)))
        out["frequency_hz"].append(float(np.median(f[m])))
        out["damping_ratio"].append(float(np.median(z[m])))
    return out


def _slope(curve: dict[str, list], key: str, log_y: bool) -> float | None:
    a = np.asarray(curve["amplitude"])
    y = np.asarray(curve[key])
    if len(a) < 3:
        return None
    if log_y:
        keep = y > 0
        if keep.sum() < 3:
            return None
        return float(np.polyfit(np.log(a[keep]), np.log(y[keep]), 1)[0])
    return float((y[-1] - y[0]) / max(abs(np.mean(y)), 1e-12))


def _even_ratio(x: np.ndarray, fs: float, f0: float) -> float:
    f, P = signal.welch(x, fs=fs, nperseg=min(len(x), 1024))
    band = lambda c: P[(f > 0.85 * c) & (f < 1.15 * c)].sum()  # noqa: E731
    p1 = band(f0)
    return float(np.sqrt(band(2 * f0) / p1)) if p1 > 0 and 2.3 * f0 < fs / 2 else math.nan


def amplitude_signatures(structure: Structure, theta: np.ndarray, val: Sequence[Recording],
                         proc: Processing, best: Candidate | None) -> dict[str, Any]:
    """Per linear mode: damping ratio and frequency vs amplitude (binned), their trend, and
    the even-harmonic ratio, for the measured validation records, the nominal model and
    the best candidate (when it is a structural one)."""
    try:
        modes = [f for f in structure.linear_modes(theta)["frequency_hz"] if f > 0]
    except Exception:  # noqa: BLE001 - no linearisation, no signature
        return {}
    sources: dict[str, list[tuple[np.ndarray, float, list[str]]]] = {"measured": [],
                                                                    "nominal": []}
    outs = _Outputs(structure, val, proc, theta)
    alt = None
    if best is not None and best.structure is not None and best.theta is not None:
        sources["candidate"] = []
        alt = _Outputs(best.structure, best.correct(val), proc, best.theta)
    for k, r in enumerate(outs.records):
        n = r.target.shape[0]
        fs = r.rec.fs / max(proc.decimation(r.rec.fs), 1)
        sources["measured"].append((r.target, fs, r.quantities))
        st, _ = outs.signals(theta, k)
        if st is not None:
            sources["nominal"].append((np.stack([getattr(st, _ATTR[q])[:, d] for d, q in
                                                 enumerate(r.quantities)], -1)[:n], fs,
                                       r.quantities))
        if alt is not None:
            sa, _ = alt.signals(best.theta, k)
            if sa is not None:
                sources["candidate"].append((np.stack(
                    [getattr(sa, _ATTR[q])[:, d] for d, q in enumerate(r.quantities)],
                    -1)[:n], fs, r.quantities))
    out: dict[str, Any] = {"modes": []}
    for m, f0 in enumerate(modes):
        # the DOF where this mode is strongest in the measurement
        meas = sources["measured"]
        if not meas:
            break
        power = np.zeros(structure.n_dof)
        for y, fs, _ in meas:
            f, P = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
            power += P[(f > 0.8 * f0) & (f < 1.2 * f0)].sum(axis=0) / np.mean(y ** 2, axis=0)
        d = int(np.argmax(power))
        entry: dict[str, Any] = {"mode": m + 1, "linear_frequency_hz": float(f0),
                                 "dof": structure.dofs[d],
                                 "quantity": meas[0][2][d]}
        tracks_meas = [t for y, fs, _ in meas if (t := _mode_track(y[:, d], fs, f0))]
        if not tracks_meas:
            continue
        env = np.concatenate([t[0] for t in tracks_meas])
        if env.size < 2:  # a mode too slow for the records leaves an empty track (seed 13007)
            continue
        lo, hi = np.percentile(env, [30, 99])  # the low tail is noise
        if not (hi > lo > 0):
            continue
        edges = np.geomspace(lo, hi, N_BINS + 1)
        for name, recs in sources.items():
            tracks = [t for y, fs, _ in recs if (t := _mode_track(y[:, d], fs, f0))]
            if not tracks:
                continue
            curve = _binned(tracks, edges, f0)
            curve["damping_exponent"] = _slope(curve, "damping_ratio", log_y=True)
            curve["frequency_shift"] = _slope(curve, "frequency_hz", log_y=False)
            ratios = [r for y, fs, _ in recs if np.isfinite(r := _even_ratio(y[:, d], fs, f0))]
            curve["even_harmonics"] = float(np.mean(ratios)) if ratios else None
            entry[name] = curve
        out["modes"].append(entry)
    out["reading"] = _reading(out["modes"])
    return out


def damping_change(curve: dict[str, Any]) -> float | None:
    """Damping ratio at the largest amplitude over that at the smallest, from the same
    binned curve the signature figure and table show (None with fewer than 2 bins)."""
    a = np.asarray(curve.get("amplitude") or [], dtype=float)
    z = np.asarray(curve.get("damping_ratio") or [], dtype=float)
    ok = np.isfinite(a) & np.isfinite(z) & (z > 0)
    if ok.sum() < 2:
        return None
    a, z = a[ok], z[ok]
    return float(z[np.argmax(a)] / z[np.argmin(a)])


def damping_words(curve: dict[str, Any], p: float) -> str:
    """What the damping does over the amplitude range, in words that agree with the
    curve's own end points: "about constant" only when it changes by less than 25 %,
    whatever the fitted exponent (a doubling over a decade is exponent 0.3)."""
    change = damping_change(curve)
    if change is not None and 0.8 <= change <= 1.25:
        return f"damping is about constant (viscous-like; x{change:.2f} over the range), " \
               f"exponent {p:+.2f}"
    if change is not None:
        verb = "grows" if change > 1 else "falls"
        like = ("dry-friction-like" if p < -0.5 else "velocity-squared-like" if 0.6 <= p < 1.4
                else "cubic-damper-like" if p >= 1.4 else "amplitude-dependent")
        return (f"damping {verb} x{change:.2f} from the smallest to the largest amplitude "
                f"({like}), exponent {p:+.2f}")
    law = ("falls with amplitude (dry-friction-like, ~1/A)" if p < -0.5 else
           "is about constant (viscous-like)" if p < 0.4 else
           "grows ~ A (velocity-squared-like)" if p < 1.4 else
           "grows ~ A^2 (cubic-damper-like)")
    return f"damping {law}, exponent {p:+.2f}"


def _reading(modes: Sequence[dict[str, Any]]) -> str:
    """One sentence per mode on what the measured signatures say against the nominal."""
    parts = []
    for e in modes:
        meas, nom = e.get("measured"), e.get("nominal")
        if not meas or not nom:
            continue
        words = []
        p = meas.get("damping_exponent")
        if p is not None:
            words.append(damping_words(meas, p))
        fs_m, fs_n = meas.get("frequency_shift"), nom.get("frequency_shift")
        if fs_m is not None and fs_n is not None:
            words.append(f"frequency changes {100 * fs_m:+.2f} % over the amplitude range "
                         f"(nominal model {100 * fs_n:+.2f} %)")
        eh_m, eh_n = meas.get("even_harmonics"), nom.get("even_harmonics")
        if eh_m is not None and eh_n is not None and np.isfinite(eh_m) and np.isfinite(eh_n):
            words.append(f"2f/f amplitude ratio {eh_m:.3g} (nominal {eh_n:.3g})")
        if words:
            parts.append(f"mode {e['mode']} ({e['linear_frequency_hz']:.3g} Hz, {e['dof']}): "
                         + "; ".join(words))
    return ". ".join(parts) + ("." if parts else "")
