"""The dashboard's view of one system's latest record: measured vs simulated, residual,
Fourier spectra and CWT, as plain JSON series.

Why a server-side computation: simulating the record needs the model, the processing chain
and the estimate, which only the service has.  It is CPU work (one simulation through the
chain, one CWT per DOF), so the route runs it in a thread, and :class:`LatestRecordCache`
keeps one result per system keyed by the *data version* (the latest record's id and the
parameter values used), so a dashboard polling every few seconds costs one computation per
new record or new estimate, not one per request.

The simulation is the report's (``siva identify``): the record's measured force drives the
model, and the simulated response passes through the *same* processing chain as the
measurement (``OutputErrorProblem``), so the residual compares like with like.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from siva_core import Processing, Recording, Structure


#: series longer than this are decimated (by a stride) before they are sent to a browser
MAX_POINTS = 1500
#: CWT grid sent to the browser: frequencies x time columns
CWT_FREQS = 64
CWT_COLUMNS = 240
#: a cached result younger than this is reused even when the ensemble mean moved a little
#: (the mean changes at every snapshot; re-simulating every poll would burn a core)
MIN_RECOMPUTE_S = 20.0


@dataclass(frozen=True)
class DofSeries:
    """One DOF of the view: measured, simulated and residual displacement [mm], their
    spectra and CWT magnitudes (decimated for a browser)."""

    measured: list[float | None]
    simulated: list[float | None]
    residual: list[float | None]
    rms_measured_mm: float
    rms_residual_mm: float | None          # None: the simulation diverged
    spectrum: dict[str, list[float | None]]
    nmse: float | None                     # None (absent): the simulation diverged
    cwt: dict[str, list[list[float]]]

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"measured": self.measured, "simulated": self.simulated,
                               "residual": self.residual,
                               "rms_measured_mm": self.rms_measured_mm,
                               "rms_residual_mm": self.rms_residual_mm,
                               "spectrum": self.spectrum}
        if self.nmse is not None:
            out["nmse"] = self.nmse
        out["cwt"] = self.cwt
        return out


@dataclass(frozen=True)
class LatestSeries:
    """:func:`compute_latest`'s result: the time and frequency axes and one
    :class:`DofSeries` per DOF."""

    t: list[float | None]
    fs_processed: float
    decimation: int
    diverged: bool
    spectrum_hz: list[float | None]
    band_hz: tuple[float, float]
    modes_hz: list[float]
    cwt_hz: list[float | None]
    cwt_t: list[float | None]
    dofs: dict[str, DofSeries]

    def to_json(self) -> dict[str, Any]:
        return {"t": self.t, "fs_processed": self.fs_processed, "decimation": self.decimation,
                "diverged": self.diverged, "spectrum_hz": self.spectrum_hz,
                "band_hz": list(self.band_hz), "modes_hz": self.modes_hz,
                "cwt_hz": self.cwt_hz, "cwt_t": self.cwt_t, "units": dict(UNITS),
                "dofs": {d: e.to_json() for d, e in self.dofs.items()}}


@dataclass(frozen=True)
class LatestRecord:
    """The latest record simulated with an estimate: what was simulated (record, parameters,
    their source, the trainer epoch then) and the series; ``computed_at`` is set by the
    cache.  The dashboard route builds its JSON body from it."""

    record: dict[str, Any]                 # id, role, filename, received_at(_iso)
    parameters: dict[str, float]
    parameters_source: str
    epoch: int
    series: LatestSeries
    computed_at: float | None = field(default=None)


#: units of the series (the ``units`` key of the view)
UNITS = {"t": "s", "displacement": "mm", "spectrum": "mm", "cwt": "normalised |W| (max 1)"}


def parameters_for_simulation(best: Mapping[str, Any] | None,
                              parameters: Mapping[str, Any] | None,
                              estimate_source: str | None, free: Sequence[str]
                              ) -> tuple[dict[str, float], str] | None:
    """The values to simulate with and where they come from: ``best`` when the refiner
    has one (what the service recommends), else the headline ``parameters`` means (a
    snapshot's keys).  Defensive about the payload's shape (``value`` or ``mean``)."""
    best = best or {}
    bp = best.get("parameters") if isinstance(best, Mapping) else None
    if isinstance(bp, Mapping) and all(isinstance(bp.get(p), Mapping) for p in free):
        vals = {p: bp[p].get("value", bp[p].get("mean")) for p in free}
        if all(isinstance(v, (int, float)) for v in vals.values()):
            return {p: float(v) for p, v in vals.items()}, "best"
    params = parameters or {}
    if all(isinstance(params.get(p), Mapping) for p in free):
        vals = {p: params[p].get("mean", params[p].get("value")) for p in free}
        if all(isinstance(v, (int, float)) for v in vals.values()):
            source = estimate_source or "parameters"
            return {p: float(v) for p, v in vals.items()}, str(source)
    return None


def _stride(n: int, limit: int) -> int:
    return max(1, int(np.ceil(n / limit)))


def _series(x: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in np.asarray(x, dtype=float)]


def compute_latest(structure: Structure, rec: Recording, processing: Processing | None,
                   theta: Mapping[str, float]) -> LatestSeries:
    """Measured vs simulated displacement [mm] of ``rec`` with ``theta``, the residual,
    the spectra of both, and the CWT (max 1) of the measured and simulated responses."""
    from siva_core import OutputErrorProblem, cwt, fourier_amplitude, frequency_band

    th = np.array([[theta[p] for p in structure.free]], dtype=float)
    prob = OutputErrorProblem.build(structure, [rec], processing or Processing(),
                                    quantity="disp", theta_ref=th)
    measured = prob.records[0].target * 1e3
    sims = prob.simulated_states(th, 0)
    sim_states = sims[0]
    if sim_states is not None and sim_states.q.shape == measured.shape:
        t = sim_states.t
        simulated = sim_states.q * 1e3
        diverged = False
    else:
        t = prob.chain.apply(rec, structure.dofs).t
        simulated = np.full_like(measured, np.nan)
        diverged = True
    fs = 1.0 / float(t[1] - t[0])
    step = _stride(len(t), MAX_POINTS)
    try:  # the axes must show every mode, also a weak one the energy criterion would cut
        modes = structure.linear_modes([theta[p] for p in structure.free]).get("frequency_hz", [])
    except Exception:  # noqa: BLE001 - a derived quantity must not stop the view
        modes = []
    fmin, fmax = frequency_band(measured, fs, include=modes)
    out_dofs: dict[str, DofSeries] = {}
    f_axis = None
    cwt_freqs = np.geomspace(max(fmax / 100, 2 * fs / len(t)), fmax, CWT_FREQS)
    cstep = _stride(len(t), CWT_COLUMNS)
    for k, d in enumerate(structure.dofs):
        m, s = measured[:, k], simulated[:, k]
        f, am = fourier_amplitude(m, fs)
        sel = (f > 0) & (f <= fmax)
        fstep = _stride(int(sel.sum()), MAX_POINTS)
        f_axis = f[sel][::fstep]
        spectrum = {"measured": _series(am[sel][::fstep])}
        nmse = None
        if not diverged:
            _, asim = fourier_amplitude(s, fs)
            spectrum["simulated"] = _series(asim[sel][::fstep])
            nmse = float(np.mean((m - s) ** 2) / max(np.mean(m ** 2), 1e-300))
        cw: dict[str, list[list[float]]] = {}
        for label, y in (("measured", m), ("simulated", s)):
            if np.all(np.isfinite(y)) and np.ptp(y) > 0:
                _, mag = cwt(y, fs, cwt_freqs)
                cw[label] = np.round(mag[:, ::cstep], 4).tolist()
        out_dofs[d] = DofSeries(
            measured=_series(m[::step]), simulated=_series(s[::step]),
            residual=_series((m - s)[::step]), rms_measured_mm=float(np.sqrt(np.mean(m ** 2))),
            rms_residual_mm=(float(np.sqrt(np.mean((m - s) ** 2))) if not diverged else None),
            spectrum=spectrum, nmse=nmse, cwt=cw)
    return LatestSeries(t=_series(t[::step]), fs_processed=fs, decimation=step,
                        diverged=diverged,
                        spectrum_hz=_series(f_axis if f_axis is not None else []),
                        band_hz=(float(fmin), float(fmax)),
                        modes_hz=[float(f) for f in modes if np.isfinite(f)],
                        cwt_hz=_series(cwt_freqs), cwt_t=_series(t[::cstep]), dofs=out_dofs)


@dataclass
class _Entry:
    key: tuple[Any, ...]
    rid: str
    computed: float
    value: LatestRecord


class LatestRecordCache:
    """One computed view per system, reused while the data version is unchanged.

    The lock per system makes concurrent polls wait for the one computation under way
    instead of starting their own."""

    def __init__(self) -> None:
        self._entries: dict[str, _Entry] = {}
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()
        self.computations = 0

    def _lock(self, system: str) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(system, threading.Lock())

    def get(self, system: str, key: tuple[Any, ...], rid: str,
            compute: Callable[[], LatestRecord]) -> tuple[LatestRecord, bool]:
        """The cached view for ``key`` (or for the same record, when younger than
        MIN_RECOMPUTE_S), else ``compute()``; returns (view, was_cached)."""
        with self._lock(system):
            e = self._entries.get(system)
            now = time.time()
            if e is not None and (e.key == key or (e.rid == rid and now - e.computed < MIN_RECOMPUTE_S)):
                return e.value, True
            value = replace(compute(), computed_at=now)
            self.computations += 1
            self._entries[system] = _Entry(key, rid, now, value)
            return value, False

    def forget(self, system: str) -> None:
        with self._guard:
            self._entries.pop(system, None)


__all__ = ["compute_latest", "parameters_for_simulation", "LatestRecordCache", "LatestRecord",
           "LatestSeries", "DofSeries"]
