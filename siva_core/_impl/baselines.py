"""Equation-error baselines: least squares and SINDy on processed states.

Both fit M a = -sum f(q, v; theta) + G F on the states a processing chain produced, so
they inherit the chain's bias (see ``benchmarks/bench_processing_bias.py``); they are the
reference points SIVA is compared with and the initial guess for refinement.

* :func:`least_squares` solves the linear parameters in closed form (columns normalised,
  residual in acceleration units, the paper's loss) and the nonlinear ones (power_spring
  ``beta``, clearance ``gap``, ...) by variable projection: an outer
  ``scipy.optimize.least_squares`` over the nonlinear parameters alone, the linear ones
  re-solved for each trial, started from a coarse grid scan.
* :func:`sindy` fits the same terms through pysindy (a ``CustomLibrary`` holding exactly
  the model's terms, STLSQ with threshold 0, i.e. unconstrained least squares per equation)
  and maps each equation's coefficient back to the model parameter (times the known mass);
  a parameter seen in several equations (a coupling element acts on both its DOFs) gets the
  mean of its per-equation estimates, as unconstrained SINDy has no way to tie them.

Both return a :class:`FitResult`: a ``dict`` {free parameter: value} with ``fit_time_s``.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from scipy import optimize

from .processing import States
from .structure import Structure


class FitResult(dict):
    """{parameter name: value} plus how the fit went (a dict so callers can use it as is)."""

    def __init__(self, values: dict[str, float], *, method: str, fit_time_s: float,
                 residual_rms: float, extra: dict[str, Any] | None = None) -> None:
        super().__init__(values)
        self.method = method
        self.fit_time_s = fit_time_s
        self.residual_rms = residual_rms
        self.extra = extra or {}

    def __repr__(self) -> str:
        vals = ", ".join(f"{k}={v:.6g}" for k, v in self.items())
        return f"FitResult[{self.method}]({vals}; {self.fit_time_s:.3f} s)"


# Grids (relative to a reference) and bounds for the coefficients that enter nonlinearly.
# ``ref`` is "one" (absolute values) or "dmax" (the largest |d| the element sees).
@dataclass(frozen=True)
class _NonlinearPrior:
    grid: tuple[float, ...]
    lower: float
    upper: float
    ref: str = "one"


_PRIORS: dict[tuple[str, str], _NonlinearPrior] = {
    ("power_spring", "beta"): _NonlinearPrior(tuple(np.linspace(0.25, 4.0, 16)), 0.0, 8.0),
    ("clearance", "gap"): _NonlinearPrior(tuple(np.linspace(0.02, 0.9, 23)), 0.0, 1.0, "dmax"),
}


@dataclass
class _Term:
    """One regression column: a free linear parameter in one slot of one element/force."""

    param: str
    dof_sign: tuple[tuple[int, float], ...]  # (dof index, +-1) the force acts on
    basis: Callable[[dict[str, float], np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class _Design:
    """The model as regression: a = known(theta_nl) + sum_p theta_p * column_p(theta_nl)."""

    def __init__(self, structure: Structure, states_list: Sequence[States]) -> None:
        if not states_list:
            raise ValueError("no states to fit")
        self.s = structure
        self.states = list(states_list)
        self.q = np.concatenate([np.asarray(st.q, float) for st in self.states])
        self.v = np.concatenate([np.asarray(st.v, float) for st in self.states])
        self.a = np.concatenate([np.asarray(st.a, float) for st in self.states])
        self.f = np.concatenate([np.asarray(st.f, float) for st in self.states])
        self.m = structure.masses
        free = set(structure.free)
        nonlinear: list[str] = []
        for el in structure.elements:
            for c, p in zip(el.kind.coefficients, el.params):
                if p in free and c not in el.kind.linear and p not in nonlinear:
                    nonlinear.append(p)
        self.nonlinear = nonlinear
        self.linear = [p for p in structure.free if p not in nonlinear]
        self.fixed = {p: info.fixed for p, info in structure.parameters.items()
                      if info.fixed is not None}
        self._terms: list[_Term] = []
        for el in structure.elements:
            sites = [(el.i, 1.0)] + ([(el.j, -1.0)] if el.j >= 0 else [])
            for c, p in zip(el.kind.coefficients, el.params):
                if p in self.linear and c in el.kind.linear:
                    self._terms.append(_Term(p, tuple(sites), self._element_basis(el, c)))
        for k, d in enumerate(structure.dofs):
            gain = structure.force_gain(d)
            if isinstance(gain, str) and gain in self.linear:
                # +g F on DOF k: a "force" pushing k by -(-F), hence sign -1 with basis F
                self._terms.append(_Term(gain, ((k, -1.0),),
                                         lambda vals, q, v, f, k=k: f[:, k]))

    # -- element pieces --------------------------------------------------------------
    def _coeffs(self, el, values: dict[str, float], unit: str | None) -> dict[str, float]:
        """Coefficients of ``el``: ``unit`` slot = 1, other free linear slots 0, rest values."""
        out = {}
        for c, p in zip(el.kind.coefficients, el.params):
            if c == unit:
                out[c] = 1.0
            elif p in self.linear and c in el.kind.linear:
                out[c] = 0.0
            else:
                out[c] = float(values[p])
        return out

    def _element_basis(self, el, slot: str):
        def basis(values, q, v, f):
            d = q[:, el.i] - (q[:, el.j] if el.j >= 0 else 0.0)
            dv = v[:, el.i] - (v[:, el.j] if el.j >= 0 else 0.0)
            return np.asarray(el.kind.force(d, dv, **self._coeffs(el, values, slot)), float)
        return basis

    def values(self, theta_nl: Sequence[float]) -> dict[str, float]:
        vals = dict(self.fixed)
        vals.update(zip(self.nonlinear, (float(x) for x in theta_nl)))
        return vals

    def known_acc(self, values: dict[str, float]) -> np.ndarray:
        """Accelerations from fixed/nonlinear-only parts and fixed-gain forces, (N, n)."""
        s = self.s
        acc = np.zeros_like(self.a)
        for el in s.elements:
            coeffs = self._coeffs(el, values, None)
            if all(coeffs[c] == 0.0 for c in el.kind.linear if c in coeffs) and el.kind.linear:
                continue  # every linear slot is free: no known contribution
            d = self.q[:, el.i] - (self.q[:, el.j] if el.j >= 0 else 0.0)
            dv = self.v[:, el.i] - (self.v[:, el.j] if el.j >= 0 else 0.0)
            fe = np.asarray(el.kind.force(d, dv, **coeffs), float)
            acc[:, el.i] -= fe
            if el.j >= 0:
                acc[:, el.j] += fe
        for k, d in enumerate(s.dofs):
            gain = s.force_gain(d)
            if isinstance(gain, str):
                if gain in self.linear:
                    continue
                gain = values[gain]
            acc[:, k] += float(gain) * self.f[:, k]
        return acc / self.m

    def columns(self, values: dict[str, float]) -> list[tuple[str, np.ndarray]]:
        """Per term: (parameter, (N, n) acceleration per unit parameter)."""
        out = []
        for term in self._terms:
            b = term.basis(values, self.q, self.v, self.f)
            col = np.zeros_like(self.a)
            for k, sign in term.dof_sign:
                col[:, k] -= sign * b / self.m[k]
            out.append((term.param, col))
        return out

    def system(self, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """(A, y): y = A theta_lin in acceleration units, rows = samples x DOFs."""
        y = (self.a - self.known_acc(values)).ravel()
        A = np.zeros((y.size, len(self.linear)))
        for p, col in self.columns(values):
            A[:, self.linear.index(p)] += col.ravel()
        return A, y

    def nonlinear_bounds(self, p: str) -> tuple[_NonlinearPrior, float, float, float]:
        """Prior, reference, and bounds of nonlinear parameter ``p`` (spec bounds win)."""
        prior: _NonlinearPrior | None = None
        dmax: list[float] = []  # largest |d| of each element using p (for "dmax" priors)
        for el in self.s.elements:
            for c, name in zip(el.kind.coefficients, el.params):
                if name == p and c not in el.kind.linear:
                    prior = prior or _PRIORS.get((el.kind.name, c))
                    d = self.q[:, el.i] - (self.q[:, el.j] if el.j >= 0 else 0.0)
                    dmax.append(float(np.max(np.abs(d))) if d.size else 0.0)
        ref = max(dmax) if prior is not None and prior.ref == "dmax" and dmax else 1.0
        ref = ref if ref > 0 else 1.0
        info = self.s.parameters[p]
        if prior is None:
            scale = info.scale or 1.0
            prior = _NonlinearPrior(tuple(scale * np.logspace(-2, 2, 17)), -np.inf, np.inf)
        lo = info.lower if info.lower is not None else prior.lower * ref
        hi = info.upper if info.upper is not None else prior.upper * ref
        return prior, ref, lo, hi


def _solve_linear(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares with columns normalised to unit norm (scales differ by 1e8 and more)."""
    if A.shape[1] == 0:
        return np.zeros(0)
    norms = np.linalg.norm(A, axis=0)
    norms[norms == 0] = 1.0
    sol, *_ = np.linalg.lstsq(A / norms, y, rcond=None)
    return sol / norms


def _profile(design: _Design, residual: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Nonlinear parameters minimising ``residual``: grid scan per parameter, then refine."""
    nl = design.nonlinear
    if not nl:
        return np.zeros(0)
    bounds = [design.nonlinear_bounds(p) for p in nl]
    x = np.array([prior.grid[len(prior.grid) // 2] * ref for prior, ref, _, _ in bounds], float)
    for _sweep in range(2):  # coordinate scans: cheap and robust to poor starting points
        for k, (prior, ref, lo, hi) in enumerate(bounds):
            best = (np.inf, x[k])
            for g in prior.grid:
                trial = x.copy()
                trial[k] = min(max(g * ref, lo), hi)
                cost = float(np.sum(residual(trial) ** 2))
                if cost < best[0]:
                    best = (cost, trial[k])
            x[k] = best[1]
    lo = np.array([b[2] for b in bounds])
    hi = np.array([b[3] for b in bounds])
    scale = np.array([max(abs(v), b[1] * 1e-3, 1e-12) for v, b in zip(x, bounds)])
    x0 = np.clip(x, lo, hi)  # inside (or on) the bounds: least_squares nudges it inward
    res = optimize.least_squares(lambda z: residual(z * scale), x0 / scale,
                                 bounds=(lo / scale, hi / scale), x_scale="jac",
                                 diff_step=1e-6, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return res.x * scale


def least_squares(structure: Structure, states_list: Sequence[States]) -> FitResult:
    """Equation-error least-squares fit of every free parameter on processed states.

    The residual is a - M^-1(-sum f + G F) over all samples and DOFs, in acceleration
    units (the paper's loss).  Linear parameters are solved in closed form for each trial
    of the nonlinear ones (variable projection), so only the few nonlinear parameters are
    searched iteratively.
    """
    t0 = time.perf_counter()
    design = _Design(structure, states_list)

    def residual(theta_nl: np.ndarray) -> np.ndarray:
        A, y = design.system(design.values(theta_nl))
        return y - A @ _solve_linear(A, y)

    theta_nl = _profile(design, residual)
    A, y = design.system(design.values(theta_nl))
    theta_lin = _solve_linear(A, y)
    r = y - A @ theta_lin
    values = {**dict(zip(design.linear, theta_lin.tolist())),
              **dict(zip(design.nonlinear, theta_nl.tolist()))}
    out = {p: float(values[p]) for p in structure.free}
    return FitResult(out, method="least_squares", fit_time_s=time.perf_counter() - t0,
                     residual_rms=float(np.sqrt(np.mean(r ** 2))))


def _library_function(n_inputs: int, fn: Callable[[np.ndarray], np.ndarray]) -> Callable:
    """A function of exactly ``n_inputs`` positional arguments (pysindy's CustomLibrary
    applies a function to every combination of as many inputs as it has arguments; taking
    all inputs at once gives exactly one feature, i.e. a library restricted to our terms)."""
    args = ", ".join(f"x{k}" for k in range(n_inputs))
    return eval(f"lambda {args}: _fn(({args},))", {"_fn": fn})  # noqa: S307 - fixed template


def sindy(structure: Structure, states_list: Sequence[States], *,
          threshold: float = 0.0) -> FitResult:
    """SINDy fit with a library restricted to the model's terms (masses known).

    State x = [q, v], derivative [v, a - known], control u = F.  Each free linear
    parameter slot becomes one library feature; STLSQ with ``threshold`` 0 (no sparsity,
    the model's terms are all wanted), no ridge, normalised columns.  The acceleration rows
    of the coefficient matrix are mapped back: coefficient x mass x sign of the term in that
    DOF's equation; estimates of one parameter from several equations are averaged.
    Nonlinear parameters (e.g. ``beta``) are profiled: the SINDy residual (per-equation
    least squares, which is what STLSQ computes at threshold 0) is minimised over them like
    in :func:`least_squares`, since a polynomial library cannot express them; pysindy then
    fits at the profiled values.
    """
    import pysindy as ps

    t0 = time.perf_counter()
    design = _Design(structure, states_list)
    s = structure
    n = s.n_dof
    terms = design._terms
    if not terms:
        raise ValueError("sindy: the model has no free linear parameter to fit")
    lengths = [len(st.t) for st in design.states]
    splits = np.cumsum(lengths)[:-1]
    dt = [float(st.t[1] - st.t[0]) if len(st.t) > 1 else 1.0 for st in design.states]

    def fit(theta_nl: np.ndarray) -> tuple[np.ndarray, np.ndarray, Any]:
        values = design.values(theta_nl)
        target = design.a - design.known_acc(values)

        def make(term: _Term) -> Callable:
            def fn(cols: tuple[np.ndarray, ...]) -> np.ndarray:
                z = np.stack(cols, axis=-1)
                q, v, f = z[:, :n], z[:, n:2 * n], z[:, 2 * n:]
                return term.basis(values, q, v, f)
            return _library_function(3 * n, fn)

        library = ps.CustomLibrary([make(t) for t in terms],
                                   function_names=[(lambda *a, p=t.param: p) for t in terms])
        model = ps.SINDy(optimizer=ps.STLSQ(threshold=threshold, alpha=0.0,
                                            normalize_columns=True),
                         feature_library=library)
        x = np.split(np.concatenate([design.q, design.v], axis=1), splits)
        xdot = np.split(np.concatenate([design.v, target], axis=1), splits)
        u = np.split(design.f, splits)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.fit(x, t=dt, x_dot=xdot, u=u)
        coef = np.asarray(model.coefficients())[n:]  # acceleration rows, (n, n_terms)
        feats = np.column_stack([t.basis(values, design.q, design.v, design.f) for t in terms])
        resid = target - feats @ coef.T
        return coef, resid, model

    def profile_residual(theta_nl: np.ndarray) -> np.ndarray:
        # what STLSQ at threshold 0 without ridge computes, per equation, without building
        # a pysindy model for every trial of the nonlinear parameters
        values = design.values(theta_nl)
        target = design.a - design.known_acc(values)
        feats = np.column_stack([t.basis(values, design.q, design.v, design.f) for t in terms])
        norms = np.linalg.norm(feats, axis=0)
        norms[norms == 0] = 1.0
        coef, *_ = np.linalg.lstsq(feats / norms, target, rcond=None)
        return (target - (feats / norms) @ coef).ravel()

    theta_nl = _profile(design, profile_residual)
    coef, resid, model = fit(theta_nl)
    estimates: dict[str, list[float]] = {}
    per_equation: dict[str, dict[str, float]] = {}
    for col, term in enumerate(terms):
        for k, sign in term.dof_sign:
            # a_k contains -sign * theta * basis / m_k
            est = float(-sign * coef[k, col] * design.m[k])
            estimates.setdefault(term.param, []).append(est)
            per_equation.setdefault(term.param, {})[s.dofs[k]] = est
    values = {p: float(np.mean(v)) for p, v in estimates.items()}
    values.update(zip(design.nonlinear, (float(x) for x in theta_nl)))
    out = {p: values[p] for p in s.free}
    return FitResult(out, method="sindy", fit_time_s=time.perf_counter() - t0,
                     residual_rms=float(np.sqrt(np.mean(resid ** 2))),
                     extra={"per_equation": per_equation,
                            "equations": model.equations(precision=6)})
