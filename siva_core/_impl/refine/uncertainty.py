"""The uncertainty of a refined estimate: the Gauss-Newton covariance and, by default, the
wider of two bootstraps of the linearised fit at the optimum, floored at the simulator's
accuracy."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..bootstrap import bootstrap_covariance, perturbation_solutions, series_of
from ..ensemble import Z95
from ..output_error import OutputErrorProblem
from ..replicates import noise_replicates

#: relative standard error below which no interval is reported (simulation accuracy)
NUMERICAL_REL_STD = 1e-6


def refined_uncertainty(full: OutputErrorProblem, res: Any, th: np.ndarray,
                        extra: dict[str, np.ndarray], dth: np.ndarray, theta: np.ndarray,
                        n_free: int, n_x: int, uncertainty: str, n_boot: int
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """(cov, std, std_gauss_newton, ci95, std / std_gauss_newton, block length) of the
    ``n_free`` parameters at ``refine``'s optimum ``res`` (``least_squares``' result on
    ``full``; ``th``, ``extra``: its parameters and nuisances; ``dth``: d theta / d x)."""
    # covariance in the well-scaled x variables, then to theta: cov = D cov_x D
    # (inverting J^T J in theta units would mix 1e7 and 1e0 scales and lose the small ones)
    r = res.fun
    dof = max(1, r.size - n_x)
    s2 = float(r @ r) / dof
    cov_gn = (s2 * _pinv_sym(res.jac.T @ res.jac) * np.outer(dth, dth))[:n_free, :n_free]
    if uncertainty == "bootstrap":
        # two bootstraps of the linearised fit (nuisance columns included, so they are
        # profiled out), the wider per parameter: (1) moving blocks of (J, r) rows, a
        # sandwich covariance that holds for correlated and misfit residuals; (2)
        # parametric: force-sensor noise in the pulse propagated through the simulation
        # and the chain, plus measurement noise with the residuals' own spectrum
        series = series_of([rr.target.shape for rr in full.records])
        cov_x, block = bootstrap_covariance(res.jac, r, series, n_boot=n_boot, seed=0)
        E = noise_replicates(full, th, extra, r, series, n_rep=max(16, n_boot // 6))
        xp = perturbation_solutions(res.jac, E)
        cov_p = np.cov(xp, rowvar=False).reshape(n_x, n_x)
        cov = _wider((cov_x * np.outer(dth, dth))[:n_free, :n_free],
                     (cov_p * np.outer(dth, dth))[:n_free, :n_free])
    elif uncertainty == "gauss-newton":
        cov, block = cov_gn, 1
    else:
        raise ValueError(f"uncertainty must be 'bootstrap' or 'gauss-newton', got {uncertainty!r}")
    # never narrower than the simulator's own accuracy: on noise-free records the
    # statistical spread vanishes and RK4 vs the data's integrator differ by ~1e-7
    floor = NUMERICAL_REL_STD * np.abs(theta)
    cov = cov + np.diag(floor ** 2)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    std_gn = np.sqrt(np.clip(np.diag(cov_gn), 0, None))
    ci = np.stack([theta - Z95 * std, theta + Z95 * std], axis=1)
    with np.errstate(all="ignore"):
        ratio = np.where(std_gn > 0, std / std_gn, 1.0)
    return cov, std, std_gn, ci, ratio, block


def _wider(c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """The covariance with the larger variance per parameter (correlations from it too)."""
    pick = np.diag(c1) >= np.diag(c2)
    s = np.sqrt(np.clip(np.where(pick, np.diag(c1), np.diag(c2)), 0, None))
    corr1 = c1 / np.sqrt(np.clip(np.outer(np.diag(c1), np.diag(c1)), 1e-300, None))
    corr2 = c2 / np.sqrt(np.clip(np.outer(np.diag(c2), np.diag(c2)), 1e-300, None))
    corr = np.where(np.outer(pick, pick), corr1, np.where(np.outer(~pick, ~pick), corr2,
                                                          0.5 * (corr1 + corr2)))
    return corr * np.outer(s, s)


def _pinv_sym(A: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    tol = max(float(w.max()), 0.0) * A.shape[0] * np.finfo(float).eps
    inv = np.where(w > tol, 1.0 / np.where(w > tol, w, 1.0), 0.0)
    return (V * inv) @ V.T
