"""What ``refine`` returns: the refined parameters, their uncertainty, the fitted
nuisances and the linearisation at the optimum."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class RefineResult:
    """Refined parameters with Gauss-Newton uncertainty.

    ``std``/``ci95``/``cov``: by default (``uncertainty="bootstrap"``) the moving-block
    bootstrap of the linearised fit at the optimum (``bootstrap.py``), which holds for the
    correlated residuals of filtered records and for misfit; ``std_gauss_newton`` is the
    textbook s^2 (J^T J)^-1 (independent residuals), kept for comparison, and
    ``ci_inflation`` the RMS ratio of the two.  ``jac``/``residuals``/``dtheta_dx``: the
    linearisation at the optimum in the fitted variables (theta, then nuisance).
    """

    theta: np.ndarray
    std: np.ndarray
    ci95: np.ndarray  # (n, 2)
    cov: np.ndarray
    cost: float
    nfev: int
    success: bool
    message: str
    njev: int = 0
    substeps: list[int] = field(default_factory=list)
    time_s: float = 0.0
    ci_inflation: float = 1.0
    names: list[str] = field(default_factory=list)
    force_scale: np.ndarray | None = None   # per record, when fit_force_scale
    force_shift: np.ndarray | None = None   # per record [samples], when fit_force_shift
    force_spread: np.ndarray | None = None  # per record [samples^2], when fit_force_spread
    force_kick: np.ndarray | None = None    # (n_records, 2, n_dof), when the kick is fitted
    stages: list[dict[str, Any]] = field(default_factory=list)
    std_gauss_newton: np.ndarray | None = None
    uncertainty: str = "bootstrap"
    block_length: int = 1
    stopped: bool = False  # ended by ``stop`` (a loser's fit cut short), not converged
    jac: np.ndarray | None = field(default=None, repr=False)
    residuals: np.ndarray | None = field(default=None, repr=False)
    dtheta_dx: np.ndarray | None = field(default=None, repr=False)

    @property
    def correlation(self) -> np.ndarray:
        """Parameter correlation matrix (e.g. alpha and beta of a power law trade off)."""
        s = np.sqrt(np.clip(np.diag(self.cov), 1e-300, None))
        return self.cov / np.outer(s, s)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """{name: {"mean", "std", "ci95"}}, the shape of the service's estimate."""
        return {n: {"mean": float(m), "std": float(s), "ci95": [float(lo), float(hi)]}
                for n, m, s, (lo, hi) in zip(self.names, self.theta, self.std, self.ci95)}
