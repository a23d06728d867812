"""One output-error estimate per record: the series that drift detection tests.

Why per record: records are independent measurements, so the scatter of per-record
estimates is the honest yardstick for "has it changed" (docs/service.md, Monitoring).
Each fit is ``siva_core.refine`` on that record alone, warm-started from the
headline estimate, with the record's force scale as a nuisance parameter (an impact's
response depends so strongly on its impulse that force-sensor noise would otherwise move
the parameters) and ``max_nfev`` bounded: on an 8 s LO-NO record about 0.4-1 s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from siva_core import Processing, Recording, Structure

from .drift import modal_quantities

#: cost evaluations of one per-record fit (its final stage)
RECORD_MAX_NFEV = 20
#: bootstrap replicates of a per-record fit (block; parametric = max(16, n/6)): ~0.3 s
RECORD_N_BOOT = 120


@dataclass
class RecordFit:
    """A record's estimate: parameters, their standard errors, modal quantities."""

    theta: np.ndarray
    se: np.ndarray | None                     # per parameter; None when not available
    modal: dict[str, float] = field(default_factory=dict)
    modal_se: dict[str, float] = field(default_factory=dict)
    cost: float | None = None
    nfev: int = 0
    success: bool = True
    seconds: float = 0.0
    force_scale: float | None = None


def fit_record(structure: Structure, theta0: Sequence[float], record: Recording,
               processing: Processing, *, max_nfev: int = RECORD_MAX_NFEV) -> RecordFit:
    """Output-error fit of one record from ``theta0`` (raises ValueError when unusable)."""
    from siva_core import refine

    t0 = time.perf_counter()
    has_force = any(c.startswith("force_") for c in getattr(record, "channels", []))
    res = refine(structure, np.asarray(theta0, dtype=float), record, processing,
                 fit_force_scale=has_force, max_nfev=max_nfev, n_boot=RECORD_N_BOOT)
    theta = np.asarray(res.theta, dtype=float)
    std = getattr(res, "std", None)
    se = None
    if std is not None:
        # refine's std is already calibrated (block + parametric bootstrap)
        se = np.asarray(std, dtype=float)
        if not np.all(np.isfinite(se)):
            se = None
    modal, modal_se = modal_values(structure, theta, getattr(res, "cov", None), 1.0)
    fs = getattr(res, "force_scale", None)
    return RecordFit(theta=theta, se=se, modal=modal, modal_se=modal_se,
                     cost=float(getattr(res, "cost", math.nan)), nfev=int(getattr(res, "nfev", 0)),
                     success=bool(getattr(res, "success", True)),
                     seconds=time.perf_counter() - t0,
                     force_scale=None if fs is None or len(fs) == 0 else float(fs[0]))


def modal_names(n_modes: int) -> list[str]:
    """Quantity names of the linear modes: f1_hz, zeta1, f2_hz, zeta2, ..."""
    return [n for k in range(1, n_modes + 1) for n in (f"f{k}_hz", f"zeta{k}")]


def modal_values(structure: Structure, theta: np.ndarray, cov: Any = None,
                 inflation: float = 1.0) -> tuple[dict[str, float], dict[str, float]]:
    """Modal quantities of ``theta`` by name, with delta-method standard errors from the
    parameters' covariance (when given)."""
    m = modal_quantities(structure, theta)
    if not m:
        return {}, {}
    values = _flat(m)
    errors: dict[str, float] = {}
    if cov is not None:
        cov = np.asarray(cov, dtype=float)
        n = len(theta)
        if cov.shape[0] >= n and np.all(np.isfinite(cov[:n, :n])):
            J = np.zeros((len(values), n))
            names = list(values)
            for j in range(n):
                h = 1e-6 * (abs(theta[j]) or 1.0)
                tp = np.array(theta, dtype=float)
                tp[j] += h
                mp = modal_quantities(structure, tp)
                if not mp:
                    return values, {}
                vp = _flat(mp)
                J[:, j] = [(vp.get(q, math.nan) - values[q]) / h for q in names]
            var = np.einsum("ij,jk,ik->i", J, cov[:n, :n], J)
            errors = {q: float(math.sqrt(v)) * inflation for q, v in zip(names, var)
                      if math.isfinite(v) and v > 0}
    return values, errors


def _flat(m: dict[str, list[float]]) -> dict[str, float]:
    out: dict[str, float] = {}
    for k, (f, z) in enumerate(zip(m["frequency_hz"], m["damping_ratio"]), start=1):
        out[f"f{k}_hz"] = float(f)
        out[f"zeta{k}"] = float(z)
    return out
