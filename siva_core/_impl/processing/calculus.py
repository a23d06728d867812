"""Integration and differentiation of sampled signals, and integration constants.

The chain derives what a recording lacks: velocity and displacement by cumulative
integration of acceleration, acceleration and velocity by central differences of
displacement.  For a free decay that dies out within the record the integration constants
come from the decayed tail (``drift="tail"``), where the structure is back at rest.
"""
from __future__ import annotations

import numpy as np
from scipy import integrate

from .filtfilt_kernel import cumulative_simpson_batched

#: fraction of the record at its end taken as the decayed tail (``drift="tail"``, decays)
TAIL_FRACTION = 0.2


def cumulative_integral(x: np.ndarray, dt: float, integrator: str) -> np.ndarray:
    """Integral from 0 along axis 0: ``"simpson"`` (cumulative Simpson) or ``"trapezoid"``
    (the paper's cumtrapz; also Simpson's fallback below 3 samples)."""
    if integrator == "simpson" and x.shape[0] >= 3:
        if x.dtype == np.float64:  # compiled, the same numbers (``filtfilt_kernel``)
            y = cumulative_simpson_batched(x, dt)
            if y is not None:
                return y
        return integrate.cumulative_simpson(x, dx=dt, axis=0, initial=0.0)
    if integrator in ("trapezoid", "simpson"):
        return np.concatenate([np.zeros((1,) + x.shape[1:]),
                               np.cumsum(0.5 * (x[1:] + x[:-1]) * dt, axis=0)])
    raise ValueError(f"integrator must be 'trapezoid' or 'simpson', got {integrator!r}")


def central_difference(x: np.ndarray, dt: float, axis: int = 0,
                       accuracy: int = 6) -> np.ndarray:
    """Derivative by a central stencil of the given order; 2nd-order one-sided at edges."""
    x = np.asarray(x, dtype=float)
    out = np.gradient(x, dt, axis=axis, edge_order=2) if x.shape[axis] > 2 else \
        np.gradient(x, dt, axis=axis)
    stencils = {2: [1 / 2], 4: [2 / 3, -1 / 12], 6: [3 / 4, -3 / 20, 1 / 60]}
    if accuracy not in stencils:
        raise ValueError(f"diff_accuracy must be 2, 4 or 6, got {accuracy}")
    w = stencils[accuracy]
    m = len(w)
    n = x.shape[axis]
    if accuracy == 2 or n <= 2 * m:
        return out
    xm = np.moveaxis(x, axis, 0)
    om = np.moveaxis(out, axis, 0)
    inner = np.zeros_like(xm[m:n - m])
    for j, c in enumerate(w, start=1):
        inner += c * (xm[m + j:n - m + j] - xm[m - j:n - m - j])
    om[m:n - m] = inner / dt
    return np.moveaxis(om, 0, axis)


def joint_tail_constants(v: np.ndarray, q: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement both integrated from acceleration (time on the last axis):
    choose the constants (q0, v0) so that q + q0 + v0 t has zero mean and no trend over the
    decayed tail.  A velocity offset left by a tail mean over partial cycles would otherwise
    become a displacement drift; fitting the drift pins v0 far more precisely."""
    n = q.shape[-1]
    m = max(2, int(TAIL_FRACTION * n))
    t = np.arange(n) / fs
    tt = t[-m:]
    A = np.stack([np.ones(m), tt - tt.mean()], axis=1)
    coef = np.linalg.lstsq(A, -np.moveaxis(q[..., -m:], -1, 0).reshape(m, -1), rcond=None)[0]
    v0 = coef[1].reshape(q.shape[:-1])[..., None]
    q0 = (coef[0] - coef[1] * tt.mean()).reshape(q.shape[:-1])[..., None]
    # v was already shifted by its own tail mean; the fit corrects what remains
    return v + v0, q + q0 + v0 * t
