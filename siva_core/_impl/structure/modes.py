"""The linearised model about rest: stiffness and damping matrices assembled from the
elements' slopes at 0, and its natural frequencies and damping ratios."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .parts import Element


def linear_modes(elements: Sequence[Element], values: dict[str, Any],
                 masses: np.ndarray) -> dict[str, list[float]]:
    """Natural frequencies [Hz] and damping ratios of the linearised model about 0
    (``values``: every parameter's value, ``masses`` per DOF)."""
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
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
    lam = np.linalg.eigvals(A)
    lam = lam[np.imag(lam) > 1e-12]
    lam = lam[np.argsort(np.abs(lam))]
    wn = np.abs(lam)
    return {"frequency_hz": [float(w / (2 * math.pi)) for w in wn],
            "damping_ratio": [float(-l.real / w) for l, w in zip(lam, wn)]}
