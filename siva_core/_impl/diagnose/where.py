"""Where the gap lies (step 6): per DOF, record, decay phase and frequency band."""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import signal

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .outputs import _ATTR, _Outputs
from .results import Candidate


def _energy_windows(y: np.ndarray) -> list[slice]:
    """Early / middle / late of a decay: where the measured response has delivered 50 %,
    then 90 %, of its energy (amplitude-based, so it means the same on every record)."""
    e = np.cumsum(np.sum(y ** 2, axis=1))
    if e[-1] <= 0:
        n = len(y)
        return [slice(0, n // 3), slice(n // 3, 2 * n // 3), slice(2 * n // 3, n)]
    i50 = int(np.searchsorted(e, 0.5 * e[-1])) + 1
    i90 = max(i50 + 1, int(np.searchsorted(e, 0.9 * e[-1])) + 1)
    return [slice(0, i50), slice(i50, i90), slice(i90, len(y))]


def _bands(freqs: Sequence[float], nyq: float) -> list[tuple[str, float, float]]:
    """Frequency bands around the nominal linear modes: below the first, one per mode
    (edges at geometric midpoints), and above the last (harmonics)."""
    fs_ = sorted(f for f in freqs if 0 < f < nyq)
    if not fs_:
        return [("all", 0.0, nyq)]
    edges = [fs_[0] / math.sqrt(2)]
    for a, b in zip(fs_[:-1], fs_[1:]):
        edges.append(math.sqrt(a * b))
    edges.append(min(nyq, fs_[-1] * math.sqrt(2)))
    out = [(f"below mode 1 (< {edges[0]:.3g} Hz)", 0.0, edges[0])]
    for m, f in enumerate(fs_):
        out.append((f"mode {m + 1} ({f:.3g} Hz: {edges[m]:.3g}-{edges[m + 1]:.3g} Hz)",
                    edges[m], edges[m + 1]))
    if edges[-1] < nyq:
        out.append((f"above (harmonics, > {edges[-1]:.3g} Hz)", edges[-1], nyq))
    return out


def spectral_noise_floor(structure: Structure, records: Sequence[Recording],
                         proc: Processing, theta: np.ndarray) -> float | None:
    """Mean white-noise floor of the processed records as an NMSE (the mean of
    ``channel_noise_floors`` over the DOFs): the level a model that is right leaves on
    them."""
    per = channel_noise_floors(structure, records, proc, theta)
    return float(np.mean(per)) if per is not None else None


def channel_noise_floors(structure: Structure, records: Sequence[Recording],
                         proc: Processing, theta: np.ndarray) -> np.ndarray | None:
    """Each DOF's white-noise floor as an NMSE of that DOF (``_noise_nmse_each``),
    averaged over the records: the floor against which a change confined to one response
    channel is judged (``set_members.shown``); their mean is the spectral floor."""
    outs = _Outputs(structure, records, proc, theta)
    vals = []
    for r in outs.records:
        y = r.target / r.rms
        t = _kept_time(proc, r.rec, structure.dofs, len(y))
        fs = 1.0 / (t[1] - t[0]) if len(t) > 1 else 1.0
        vals.append(_noise_nmse_each(y, fs, _passband(proc, fs)))
    return np.mean(vals, axis=0) if vals else None


def where_analysis(structure: Structure, theta_nom: np.ndarray, records: Sequence[Recording],
                   roles: Sequence[str], proc: Processing,
                   best: Candidate | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split the nominal output-error residual per DOF, record, decay phase and band.

    Returns (where-json, plot data for the HTML report).
    """
    outs = _Outputs(structure, records, proc, theta_nom)
    alt = _Outputs(best.structure, best.correct(records), proc, best.theta) if best is not None and \
        best.structure is not None else None
    dofs = structure.dofs
    modes = structure.linear_modes(theta_nom)["frequency_hz"]
    per_record, plots = [], []
    dof_num = np.zeros(len(dofs))
    dof_den = np.zeros(len(dofs))
    win_err = np.zeros(3)
    win_sig = np.zeros(3)
    band_acc: dict[str, list[float]] = {}
    for k, (r, role) in enumerate(zip(outs.records, roles)):
        st, _ = outs.signals(theta_nom, k)
        y = r.target / r.rms  # per-DOF normalised measurement
        sim = None if st is None else np.stack(
            [getattr(st, _ATTR[q])[:, d] for d, q in enumerate(r.quantities)], -1) / r.rms
        aug = None
        if alt is not None:
            sa, _ = alt.signals(best.theta, k)
            if sa is not None:
                ra = alt.records[k]
                aug = np.stack([getattr(sa, _ATTR[q])[:, d]
                                for d, q in enumerate(ra.quantities)], -1) / ra.rms
        t = _kept_time(proc, r.rec, structure.dofs, len(y))
        fs = 1.0 / (t[1] - t[0]) if len(t) > 1 else 1.0
        peak_force = float(np.max(np.abs(r.force))) if r.force is not None else 0.0
        entry: dict[str, Any] = {"record": r.rec.name, "role": role,
                                 "peak_force": peak_force,
                                 "response_rms": {d: float(x) for d, x in zip(dofs, r.rms)}}
        if sim is None:
            entry["gap"] = None
            per_record.append(entry)
            continue
        e = sim - y
        entry["gap"] = float(np.mean(np.mean(e ** 2, axis=0)))
        entry["gap_per_dof"] = {d: float(x) for d, x in zip(dofs, np.mean(e ** 2, axis=0))}
        if aug is not None:
            entry["gap_after"] = float(np.mean(np.mean((aug - y) ** 2, axis=0)))
        per_record.append(entry)
        plots.append({"record": r.rec.name, "role": role, "t": t, "y": y * r.rms,
                      "nominal": sim * r.rms, "augmented": None if aug is None else aug * r.rms,
                      "quantities": r.quantities, "fs": fs})
        if role != "val":
            continue
        dof_num += np.sum(e ** 2, axis=0) / len(e)
        dof_den += 1
        for w, sl in enumerate(_energy_windows(y)):
            win_err[w] += float(np.sum(e[sl] ** 2))
            win_sig[w] += float(np.sum(y[sl] ** 2))
        f, Pe = signal.welch(e, fs=fs, axis=0, nperseg=min(len(e), 1024))
        _, Py = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
        for name, lo, hi in _bands(modes, fs / 2):
            m = (f >= lo) & (f < hi)
            acc = band_acc.setdefault(name, [0.0, 0.0])
            acc[0] += float(np.sum(Pe[m]))
            acc[1] += float(np.sum(Py[m]))
    val_entries = [e for e in per_record if e["role"] == "val" and e.get("gap") is not None]
    per_dof = {d: float(x) for d, x in zip(dofs, dof_num / np.maximum(dof_den, 1))}
    windows = {name: (float(win_err[w] / win_sig[w]) if win_sig[w] > 0 else None)
               for w, name in enumerate(("early", "middle", "late"))}
    total_e = sum(v[0] for v in band_acc.values()) or 1.0
    bands = {name: {"share_of_gap": float(v[0] / total_e),
                    "relative_error": float(v[0] / v[1]) if v[1] > 0 else None}
             for name, v in band_acc.items()}
    trend = _amplitude_trend(val_entries if len(val_entries) >= 2 else
                             [e for e in per_record if e.get("gap") is not None])
    where = {
        "per_dof": per_dof,
        "per_record": per_record,
        "amplitude_trend": trend,
        "decay": windows,
        "frequency_bands": bands,
        "modes_hz": [float(x) for x in modes],
    }
    where["explanation"] = _explain(where, best)
    return where, {"records": plots, "modes": modes}


def _passband(proc: Processing, fs: float) -> tuple[float, float] | None:
    """The band the chain lets through (band-pass, high-pass, anti-aliasing), if any."""
    lo = max([x for x in (proc.bandpass[0] if proc.bandpass else None, proc.highpass)
              if x is not None], default=0.0)
    hi = min([x for x in (proc.bandpass[1] if proc.bandpass else None, 0.4 * fs)
              if x is not None])
    return (lo, hi) if hi > lo else None


def _kept_time(proc: Processing, rec: Recording, dofs: Sequence[str], n: int) -> np.ndarray:
    i0 = proc.start_index(rec, dofs) + int(round(proc.trim * rec.fs))
    k = proc.decimation(rec.fs)
    t = rec.time[i0::k][:n]
    return t if len(t) == n else np.arange(n) * rec.dt * k + rec.time[0]


def _noise_nmse_each(y: np.ndarray, fs: float, band: tuple[float, float] | None
                     ) -> np.ndarray:
    """White-noise floor of each DOF of a normalised measured record as an NMSE: the median
    Welch PSD over the chain's passband (a decaying response occupies few bins, noise all
    of them) times the passband width, over the signal's variance.  Stationary lines (hum)
    are not counted; bins the chain filtered out would bias the median low, so they are
    excluded."""
    if len(y) < 32:
        return np.zeros(y.shape[1] if y.ndim > 1 else 1)
    f, P = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
    lo, hi = band if band is not None else (0.0, fs / 2)
    hi = min(hi, fs / 2)
    m = (f > lo) & (f < hi)
    if m.sum() < 4:
        m = f > 0
    var = np.mean(y ** 2, axis=0)
    floor = np.median(P[m], axis=0) * (hi - lo)
    return np.atleast_1d(floor / np.maximum(var, 1e-300))


def _amplitude_trend(entries: Sequence[dict[str, Any]]) -> str:
    """Does the nominal gap grow or shrink with the excitation (peak force, else RMS)?"""
    if len(entries) < 2:
        return "one record only"
    amp = np.array([e["peak_force"] or np.mean(list(e["response_rms"].values()))
                    for e in entries])
    gap = np.array([e["gap"] for e in entries])
    order = np.argsort(amp)
    g = gap[order]
    if np.all(np.diff(g) > 0) and g[-1] > 1.5 * g[0]:
        return "grows with amplitude"
    if np.all(np.diff(g) < 0) and g[0] > 1.5 * g[-1]:
        return "shrinks with amplitude"
    if max(g) < 1.5 * min(g):
        return "about the same at every amplitude"
    return "varies with amplitude, not monotonically"


def _explain(where: Mapping[str, Any], best: Candidate | None) -> str:
    per_dof = where["per_dof"]
    parts = []
    if per_dof:
        worst = max(per_dof, key=lambda d: per_dof[d])
        tot = sum(per_dof.values()) or 1.0
        parts.append(f"The nominal model's validation gap is largest on {worst} "
                     f"({100 * per_dof[worst] / tot:.0f} % of it)")
    parts.append(f"it {where['amplitude_trend']}")
    win = {k: v for k, v in where["decay"].items() if v is not None}
    if win:
        w = max(win, key=lambda k: win[k])
        parts.append(f"relative to the response it is worst {w} in the decay "
                     f"(early {win.get('early', float('nan')):.3g}, late "
                     f"{win.get('late', float('nan')):.3g})")
    bands = where["frequency_bands"]
    if bands:
        b = max(bands, key=lambda k: bands[k]["share_of_gap"])
        parts.append(f"{100 * bands[b]['share_of_gap']:.0f} % of it lies in the band {b}")
    text = "; ".join(parts) + "."
    if best is not None:
        text += (f" Adding {best.effect.kind} {best.loc.between[0]}-{best.loc.between[1]} "
                 f"closes {100 * best.closure:.0f} % of it: {best.effect.describe(best.coefficients)}")
    return text
