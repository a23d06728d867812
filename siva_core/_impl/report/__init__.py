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
(:class:`~siva_core._impl.output_error.OutputErrorProblem`), so what is compared is like with like
(the chain's own distortion appears on both sides).  Raw recordings are taken from
``est.train_recordings_`` / ``est.val_recordings_`` or the ``train=``/``val=`` arguments;
without them the processed states are simulated as records of their own (noted in the page).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..recording import Recording
from .page import page_html
from .record_figures import fig_cwt, fig_response, fig_spectrum
from .simulations import approach_ii_window, records_to_draw, simulate_record, truth_vector
from .style import file_slug
from .training_figures import fig_distributions, fig_losses, fig_parameters


Progress = Callable[[str], None]


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


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
    truth_vec = truth_vector(names, truth)
    written: list[tuple[Path, str]] = []
    t_start = time.perf_counter()

    def save(fig: Any, fname: str, caption: str) -> None:
        path = out / fname
        if not getattr(fig, "_siva_laid_out", False):
            fig.tight_layout()  # one layout pass: constrained layout re-runs on every draw
        fig.savefig(path, dpi=dpi)
        written.append((path, caption))
        say(f"report: {fname} ({time.perf_counter() - t_start:.1f} s)")

    save(fig_losses(res), "losses.png",
         "(a) Losses per epoch: discriminator (ln 4 = optimum, eq. 3), adversarial term "
         "(ln(4)/2), MSE of the accelerations (log axis); dotted: convergence epoch.")
    window = approach_ii_window(est, res)
    save(fig_parameters(res, names, window, truth_vec, units), "parameters.png",
         "(b) Parameter per epoch (mean of the epoch's last batch); shaded green: the Approach "
         "II window; dashed red: best, with its 95 % interval shaded red.")
    save(fig_distributions(res, names, truth_vec, units), "distributions.png",
         "(c) Approach II distribution: histogram, fitted normal pdf over +-6 std, mean "
         "(dashed red), 95 % CI (green); Approach III, best and exact value marked.")

    recs, note = records_to_draw(est, train, val)
    say(f"report: simulating {len(recs)} records ({min(n_sims, len(res.samples_I))} Approach I "
        f"samples + 4 point estimates each)")
    per_rec = None if sim_budget_s is None else sim_budget_s / max(1, len(recs))
    sims = []
    for rec, role in recs:
        sims.append(simulate_record(est, res, rec, role, n_sims, per_rec))
        say(f"report: simulated {rec.name}: {len(sims[-1].band_sims)} band sets"
            + (f" ({sims[-1].n_diverged} diverged)" if sims[-1].n_diverged else "")
            + f" ({time.perf_counter() - t_start:.1f} s)")
    for k, rs in enumerate(sims):
        slug = f"{k}_{file_slug(rs.name)}"
        save(fig_response(rs, est.structure.dofs), f"response_{slug}.png",
             f"(d) {rs.role} record {rs.name}: measured vs simulated displacement, with the "
             "95 % bands of Approach I and of best, and the residuals (measured - simulated).")
        save(fig_spectrum(rs, est.structure.dofs), f"spectrum_{slug}.png",
             f"(e) {rs.role} record {rs.name}: Fourier amplitude spectra; dashed grey: the "
             "natural frequencies of best (the axis reaches past the highest).")
        save(fig_cwt(rs, est.structure.dofs), f"cwt_{slug}.png",
             f"(f) {rs.role} record {rs.name}: CWT (complex Morlet, max = 1), measured vs best; "
             "dashed white: the natural frequencies of best (the axis reaches past the highest).")

    index = out / "index.html"
    index.write_text(page_html(est, res, names, truth_vec, written, sims, note))
    say(f"report: index.html, {len(written)} figures in {time.perf_counter() - t_start:.1f} s")
    return [p for p, _ in written] + [index]


__all__ = ["write_report"]
