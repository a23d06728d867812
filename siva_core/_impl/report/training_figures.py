"""Figures of the training itself: losses, parameters per epoch, Approach II distributions
(paper Figs. 3, 8)."""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..ensemble import Z95
from .style import COLOURS, LABELS, LN4, grid, subplots, unit_of


def fig_losses(res: Any) -> Any:
    h = res.history
    ep = np.arange(len(h["loss_d"]))
    fig, axs = subplots(1, 3, figsize=(13, 3.6))
    ax = axs[0]
    ax.plot(ep, h["loss_d"], lw=0.8, color="tab:blue", label=r"$\mathcal{L}_D$")
    ax.axhline(LN4, color="k", ls="--", lw=1, label=f"ln 4 = {LN4:.4f}")
    ax.set_title("Discriminator loss")
    ax = axs[1]
    ax.plot(ep, h["loss_adv"], lw=0.8, color="tab:orange", label=r"$\mathcal{L}_{adv}$")
    ax.axhline(LN4 / 2, color="k", ls="--", lw=1, label=f"ln(4)/2 = {LN4 / 2:.4f}")
    ax.set_title("Adversarial term of the generator loss")
    ax = axs[2]
    mse = np.asarray(h["loss_mse"], dtype=float)
    ax.semilogy(ep, np.where(mse > 0, mse, np.nan), lw=0.8, color="tab:green",
                label=r"$\mathcal{L}_{MSE}$ (normalised acc.)")
    ax.set_title("MSE term (log axis)")
    for ax in axs:
        if res.converged_epoch is not None:
            ax.axvline(res.converged_epoch, color="tab:red", ls=":", lw=1.2,
                       label=f"converged (epoch {res.converged_epoch})")
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    return fig


def fig_parameters(res: Any, names: Sequence[str], window: tuple[int, int] | None,
                    truth: np.ndarray | None, units: Mapping[str, str] | None = None) -> Any:
    units = units or {}
    theta = np.array(res.history["theta"], dtype=float).reshape(-1, len(names))
    ep = np.arange(len(theta))
    nr, nc = grid(len(names))
    fig, axs = subplots(nr, nc, figsize=(4.3 * nc, 2.9 * nr),
                            squeeze=False)
    for k, p in enumerate(names):
        ax = axs.flat[k]
        ax.plot(ep, theta[:, k], lw=0.8, color="tab:blue", label="per epoch")
        if window is not None:
            ax.axvspan(window[0], window[1], color="tab:green", alpha=0.15,
                       label="Approach II window")
        if truth is not None and np.isfinite(truth[k]):
            ax.axhline(truth[k], color=COLOURS["truth"], lw=1, label=f"exact {truth[k]:.5g}")
        ax.axhline(res.best[k], color=COLOURS["best"], ls="--", lw=1.3, label=f"best {res.best[k]:.5g}")
        best_lo = best_hi = float(res.best[k])
        if res.best_std is not None and np.isfinite(res.best_std[k]):
            best_lo, best_hi = (float(res.best[k] - Z95 * res.best_std[k]),
                                float(res.best[k] + Z95 * res.best_std[k]))
            ax.axhspan(best_lo, best_hi, color=COLOURS["best"], alpha=0.15, lw=0,
                       label="best 95 %")
        if res.converged_epoch is not None:
            ax.axvline(res.converged_epoch, color="tab:red", ls=":", lw=1)
        # a first-epoch excursion would flatten the interesting part: limit to the harvest
        tail = theta[len(theta) // 4:, k]
        if len(tail) > 4 and np.all(np.isfinite(tail)):
            lo, hi = np.percentile(tail, [0.5, 99.5])
            refs = [best_lo, best_hi] + ([truth[k]] if truth is not None and np.isfinite(truth[k]) else [])
            lo, hi = min(lo, *refs), max(hi, *refs)
            pad = 0.15 * (hi - lo) if hi > lo else 0.05 * abs(hi) + 1e-12
            # the reference lines must stay on the axis even where the epochs never went
            full_lo = min(np.nanmin(theta[:, k]), *refs)
            full_hi = max(np.nanmax(theta[:, k]), *refs)
            ax.set_ylim(max(full_lo, lo - pad) - pad * 0.2, min(full_hi, hi + pad) + pad * 0.2)
        ax.set_title(p + unit_of(units, p))
        ax.set_ylabel(p + unit_of(units, p))
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in list(axs.flat)[len(names):]:
        ax.set_visible(False)
    return fig


def fig_distributions(res: Any, names: Sequence[str], truth: np.ndarray | None,
                       units: Mapping[str, str] | None = None) -> Any:
    units = units or {}
    S = np.asarray(res.samples_II, dtype=float).reshape(-1, len(names))
    nr, nc = grid(len(names))
    fig, axs = subplots(nr, nc, figsize=(4.3 * nc, 3.0 * nr),
                            squeeze=False)
    for k, p in enumerate(names):
        ax = axs.flat[k]
        col = S[:, k][np.isfinite(S[:, k])]
        summ = res.approach_II.get(p, {})
        mu = float(summ.get("mean", col.mean() if len(col) else np.nan))
        sd = float(summ.get("std", col.std(ddof=1) if len(col) > 1 else 0.0))
        if len(col):
            ax.hist(col, bins=min(40, max(8, len(col) // 8)), density=True, color="tab:blue",
                    alpha=0.45, label=f"Approach II (n={len(col)})")
        if sd > 0 and np.isfinite(sd):
            x = np.linspace(mu - 6 * sd, mu + 6 * sd, 400)
            pdf = np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
            ax.plot(x, pdf, color="tab:blue", lw=1.3, label="normal fit")
            ax.set_xlim(x[0], x[-1])
            ax.axvspan(mu - Z95 * sd, mu + Z95 * sd, color="tab:green", alpha=0.2,
                       label=f"95 % CI [{mu - Z95 * sd:.4g}, {mu + Z95 * sd:.4g}]")
        ax.axvline(mu, color="red", ls="--", lw=1.3, label=f"mean {mu:.5g}")
        lim = ax.get_xlim()
        marks = [("approach_III", float(res.approach_III[k]), ":", COLOURS["approach_III"]),
                 ("best", float(res.best[k]), "-.", COLOURS["best"])]
        if truth is not None and np.isfinite(truth[k]):
            marks.append(("exact", float(truth[k]), "-", COLOURS["truth"]))
        for label, val, ls, c in marks:
            off = not (lim[0] <= val <= lim[1])
            text = f"{LABELS.get(label, label)} {val:.5g}" + (" (off axis)" if off else "")
            if off:
                ax.plot([], [], color=c, ls=ls, label=text)
            else:
                ax.axvline(val, color=c, ls=ls, lw=1.4, label=text)
        ax.set_title(p + unit_of(units, p))
        ax.set_xlabel(p + unit_of(units, p))
        ax.set_ylabel("pdf")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, loc="upper right")
    for ax in list(axs.flat)[len(names):]:
        ax.set_visible(False)
    return fig
