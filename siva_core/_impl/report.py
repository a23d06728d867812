"""The paper's figures for one SIVA run, as PNGs plus an ``index.html`` that shows them.

``write_report(est, dir)`` draws, from a fitted :class:`~siva_core.Siva`:

(a) ``losses.png`` - discriminator loss with the ln 4 line (eq. 3), adversarial term with
    ln(4)/2 (= ln 2, the BCE of D = 0.5 against label 1; paper Sec. 3.1), MSE on a log
    axis; the convergence epoch marked (paper Figs. 3a, 8a);
(b) ``parameters.png`` - each parameter per epoch, the Approach II window shaded;
(c) ``distributions.png`` - Approach II histogram, fitted normal pdf over +-6 std, mean
    dashed red, 95 % CI shaded green, exact value solid black when known, Approach III and
    ``best`` marked (paper Figs. 3c, 8c);
(d) ``response_<k>.png`` per train / validation record - measured vs simulated displacement:
    mean of simulations of (a subset of) Approach I samples with the 95 % band, and the
    Approach I mean, II, III and best parameter sets (paper Figs. 4, 5, 9, 11);
(e) ``spectrum_<k>.png`` - Fourier amplitude spectra of measured vs simulated;
(f) ``cwt_<k>.png`` - complex-Morlet CWT (maximum 1) of measured vs best-simulated.

Simulations go through the same processing chain as the measurement
(:class:`~siva_core._impl.refine.OutputErrorProblem`), so what is compared is like with like
(the chain's own distortion appears on both sides).  Raw recordings are taken from
``est.train_recordings_`` / ``est.val_recordings_`` or the ``train=``/``val=`` arguments;
without them the processed states are simulated as records of their own (noted in the page).
"""
from __future__ import annotations

import html
import math
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .ensemble import Z95
from .processing import Processing, States
from .recording import Recording
from .spectra import cwt, fourier_amplitude, frequency_band

LN4 = math.log(4.0)
#: colours used consistently across figures (paper: measured black, Approach I blue/pink band)
COLOURS = {"measured": "black", "band": "#f4a6c0", "I_mean_sim": "tab:blue",
           "approach_I": "tab:green", "approach_II": "tab:orange", "approach_III": "tab:purple",
           "best": "tab:red", "truth": "black"}
LABELS = {"approach_I": "Approach I (mean params)", "approach_II": "Approach II",
          "approach_III": "Approach III", "best": "best"}

Progress = Callable[[str], None]
#: parameter sets drawn from N(best, best_std) for the 95 % band of the recommended estimate
N_BEST_BAND = 40


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclass
class _RecordSims:
    """One record: measured processed displacement and the simulated ones (mm)."""

    name: str
    role: str
    t: np.ndarray
    measured: np.ndarray            # (T, n_dof) mm
    band_sims: np.ndarray           # (S, T, n_dof) mm, finite Approach I simulations
    points: dict[str, np.ndarray]   # approach -> (T, n_dof) mm (NaN if diverged)
    n_diverged: int
    fs: float
    best_sims: np.ndarray | None = None  # (S, T, n_dof) mm, sets drawn from N(best, best_std)
    modes_hz: tuple[float, ...] = ()    # natural frequencies of best: the axes must show them


# ---------------------------------------------------------------------------- entry point
def write_report(est: Any, out_dir: str | Path, *, truth: Mapping[str, float] | None = None,
                 train: Sequence[Recording] | None = None, val: Sequence[Recording] | None = None,
                 n_sims: int = 200, sim_budget_s: float | None = 30.0, dpi: int = 100,
                 progress: Progress | None = _stderr) -> list[Path]:
    """Write the figures and ``index.html`` into ``out_dir``; returns the written paths
    (PNGs in drawing order, ``index.html`` last).  ``truth`` (optional) marks exact values.
    ``n_sims`` Approach I samples are simulated for the band (the paper used all 1000),
    fewer (at least 20 per record) when putting them through the processing chain would
    take longer than ``sim_budget_s`` in all (None: no limit)."""
    res = est.result_
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _m: None)
    names = list(res.names)
    units = est.structure.parameter_units() if hasattr(est.structure, "parameter_units") else {}
    truth_vec = _truth_vector(names, truth)
    written: list[tuple[Path, str]] = []
    t_start = time.perf_counter()

    def save(fig: Any, fname: str, caption: str) -> None:
        path = out / fname
        if not getattr(fig, "_siva_laid_out", False):
            fig.tight_layout()  # one layout pass: constrained layout re-runs on every draw
        fig.savefig(path, dpi=dpi)
        written.append((path, caption))
        say(f"report: {fname} ({time.perf_counter() - t_start:.1f} s)")

    save(_fig_losses(res), "losses.png",
         "(a) Losses per epoch: discriminator (ln 4 = optimum, eq. 3), adversarial term "
         "(ln(4)/2), MSE of the accelerations (log axis); dotted: convergence epoch.")
    window = _window(est, res)
    save(_fig_parameters(res, names, window, truth_vec, units), "parameters.png",
         "(b) Parameter per epoch (mean of the epoch's last batch); shaded green: the Approach "
         "II window; dashed red: best, with its 95 % interval shaded red.")
    save(_fig_distributions(res, names, truth_vec, units), "distributions.png",
         "(c) Approach II distribution: histogram, fitted normal pdf over +-6 std, mean "
         "(dashed red), 95 % CI (green); Approach III, best and exact value marked.")

    recs, note = _records(est, train, val)
    say(f"report: simulating {len(recs)} records ({min(n_sims, len(res.samples_I))} Approach I "
        f"samples + 4 point estimates each)")
    per_rec = None if sim_budget_s is None else sim_budget_s / max(1, len(recs))
    sims = []
    for rec, role in recs:
        sims.append(_simulate_record(est, res, rec, role, n_sims, per_rec))
        say(f"report: simulated {rec.name}: {len(sims[-1].band_sims)} band sets"
            + (f" ({sims[-1].n_diverged} diverged)" if sims[-1].n_diverged else "")
            + f" ({time.perf_counter() - t_start:.1f} s)")
    for k, rs in enumerate(sims):
        slug = f"{k}_{_slug(rs.name)}"
        save(_fig_response(rs, est.structure.dofs), f"response_{slug}.png",
             f"(d) {rs.role} record {rs.name}: measured vs simulated displacement, with the "
             "95 % bands of Approach I and of best, and the residuals (measured - simulated).")
        save(_fig_spectrum(rs, est.structure.dofs), f"spectrum_{slug}.png",
             f"(e) {rs.role} record {rs.name}: Fourier amplitude spectra; dashed grey: the "
             "natural frequencies of best (the axis reaches past the highest).")
        save(_fig_cwt(rs, est.structure.dofs), f"cwt_{slug}.png",
             f"(f) {rs.role} record {rs.name}: CWT (complex Morlet, max = 1), measured vs best; "
             "dashed white: the natural frequencies of best (the axis reaches past the highest).")

    index = out / "index.html"
    index.write_text(_html(est, res, names, truth_vec, written, sims, note))
    say(f"report: index.html, {len(written)} figures in {time.perf_counter() - t_start:.1f} s")
    return [p for p, _ in written] + [index]


# ---------------------------------------------------------------------------- data helpers
def _truth_vector(names: Sequence[str], truth: Mapping[str, float] | None) -> np.ndarray | None:
    if not truth:
        return None
    return np.array([float(truth[p]) if p in truth else np.nan for p in names])


def _window(est: Any, res: Any) -> tuple[int, int] | None:
    """First and last epoch of the Approach II samples."""
    ens = getattr(getattr(est, "trainer_", None), "ensemble", None)
    if ens is not None and len(ens):
        ep = ens.epochs
        return int(ep.min()), int(ep.max())
    n_ep = len(res.history.get("theta", []))
    E = len(res.samples_II)
    if n_ep == 0 or E == 0:
        return None
    return max(0, n_ep - E), n_ep - 1


def _records(est: Any, train: Sequence[Recording] | None, val: Sequence[Recording] | None
             ) -> tuple[list[tuple[Recording, str]], str | None]:
    """(recording, role) pairs: raw recordings when known, else the processed states."""
    train = train if train is not None else getattr(est, "train_recordings_", None)
    val = val if val is not None else getattr(est, "val_recordings_", None)
    note = None
    if train is None:
        train = [_states_as_recording(s, est.structure.dofs) for s in est.train_states_]
        val = [_states_as_recording(s, est.structure.dofs) for s in est.val_states_]
        note = ("raw recordings were not available: each record was simulated from its "
                "processed states (first state, processed force).")
    elif val is None:
        val = []
    return [(r, "training") for r in train] + [(r, "validation") for r in val], note


def _states_as_recording(s: States, dofs: Sequence[str]) -> Recording:
    ch: dict[str, np.ndarray] = {}
    for k, d in enumerate(dofs):
        ch[f"disp_{d}"] = s.q[:, k]
        ch[f"vel_{d}"] = s.v[:, k]
        ch[f"acc_{d}"] = s.a[:, k]
        if s.has_force:
            ch[f"force_{d}"] = s.f[:, k]
    return Recording(s.t, ch, s.name, {"from_states": True})


def _simulate_record(est: Any, res: Any, rec: Recording, role: str, n_sims: int,
                     budget_s: float | None = None) -> _RecordSims:
    """Simulate the point estimates and the Approach I subset on one record, each through
    the processing chain (``OutputErrorProblem.simulated_states``, batched).  Substeps are
    chosen from the point estimates and the band's 2.5/97.5 % parameter percentiles (one
    odd sample cannot force thousands).  ``budget_s`` caps the time spent on the band (at
    least 20 sets), extrapolated from the point estimates; the count used is shown."""
    from .refine import OutputErrorProblem

    st = est.structure
    if rec.meta.get("from_states"):
        proc = Processing()  # the states are already processed
    else:
        proc = getattr(est, "processing_", None) or res.processing or Processing()
    ests = res.estimates()
    order = ["approach_I", "approach_II", "approach_III", "best"]
    pts = np.stack([np.asarray(ests[k], dtype=float) for k in order])
    sub = np.asarray(res.samples_I, dtype=float)[:n_sims]
    ref = np.vstack([pts, np.percentile(sub, [2.5, 97.5], axis=0)]) if len(sub) else pts
    prob = OutputErrorProblem.build(st, [rec], proc, quantity="disp", theta_ref=ref)
    target = prob.records[0].target * 1e3
    T, n = target.shape

    def processed(thetas: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Displacement [mm] per set through the chain (NaN when diverged), and the time."""
        out, t = [], None
        for s in prob.simulated_states(thetas, 0):
            if s is not None and t is None:
                t = s.t
            ok = s is not None and s.q.shape == (T, n) and np.all(np.isfinite(s.q))
            out.append(s.q * 1e3 if ok else np.full((T, n), np.nan))
        return out, t

    t0 = time.perf_counter()
    point_q, t_axis = processed(pts)
    per_set = (time.perf_counter() - t0) / len(pts)
    n_band = len(sub)
    if budget_s is not None and per_set > 0:
        # the first batch includes fixed costs, so this errs on the side of fewer sets
        n_band = int(min(n_band, max(20, budget_s / per_set)))
    band_q = processed(sub[:n_band])[0] if n_band else []
    band = np.array([q for q in band_q if np.all(np.isfinite(q))]).reshape(-1, T, n)
    best_band = None
    best_std = getattr(res, "best_std", None)
    if best_std is not None and np.all(np.isfinite(best_std)):
        # the recommended estimate's own band: sets drawn from its normal approximation
        rng = np.random.default_rng(0)
        draws = pts[3] + rng.standard_normal((N_BEST_BAND, len(pts[3]))) * np.asarray(best_std)
        bq = [q for q in processed(draws)[0] if np.all(np.isfinite(q))]
        best_band = np.array(bq).reshape(-1, T, n) if bq else None
    if t_axis is None:  # every point estimate diverged: the chain's time axis of the record
        t_axis = prob.chain.apply(rec, st.dofs).t
    try:
        modes = tuple(float(f) for f in st.linear_modes(pts[3]).get("frequency_hz", [])
                      if np.isfinite(f))
    except Exception:  # noqa: BLE001 - the axes fall back to the energy criterion
        modes = ()
    return _RecordSims(rec.name, role, t_axis, target, band, dict(zip(order, point_q)),
                       len(band_q) - len(band), 1.0 / (t_axis[1] - t_axis[0]), best_band, modes)


def _mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over time and DOFs of the squared difference (inf when b diverged)."""
    return float(np.mean((a - b) ** 2)) if np.all(np.isfinite(b)) else math.inf


def _slug(name: str) -> str:
    stem = re.sub(r"\.(csv|json|npz|mcap)$", "", name, flags=re.I)
    return re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_")[:40] or "record"


def _grid(n: int) -> tuple[int, int]:
    ncols = min(3, n) if n != 4 else 2
    return math.ceil(n / ncols), ncols


# ---------------------------------------------------------------------------- figures
def _subplots(nrows: int, ncols: int, **kw: Any) -> tuple[Any, Any]:
    """A figure on its own Agg canvas: no pyplot, so no global backend or figure registry
    is touched (safe inside a service thread or next to a user's interactive session)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize", None))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kw)


def _fig_losses(res: Any) -> Any:
    h = res.history
    ep = np.arange(len(h["loss_d"]))
    fig, axs = _subplots(1, 3, figsize=(13, 3.6))
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


def _unit(units: Mapping[str, str], p: str) -> str:
    u = units.get(p, "")
    return f" [{u}]" if u else ""


def _fig_parameters(res: Any, names: Sequence[str], window: tuple[int, int] | None,
                    truth: np.ndarray | None, units: Mapping[str, str] | None = None) -> Any:
    units = units or {}
    theta = np.array(res.history["theta"], dtype=float).reshape(-1, len(names))
    ep = np.arange(len(theta))
    nr, nc = _grid(len(names))
    fig, axs = _subplots(nr, nc, figsize=(4.3 * nc, 2.9 * nr),
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
        ax.set_title(p + _unit(units, p))
        ax.set_ylabel(p + _unit(units, p))
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in list(axs.flat)[len(names):]:
        ax.set_visible(False)
    return fig


def _fig_distributions(res: Any, names: Sequence[str], truth: np.ndarray | None,
                       units: Mapping[str, str] | None = None) -> Any:
    units = units or {}
    S = np.asarray(res.samples_II, dtype=float).reshape(-1, len(names))
    nr, nc = _grid(len(names))
    fig, axs = _subplots(nr, nc, figsize=(4.3 * nc, 3.0 * nr),
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
        ax.set_title(p + _unit(units, p))
        ax.set_xlabel(p + _unit(units, p))
        ax.set_ylabel("pdf")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, loc="upper right")
    for ax in list(axs.flat)[len(names):]:
        ax.set_visible(False)
    return fig


def _fig_response(rs: _RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = _subplots(n, 3, figsize=(18, 3.0 * n), squeeze=False,
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
                    label=f"mean of sims (MSE {_mse(m, mean):.3g} mm²)")
        pI = rs.points["approach_I"][:, k]
        ax.plot(t, pI, color=COLOURS["approach_I"], lw=0.9, ls="--",
                label=f"Approach I mean params (MSE {_mse(m, pI):.3g} mm²)")
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
                    label=f"{LABELS[key]} (MSE {_mse(m, y):.3g} mm²)")
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


def _fig_spectrum(rs: _RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = _subplots(n, 1, figsize=(9, 3.0 * n), squeeze=False)
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


def _fig_cwt(rs: _RecordSims, dofs: Sequence[str]) -> Any:
    n = len(dofs)
    fig, axs = _subplots(n, 2, figsize=(12, 3.0 * n), squeeze=False,
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


# ---------------------------------------------------------------------------- HTML
def _fmt(x: Any) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return html.escape(str(x))
    return f"{v:.5g}" if np.isfinite(v) else str(v)


def _interval(value: float, lo: float, hi: float, unit: str) -> str:
    """"v ± h unit (±r %)": readable where "[lo, hi]" would print the same digits twice."""
    half = 0.5 * (hi - lo)
    unit = "" if unit == "-" else unit  # dimensionless: the unit column says so
    rel = f" (±{100 * half / abs(value):.2g} %)" if value else ""
    return f"{_fmt(value)} ± {float(half):.2g}{(' ' + html.escape(unit)) if unit else ''}{rel}"


def _verdict_banner(verdict: Any) -> str:
    """The validation verdict, first thing on the page (red when rejected)."""
    e = html.escape
    colour = {"accepted": "#e6f4e6", "rejected": "#fbe3e3"}.get(verdict.status, "#fff4d6")
    items = "".join(f"<li>{e(d)}</li>" for d in verdict.details)
    steps = "".join(f"<li><code>{e(s)}</code></li>" if s.startswith("siva ") else
                    f"<li>{e(s)}</li>" for s in verdict.next_steps)
    return (f'<div id="verdict" class="{e(verdict.status)}" style="background:{colour};'
            f'border:1px solid #999;padding:0.6em 1em;margin:1em 0">'
            f"<p><b>{e(verdict.headline)}</b></p>"
            + (f"<ul>{items}</ul>" if items else "")
            + (f"<p>What to try next:</p><ul>{steps}</ul>" if steps else "") + "</div>")


def _recommendation(res: Any, verdict: Any = None) -> str:
    """Which estimate to use and why, in one paragraph (what ``best`` is and how sure)."""
    if verdict is not None and not verdict.usable:
        return ("<p><b><code>best</code> below is what the fit found, not a recommendation"
                "</b>: " + html.escape(verdict.headline) + ".</p>")
    refined = res.best_std is not None
    oe = (res.metrics.get("train") or {}).get("best", {}).get("output_error")
    why = ("<b>Use <code>best</code></b>: the output-error refinement of Approach III, i.e. "
           "the parameters whose simulation, driven by the measured force and passed through "
           "the same processing chain as the measurement, matches the measured displacement "
           "best" + (f" (normalised output error {_fmt(oe)} on the training records)" if oe is not None else "")
           + ". Approaches I and II describe the trained generator and carry the processing "
           "chain's bias on measured data; use them to see how well the data constrain a "
           "parameter, not as the value.")
    if refined:
        why += (" Its 95 % interval is the Gauss-Newton one, inflated for correlated "
                "residuals.")
    else:
        why += (" The refinement did not lower the output error, so <code>best</code> is "
                "Approach III's winner and has no interval of its own.")
    return f"<p>{why}</p>"


def _html(est: Any, res: Any, names: Sequence[str], truth: np.ndarray | None,
          figures: list[tuple[Path, str]], sims: list[_RecordSims], note: str | None) -> str:
    e = html.escape
    units = est.structure.parameter_units() if hasattr(est.structure, "parameter_units") else {}
    verdict = res.assessment(
        train=" ".join(r.name for r in getattr(est, "train_recordings_", [])) or "TRAIN...",
        val=" ".join(r.name for r in getattr(est, "val_recordings_", [])) or None)
    rows = []
    for k, p in enumerate(names):
        u = units.get(p, "")
        I, II = res.approach_I[p], res.approach_II[p]
        if res.best_std is not None and np.isfinite(res.best_std[k]):
            s = float(res.best_std[k])
            use = _interval(float(res.best[k]), res.best[k] - Z95 * s, res.best[k] + Z95 * s, u)
        else:
            use = f"{_fmt(res.best[k])}{(' ' + e(u)) if u and u != '-' else ''} (no interval)"
        cells = [f"{e(p)}", e(u) or "–", f"<b>{use}</b>"]
        if truth is not None:
            cells.append(_fmt(truth[k]))
            err = (f"{100 * (res.best[k] - truth[k]) / abs(truth[k]):+.3f} %"
                   if np.isfinite(truth[k]) and truth[k] != 0 else "–")
            cells.append(err)
        cells += [_interval(I["mean"], I["ci95"][0], I["ci95"][1], u),
                  _interval(II["mean"], II["ci95"][0], II["ci95"][1], u),
                  _fmt(res.approach_III[k])]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    head = ["parameter", "unit", ("use this: best ± 95 %" if verdict.usable
                                  else "best ± 95 % (NOT validated: see above)")] + \
        (["exact", "best error"] if truth is not None else []) + \
        ["Approach I mean ± 95 %", "Approach II mean ± 95 %", "Approach III"]
    ptable = (_recommendation(res, verdict) + "<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in head)
              + "</tr>" + "".join(rows) + "</table>")

    mrows = []
    for split in ("train", "validation"):
        for approach, m in (res.metrics.get(split) or {}).items():
            mrows.append(f"<tr><td>{e(split)}</td><td>{e(approach)}</td>"
                         f"<td>{_fmt(m.get('disp_mse_mm2'))}</td>"
                         f"<td>{_fmt(m.get('output_error'))}</td></tr>")
    mtable = ("<table><tr><th>records</th><th>estimate</th><th>displacement MSE [mm²]</th>"
              "<th>output error (NMSE)</th></tr>" + "".join(mrows) + "</table>") if mrows else ""

    disc = res.discriminator or {}
    timing = ", ".join(f"{e(k)} {v:.2f} s" for k, v in res.timing_s.items())
    notes = list(res.notes) + ([note] if note else [])
    figs = "\n".join(
        f'<figure><img src="{e(p.name)}" alt="{e(p.stem)}"><figcaption>{e(c)}</figcaption></figure>'
        for p, c in figures)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>SIVA report - {e(est.structure.name)}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; max-width: 1400px; }}
table {{ border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 3px 8px; text-align: right; }}
th {{ background: #eee; }}
figure {{ margin: 1em 0 2em; }} img {{ max-width: 100%; border: 1px solid #ddd; }}
figcaption {{ color: #333; font-size: 0.9em; }}
</style></head><body>
<h1>SIVA identification: {e(est.structure.name)}</h1>
{_verdict_banner(verdict)}
<p>{len(res.history.get('loss_d', []))} epochs, converged at epoch {e(str(res.converged_epoch))};
Approach I: {len(res.samples_I)} samples; Approach II: {len(res.samples_II)} epochs.
Final discriminator loss {_fmt(disc.get('loss_d'))} (ln 4 = {LN4:.4f}, distance
{_fmt(disc.get('ln4_distance'))}).</p>
<p>Timing: {timing}.</p>
{''.join(f'<p><em>Note: {e(n)}</em></p>' for n in notes)}
<h2>Parameters</h2>
{ptable}
<h2>Displacement fit</h2>
{mtable}
<h2>Figures</h2>
{figs}
</body></html>
"""


__all__ = ["write_report"]
