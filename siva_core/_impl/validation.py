"""Validation that validates: held-out residual power against the measurement noise.

Why: the paper reads the discriminator loss near ln 4 as "validated", but on measured
LO-NO a model that predicts the held-out records no better than zero (normalised output
error 0.9) had a discriminator loss 0.033 from ln 4.  A companion statistic with a stated
meaning replaces that reading:

    T = (mean squared held-out residual) / (measurement-noise power)

per record and DOF, after the model (fixed parameters) is simulated with the record's
measured force through the same chain, a per-record force scale (and the initial state of
a free decay) being the only things fitted.  T = 1: the model explains everything but the
noise.  The noise power is measured, not assumed: the raw channel's white-noise level
from the median absolute third difference (insensitive to the smooth response, to hum and
to an impact's few sharp samples), turned into processed units by passing white noise of
that level through the very same chain (so band-pass, notch and decimation are accounted
for exactly), which also gives the noise's correlation time and so the effective number of
independent samples N_eff.

Decision: H0 "the unexplained power is at most ``tolerance`` times the noise power"
(default 0.5: prediction uncertainty of the fitted parameters and force-sensor noise
typically add 5-15 %).  Under H0, T is at most 1 + tolerance up to sampling error
sqrt(2 / N_eff) (chi-square with N_eff degrees of freedom, normal approximation), so the
p-value is ``1 - Phi((T - (1 + tol)) / ((1 + tol) sqrt(2 / N_eff)))`` and the model is
accepted when p >= ``alpha`` (0.05).  Measured (benchmarks/bench_validation.py): T = 1.06-1.11
for the right LO-NO model on held-out records, 28-19 000 when an element is missing.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .bootstrap import correlation_time, series_of
from .processing import Processing
from .recording import Recording

#: default tolerance of H0 (unexplained power / noise power) and test level
TOLERANCE = 0.5
ALPHA = 0.05


def white_noise_sigma(x: np.ndarray) -> float:
    """Std of the white noise in ``x``: robust (MAD) std of the third difference / sqrt(20)
    (a white sequence's third difference has variance 20 sigma^2)."""
    d = np.diff(np.asarray(x, dtype=float), 3)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(20.0))


def processed_noise(structure: Any, rec: Recording, quantities: Sequence[str],
                    processing: Processing, seed: int = 0) -> tuple[np.ndarray, float]:
    """(per-DOF noise variance after the chain, correlation time in processed samples)."""
    rng = np.random.default_rng(seed)
    cols: dict[str, np.ndarray] = {}
    for d, q in zip(structure.dofs, quantities):
        raw = rec.get(q, d)
        cols[f"{q}_{d}"] = white_noise_sigma(raw) * rng.standard_normal(len(raw))
    for d in structure.dofs:
        f = rec.get("force", d)
        if f is not None:
            cols[f"force_{d}"] = f  # the same segmentation (impact detection) as the record
    noise_rec = Recording(rec.time, cols, f"{rec.name}:noise")
    st = processing.apply(noise_rec, structure.dofs)
    attr = {"disp": "q", "vel": "v", "acc": "a"}
    y = np.stack([getattr(st, attr[q])[:, k] for k, q in enumerate(quantities)], axis=-1)
    tau = correlation_time(y.reshape(-1), series_of([y.shape]))
    return np.var(y, axis=0), tau


def validation_score(structure: Any, theta: Any, records: Sequence[Recording],
                     processing: Processing, *, tolerance: float = TOLERANCE,
                     alpha: float = ALPHA) -> dict[str, Any]:
    """The held-out test of ``theta`` on ``records`` (see the module doc).  Returns
    ``{"statistic", "p_value", "accepted", "n_eff", "tolerance", "records": {...},
    "meaning"}``."""
    from .linearized import linearize

    recs = list(records)
    if not recs:
        raise ValueError("validation needs at least one held-out record")
    per: dict[str, dict[str, Any]] = {}
    num = den = n_eff_tot = 0.0
    for rec in recs:
        # a window held out of a longer record (``hold_out``: the last part of one hit's
        # decay) is predicted from that record's start, hit included: its own initial state
        # mid-decay is only known through integration, which is not what is being tested
        whole, t_from = rec.meta.get("held_out_of", (rec, None))
        try:
            lin = linearize(structure, np.asarray(theta, dtype=float), [whole], processing,
                            jacobian=False)  # the profiled residuals only
        except ValueError as exc:
            per[rec.name] = {"statistic": None, "error": str(exc)}
            num, den = math.inf, 1.0
            continue
        res = lin.residual_series(0)
        if t_from is not None:
            res = res[_processed_time(processing, whole, structure.dofs, len(res)) >= t_from]
            if len(res) < 8:
                per[rec.name] = {"statistic": None, "error": "held-out window too short"}
                num, den = math.inf, 1.0
                continue
        nv, tau = processed_noise(structure, whole, lin.quantities[0], processing)
        nv = np.maximum(nv, 1e-300)
        T_dof = np.mean(res ** 2, axis=0) / nv
        n_eff = len(res) / max(tau, 1.0)
        T_rec = float(np.mean(T_dof))
        per[rec.name] = {"statistic": T_rec, "statistic_per_dof": dict(zip(structure.dofs, T_dof.tolist())),
                         "n_eff": n_eff,
                         "p_value": _p_value(T_rec, n_eff * len(T_dof), tolerance)}
        num += T_rec * n_eff
        den += n_eff
        n_eff_tot += n_eff * len(T_dof)
    T = num / den if den > 0 else math.inf
    p = _p_value(T, n_eff_tot, tolerance) if math.isfinite(T) else 0.0
    return {"statistic": T, "p_value": p, "accepted": bool(p >= alpha), "alpha": alpha,
            "tolerance": tolerance, "n_eff": n_eff_tot, "records": per,
            "meaning": ("statistic = held-out residual power / measurement-noise power "
                        "(1 = explains all but the noise); p_value of H0 'unexplained power "
                        f"<= {tolerance:g} x noise power'; accepted when p >= {alpha:g}")}


def _processed_time(processing: Processing, rec: Recording, dofs: Sequence[str],
                    n: int) -> np.ndarray:
    """Time [s] of each of the ``n`` processed samples of ``rec`` (start, trim, decimation
    as in ``Processing._finish``)."""
    k = processing.decimation(rec.fs)
    edge = int(round(processing.trim * rec.fs))
    i0 = max(processing.start_index(rec, dofs), edge)
    t = rec.time[i0:len(rec) - edge:k][:n]
    if len(t) < n:
        t = np.r_[t, t[-1] + rec.dt * k * np.arange(1, n - len(t) + 1)] if len(t) else \
            rec.time[0] + rec.dt * k * np.arange(n)
    return t


def _p_value(T: float, n_eff: float, tolerance: float) -> float:
    if not math.isfinite(T):
        return 0.0
    mu = 1.0 + tolerance
    sd = mu * math.sqrt(2.0 / max(n_eff, 1.0))
    return float(0.5 * math.erfc((T - mu) / (sd * math.sqrt(2.0))))


__all__ = ["validation_score", "white_noise_sigma", "processed_noise", "TOLERANCE", "ALPHA"]
