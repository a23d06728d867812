"""Figures per record: measured vs simulated displacement, spectra, CWT (paper Figs. 4, 5,
9, 11)."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..spectra import cwt, fourier_amplitude, frequency_band
from .simulations import RecordSims
from .style import COLOURS, LABELS, mse, subplots


def fig_response(rs: RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = subplots(n, 3, figsize=(18, 3.0 * n), squeeze=False,
                            sharex=True)
    t = rs.t
    for k, d in enumerate(dofs):
        m = rs.measured[:, k]
        ax = axs[k, 0]
        ax.plot(t, m, color=COLOURS["measured"], lw=1.0, label="measured")
        if len(rs.band_sims):
            b = rs.band_sims[:, :, k]
            lo, hi = np.percentile(b, [2.5, 97.5], axis=0)
            mean = b.mean(axis=0)
            ax.fill_between(t, lo, hi, color=COLOURS["band"], alpha=0.7, lw=0,
                            label=f"95 % band ({len(b)} Approach I sims)")
            ax.plot(t, mean, color=COLOURS["I_mean_sim"], lw=0.9,
                    label=f"mean of sims (MSE {mse(m, mean):.3g} mm²)")
        pI = rs.points["approach_I"][:, k]
        ax.plot(t, pI, color=COLOURS["approach_I"], lw=0.9, ls="--",
                label=f"Approach I mean params (MSE {mse(m, pI):.3g} mm²)")
        ax.set_title(f"{rs.name} ({rs.role}) - {d}: Approach I"
                     + (f", {rs.n_diverged} sims diverged" if rs.n_diverged else ""))
        ax = axs[k, 1]
        ax.plot(t, m, color=COLOURS["measured"], lw=1.0, label="measured")
        if rs.best_sims is not None and len(rs.best_sims):
            lo, hi = np.percentile(rs.best_sims[:, :, k], [2.5, 97.5], axis=0)
            ax.fill_between(t, lo, hi, color=COLOURS["best"], alpha=0.25, lw=0,
                            label=f"best 95 % band ({len(rs.best_sims)} sets from its CI)")
        for key, ls in (("approach_II", "-"), ("approach_III", "--"), ("best", ":")):
            y = rs.points[key][:, k]
            ax.plot(t, y, color=COLOURS[key], lw=1.0, ls=ls,
                    label=f"{LABELS[key]} (MSE {mse(m, y):.3g} mm²)")
        ax.set_title(f"{rs.name} ({rs.role}) - {d}: Approaches II, III, best")
        ax = axs[k, 2]
        for key, ls in (("best", "-"), ("approach_II", "--")):
            y = rs.points[key][:, k]
            if np.all(np.isfinite(y)):
                r = m - y
                ax.plot(t, r, color=COLOURS[key], lw=0.8, ls=ls,
                        label=f"{LABELS[key]}: RMS {np.sqrt(np.mean(r ** 2)):.3g} mm "
                              f"({100 * np.sqrt(np.mean(r ** 2) / max(np.mean(m ** 2), 1e-300)):.1f} % of measured)")
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"{d}: residual, measured - simulated")
        for ax in axs[k]:
            ax.set_ylabel(f"{d} displacement [mm]")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper right")
    for ax in axs[-1]:
        ax.set_xlabel("time [s]")
    return fig


def fig_spectrum(rs: RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = subplots(n, 1, figsize=(9, 3.0 * n), squeeze=False)
    fmin, fmax = frequency_band(rs.measured, rs.fs, include=rs.modes_hz)
    for k, d in enumerate(dofs):
        ax = axs[k, 0]
        f, a = fourier_amplitude(rs.measured[:, k], rs.fs)
        sel = f <= fmax
        ax.semilogy(f[sel], a[sel], color=COLOURS["measured"], lw=1.2, label="measured")
        if len(rs.band_sims):
            _, am = fourier_amplitude(rs.band_sims[:, :, k].mean(axis=0), rs.fs)
            ax.semilogy(f[sel], am[sel], color=COLOURS["I_mean_sim"], lw=0.9,
                        label="mean of Approach I sims")
        for key, ls in (("approach_II", "-"), ("approach_III", "--"), ("best", ":")):
            y = rs.points[key][:, k]
            if np.all(np.isfinite(y)):
                _, ay = fourier_amplitude(y, rs.fs)
                ax.semilogy(f[sel], ay[sel], color=COLOURS[key], lw=1.0, ls=ls, label=LABELS[key])
        band = a[sel & (f >= fmin)]
        top = float(band.max()) if band.size and band.max() > 0 else 1.0
        floor = float(np.percentile(band[band > 0], 1)) / 3 if np.any(band > 0) else top * 1e-4
        ax.set_ylim(max(floor, top * 1e-5), top * 3)
        ax.set_xlim(0, fmax)
        for j, fm in enumerate(rs.modes_hz):
            ax.axvline(fm, color="tab:gray", lw=0.8, ls="--",
                       label="natural frequencies of best" if j == 0 else None)
            ax.annotate(f"{fm:.3g} Hz", (fm, 1), xycoords=("data", "axes fraction"),
                        xytext=(2, -10), textcoords="offset points", fontsize=7, color="tab:gray")
        ax.set_title(f"{rs.name} ({rs.role}) - {d}: Fourier amplitude")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("amplitude [mm]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, loc="upper right")
    return fig


def fig_cwt(rs: RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = subplots(n, 2, figsize=(12, 3.0 * n), squeeze=False,
                            sharey="row")
    t = rs.t
    _, fmax = frequency_band(rs.measured, rs.fs, include=rs.modes_hz)
    freqs = np.linspace(max(fmax / 100, 2 * rs.fs / len(t)), fmax, 96)
    stride = max(1, len(t) // 1500)
    im = None
    for k, d in enumerate(dofs):
        for j, (label, y) in enumerate((("measured", rs.measured[:, k]),
                                        ("best (simulated)", rs.points["best"][:, k]))):
            ax = axs[k, j]
            if np.all(np.isfinite(y)) and np.ptp(y) > 0:
                _, mag = cwt(y, rs.fs, freqs)
                im = ax.imshow(mag[:, ::stride], aspect="auto", origin="lower", cmap="jet",
                               vmin=0, vmax=1, extent=(t[0], t[-1], freqs[0], freqs[-1]),
                               interpolation="nearest")
            else:
                ax.text(0.5, 0.5, "simulation diverged", ha="center", transform=ax.transAxes)
            for fm in rs.modes_hz:
                if freqs[0] <= fm <= freqs[-1]:
                    ax.axhline(fm, color="white", ls="--", lw=0.7)
            ax.set_title(f"{rs.name} - {d}: CWT {label}")
            ax.set_xlabel("time [s]")
            ax.set_ylabel("frequency [Hz]")
    fig.tight_layout(rect=(0, 0, 0.91, 1))
    if im is not None:
        cax = fig.add_axes((0.925, 0.15, 0.012, 0.7))
        fig.colorbar(im, cax=cax, label="normalised |W|")
    fig._siva_laid_out = True
    return fig
