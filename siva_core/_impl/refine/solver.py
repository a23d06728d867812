"""One stage of ``refine``: ``scipy.optimize.least_squares`` (trust-region reflective) on
the output-error residuals, its forward-difference Jacobian from one batched simulation."""
from __future__ import annotations

import warnings
from typing import Any, Callable

import numpy as np
from scipy.optimize import least_squares

from ..output_error import OutputErrorProblem


def _stage_stop(stop: Callable[[int, bool, int, float, OutputErrorProblem], bool],
                stage: int, last: bool, prob: OutputErrorProblem) -> Callable[[Any], None]:
    """``least_squares``' callback for one stage of ``refine`` (scipy stops the solver
    when it raises StopIteration; the argument must be named ``intermediate_result``)."""
    def halt(intermediate_result: Any) -> None:
        if stop(stage, last, int(intermediate_result.nit),
                2.0 * float(intermediate_result.cost), prob):
            raise StopIteration
    return halt


def _solve(prob: OutputErrorProblem, to_theta: Any, x0: np.ndarray, lower: np.ndarray,
           upper: np.ndarray, max_nfev: int, fd_step: float, ftol: float, xtol: float,
           gtol: float, verbose: int, callback: Callable[[Any], None] | None = None) -> Any:
    n = x0.size

    def evaluate(X: np.ndarray) -> np.ndarray:
        th, extra = to_theta(X)
        return prob.residuals(th, **extra)

    # the trust-region method asks for the Jacobian at the point whose residuals it just
    # had: those are reused as the Jacobian's base row (each set of a batch is simulated
    # and processed on its own, so the row is the same bit for bit)
    last: dict[str, np.ndarray] = {}

    def fun(x: np.ndarray) -> np.ndarray:
        r = evaluate(x[None])[0]
        last["x"], last["r"] = x.copy(), r.copy()
        return r

    def jac(x: np.ndarray) -> np.ndarray:
        h = np.full(n, fd_step)
        h = np.where(x + h > upper, -h, h)  # keep every probe feasible
        X = np.repeat(x[None], n + 1, axis=0)
        X[1:] += np.diag(h)
        if "x" in last and np.array_equal(last["x"], x):
            R = np.concatenate([last["r"][None], evaluate(X[1:])])
        else:
            R = evaluate(X)  # ONE batched simulation of the n+1 sets
        J = (R[1:] - R[0]).T / h
        J[~np.isfinite(J)] = 0.0
        return J

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise ValueError("refine: the simulation diverges at the start (non-finite residuals)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        kw = {} if callback is None else {"callback": callback}  # scipy >= 1.16
        return least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf",
                             x_scale=1.0, max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol,
                             verbose=verbose, **kw)
