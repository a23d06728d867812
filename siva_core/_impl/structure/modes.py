"""The linearised model about rest: stiffness and damping matrices assembled from the
elements' slopes at 0, and its natural frequencies, damping ratios and growth rate."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .parts import Element


def _state_matrix(elements: Sequence[Element], values: dict[str, Any],
                  masses: np.ndarray) -> np.ndarray:
    """The first-order state matrix [[0, I], [-M^-1 K, -M^-1 C]] of the model linearised
    about rest (the elements' slopes at 0)."""
    n = len(masses)
    K = np.zeros((n, n))
    C = np.zeros((n, n))
    eps = 1e-9
    for el in elements:
        coeffs = {c: float(values[p]) for c, p in zip(el.kind.coefficients, el.params)}
        kd = (el.kind.force(np.array(eps), np.array(0.0), **coeffs)
              - el.kind.force(np.array(-eps), np.array(0.0), **coeffs)) / (2 * eps)
        cd = (el.kind.force(np.array(0.0), np.array(eps), **coeffs)
              - el.kind.force(np.array(0.0), np.array(-eps), **coeffs)) / (2 * eps)
        for M, val in ((K, float(kd)), (C, float(cd))):
            M[el.i, el.i] += val
            if el.j >= 0:
                M[el.j, el.j] += val
                M[el.i, el.j] -= val
                M[el.j, el.i] -= val
    Minv = np.diag(1.0 / masses)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])


def linear_modes(elements: Sequence[Element], values: dict[str, Any],
                 masses: np.ndarray) -> dict[str, list[float]]:
    """Natural frequencies [Hz] and damping ratios of the linearised model about 0
    (``values``: every parameter's value, ``masses`` per DOF).  Oscillating modes only:
    an overdamped or a divergent (real) eigenvalue is not a mode (see ``growth_rate``)."""
    lam = np.linalg.eigvals(_state_matrix(elements, values, masses))
    lam = lam[np.imag(lam) > 1e-12]
    lam = lam[np.argsort(np.abs(lam))]
    wn = np.abs(lam)
    return {"frequency_hz": [float(w / (2 * math.pi)) for w in wn],
            "damping_ratio": [float(-l.real / w) for l, w in zip(lam, wn)]}


def growth_rate(elements: Sequence[Element], values: dict[str, Any],
                masses: np.ndarray) -> float:
    """The largest real part [1/s] of the linearised model's eigenvalues, real ones
    included: > 0 means motion about rest grows.  Why apart from ``linear_modes``: an
    indefinite stiffness (a negative spring between two masses outweighing the rest)
    gives a *real* positive eigenvalue, which the modes leave out (fresh seed 17482: a
    least-squares start with k = -838 N/m between m1 and m2 had two stable modes listed
    and a divergence of +15 1/s not, and every simulation from it overflowed)."""
    return float(np.max(np.linalg.eigvals(_state_matrix(elements, values, masses)).real))
